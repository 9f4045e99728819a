"""Command shaping: box, acceleration/deceleration, jerk, curvature-preserving wheel saturation."""

from __future__ import annotations

import itertools

import pytest

from controller.config import LimitParams
from controller.limits import CommandLimiter, LimitedCommand
from controller.types import TwistCommand

DT = 0.01
B, R = 0.28, 0.30


def limiter(**kw: float) -> CommandLimiter:
    return CommandLimiter(LimitParams(**kw), B, R)


def run(lim: CommandLimiter, targets: list[tuple[float, float]]) -> list[LimitedCommand]:
    return [lim.apply(TwistCommand(v, w), DT) for v, w in targets]


def test_box_limits_forward_and_reverse_separately() -> None:
    lim = limiter(
        v_max_mps=1.0, v_reverse_max_mps=0.3, accel_max_mps2=5, decel_max_mps2=5, jerk_max_mps3=500
    )
    out = run(lim, [(3.0, 0.0)] * 200)
    assert out[-1].v_mps == pytest.approx(1.0)
    out = run(lim, [(-3.0, 0.0)] * 300)
    assert out[-1].v_mps == pytest.approx(-0.3)
    assert lim.counters.box > 0


def test_acceleration_and_deceleration_have_their_own_limits() -> None:
    lim = limiter(accel_max_mps2=0.5, decel_max_mps2=1.5, jerk_max_mps3=500)
    up = run(lim, [(1.0, 0.0)] * 300)
    acc = max((b.v_mps - a.v_mps) / DT for a, b in itertools.pairwise(up))
    assert acc == pytest.approx(0.5, rel=1e-6)
    down = run(lim, [(0.0, 0.0)] * 300)
    dec = max((a.v_mps - b.v_mps) / DT for a, b in itertools.pairwise(down))
    assert dec == pytest.approx(1.5, rel=1e-6)


def test_jerk_limit_bounds_the_change_of_acceleration_and_never_overshoots_a_step() -> None:
    lim = limiter(accel_max_mps2=1.0, decel_max_mps2=1.0, jerk_max_mps3=5.0)
    out = run(lim, [(0.8, 0.0)] * 400)
    v = [c.v_mps for c in out]
    a = [(y - x) / DT for x, y in zip([0.0, *v], v, strict=False)]
    jerk = max(abs(y - x) / DT for x, y in itertools.pairwise(a))
    assert jerk <= 5.0 + 1e-6
    assert max(v) <= 0.8 + 1e-12
    assert v[-1] == pytest.approx(0.8)


def test_a_smoothly_ramping_target_is_followed_at_its_own_rate() -> None:
    # A controller ramping its command at 0.5 m/s^2 (within every limit) must not be slowed down.
    lim = limiter(accel_max_mps2=1.0, decel_max_mps2=1.5, jerk_max_mps3=20.0)
    targets = [(min(0.5 * k * DT, 1.0), 0.0) for k in range(1, 300)]
    out = run(lim, targets)
    # after the jerk-limited start (the ramp itself starts with an acceleration step)
    lag = max(t[0] - o.v_mps for t, o in list(zip(targets, out, strict=True))[20:])
    assert lag < 1e-3  # no steady lag behind a feasible ramp


def test_wheel_saturation_scales_both_wheels_and_keeps_the_curvature() -> None:
    lim = limiter(
        v_max_mps=3.0,
        omega_max_radps=10.0,
        wheel_max_radps=4.0,
        accel_max_mps2=5,
        decel_max_mps2=5,
        jerk_max_mps3=500,
        alpha_max_radps2=100,
    )
    v, w = 1.5, 2.0  # curvature 4/3 1/m; the outer wheel would need (1.5 + 0.56)/0.3 = 6.9 rad/s
    out = run(lim, [(v, w)] * 200)[-1]
    assert out.omega_radps / out.v_mps == pytest.approx(w / v)
    assert max(
        abs(out.v_mps - B * out.omega_radps), abs(out.v_mps + B * out.omega_radps)
    ) / R == pytest.approx(4.0)
    assert lim.counters.wheel > 0


def test_the_result_carries_the_wheel_speeds_of_the_command_it_sends() -> None:
    """Computed once, with the last wheel check, saturated or not; a stop step's too."""
    lim = limiter(wheel_max_radps=4.0)
    for c in run(lim, [(1.5, 2.0)] * 200) + [lim.stop_step(DT, 1.0) for _ in range(50)]:
        assert c.left_radps == (c.v_mps - B * c.omega_radps) / R
        assert c.right_radps == (c.v_mps + B * c.omega_radps) / R
        assert max(abs(c.left_radps), abs(c.right_radps)) <= 4.0 + 1e-12
    assert lim.counters.wheel > 0


def test_a_coordinated_stop_shrinks_v_and_omega_together_at_the_rim_deceleration() -> None:
    lim = limiter(accel_max_mps2=5, decel_max_mps2=5, jerk_max_mps3=500, alpha_max_radps2=100)
    run(lim, [(1.0, 0.8)] * 200)
    prev = (lim.v_mps, lim.omega_radps)
    for _ in range(300):
        c = lim.stop_step(DT, 1.0)
        if prev[0]:
            assert c.omega_radps * prev[0] == pytest.approx(
                prev[1] * c.v_mps, abs=1e-12
            )  # same curvature
        rim_prev = max(abs(prev[0] - B * prev[1]), abs(prev[0] + B * prev[1]))
        rim = max(abs(c.v_mps - B * c.omega_radps), abs(c.v_mps + B * c.omega_radps))
        assert rim_prev - rim <= 1.0 * DT + 1e-12
        prev = (c.v_mps, c.omega_radps)
    assert prev == (0.0, 0.0)
