"""RESILIENT: the 4-rule TSK fuzzy controller (rule firing, weighted average, inputs, hazards)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.config import GeometryParams, LimitParams
from controller.tracking import registry
from controller.tracking.resilient import ResilientTSK, ramp
from controller.types import ReferenceSample, StateEstimate, tracking_error
from dbc.runtime.errors import ConfigError

ROOT = Path(__file__).resolve().parents[4]
GEOM = GeometryParams()
B = GEOM.half_track_m

# Round numbers, independent of the tuned gains in gains.toml.
P = ResilientTSK.Params(
    d_near_m=0.1,
    d_far_m=0.5,
    theta_small_rad=0.1,
    theta_large_rad=0.5,
    k_d_near_small=1.0,
    k_t_near_small=0.2,
    k_d_near_large=0.5,
    k_t_near_large=0.4,
    k_d_far_small=2.0,
    k_t_far_small=0.6,
    k_d_far_large=1.5,
    k_t_far_large=0.8,
    lookahead_m=0.3,
)
#: A wheel limit that never binds (15 m/s at the rim).
WIDE = LimitParams(wheel_max_radps=50.0)


def _tsk(params: ResilientTSK.Params = P, traj=None, limits: LimitParams = WIDE) -> ResilientTSK:
    return ResilientTSK(params, GEOM, traj, limits=limits)  # type: ignore[arg-type]


def _at_rest(x: float = 0.0, y: float = 0.0, heading: float = 0.0, *, done: bool = False):
    return ReferenceSample(0.0, x, y, heading, 0.0, 0.0, done=done)


def _est(x: float, y: float, heading: float) -> StateEstimate:
    return StateEstimate(0.0, x, y, heading, 0.0, 0.0)


# ------------------------------------------------------------------ the fuzzy system


def test_memberships_are_linear_ramps_between_their_breakpoints() -> None:
    assert ramp(0.05, 0.1, 0.5) == 0.0
    assert ramp(0.1, 0.1, 0.5) == 0.0
    assert ramp(0.2, 0.1, 0.5) == pytest.approx(0.25)
    assert ramp(0.5, 0.1, 0.5) == 1.0
    assert ramp(3.0, 0.1, 0.5) == 1.0


def test_only_the_near_small_rule_fires_for_small_inputs() -> None:
    tsk = _tsk()
    vl, vr = tsk.infer(0.05, 0.02)
    assert tsk._w == (1.0, 0.0, 0.0, 0.0)
    assert vl == pytest.approx(1.0 * 0.05 + 0.2 * 0.02)
    assert vr == pytest.approx(1.0 * 0.05 - 0.2 * 0.02)


def test_only_the_far_large_rule_fires_for_large_inputs() -> None:
    tsk = _tsk()
    vl, vr = tsk.infer(-0.8, -1.0)
    assert tsk._w == (0.0, 0.0, 0.0, 1.0)
    assert vl == pytest.approx(1.5 * -0.8 + 0.8 * -1.0)
    assert vr == pytest.approx(1.5 * -0.8 - 0.8 * -1.0)


def test_rules_fire_with_the_min_t_norm_and_are_averaged_by_weight() -> None:
    tsk = _tsk()
    # |d_e| = 0.2: far 0.25, near 0.75;  |theta_e| = 0.4: large 0.75, small 0.25
    d, th = 0.2, -0.4
    vl, vr = tsk.infer(d, th)
    w = (0.25, 0.75, 0.25, 0.25)  # min(near, small), min(near, large), min(far, ...) x2
    assert tsk._w == pytest.approx(w)
    kd = (0.25 * 1.0 + 0.75 * 0.5 + 0.25 * 2.0 + 0.25 * 1.5) / 1.5  # = 1.0
    kt = (0.25 * 0.2 + 0.75 * 0.4 + 0.25 * 0.6 + 0.25 * 0.8) / 1.5  # = 0.4667
    assert vl == pytest.approx(kd * d + kt * th)
    assert vr == pytest.approx(kd * d - kt * th)
    assert kd == pytest.approx(1.0)
    assert kt == pytest.approx(0.7 / 1.5)


def test_the_weighted_average_interpolates_between_neighbouring_rules() -> None:
    tsk = _tsk()
    lo, _ = tsk.infer(0.1, 0.0)  # near only: k_d = 1
    mid, _ = tsk.infer(0.3, 0.0)  # near 0.5, far 0.5: k_d = 1.5
    hi, _ = tsk.infer(0.5, 0.0)  # far only: k_d = 2
    assert (lo, mid, hi) == pytest.approx((0.1, 0.45, 1.0))


# ------------------------------------------------------------------ inputs and outputs


def test_a_chair_behind_the_reference_drives_forward_and_one_ahead_brakes() -> None:
    tsk = _tsk()
    ref = _at_rest()
    behind = tsk.step(0.0, 0.01, ref, _est(-0.3, 0.0, 0.0))
    # d_e = 0.3 m: near 0.5, far 0.5; theta_e = 0: small -> k_d = (1.0 + 2.0) / 2
    assert behind.v_mps == pytest.approx(1.5 * 0.3 * math.tanh(0.3 / 0.02))
    assert behind.omega_radps == pytest.approx(0.0, abs=1e-12)
    ahead = tsk.step(0.0, 0.01, ref, _est(0.2, 0.0, 0.0))
    assert ahead.v_mps < -0.1
    assert tsk.internals()["fuzzy.d_e_m"] == pytest.approx(-0.2, rel=1e-6)


def test_a_chair_beside_the_reference_is_not_sent_back_and_forth() -> None:
    tsk = _tsk()
    ref = _at_rest()
    for x_e in (-1e-4, 0.0, 1e-4):  # the sign of x_e flips: d_e must stay ~0
        cmd = tsk.step(0.0, 0.01, ref, _est(x_e, -0.3, 0.0))
        assert abs(cmd.v_mps) < 0.01
        # it turns toward the path (left, omega > 0): the carrot is up and ahead
        assert cmd.omega_radps > 0.5


def test_heading_error_is_wrapped_and_the_wheels_turn_the_chair_back() -> None:
    tsk = _tsk()
    ref = _at_rest()
    cmd = tsk.step(0.0, 0.01, ref, _est(0.0, 0.0, 0.5 + 4.0 * math.pi))
    theta = tsk.internals()["fuzzy.theta_e_rad"]
    assert theta == pytest.approx(0.5, abs=1e-9)
    vl, vr = tsk.internals()["fuzzy.v_left_mps"], tsk.internals()["fuzzy.v_right_mps"]
    assert vl > vr  # heading left of the carrot: the left wheel runs faster, turning right
    assert cmd.omega_radps == pytest.approx((vr - vl) / (2.0 * B))
    assert cmd.v_mps == pytest.approx(0.5 * (vl + vr))
    assert cmd.omega_radps < 0.0


def test_theta_is_the_bearing_of_the_carrot_ahead_of_the_virtual_robot() -> None:
    tsk = _tsk()
    ref = ReferenceSample(0.0, 1.0, 2.0, math.pi / 2, 0.0, 0.0)
    # chair 0.3 m right of the reference (x + 0.3), facing the path heading
    tsk.step(0.0, 0.01, ref, _est(1.3, 2.0, math.pi / 2))
    # carrot at (1, 2.3): bearing from (1.3, 2) is 135 deg; heading 90 deg -> theta = -45 deg
    assert tsk.internals()["fuzzy.theta_e_rad"] == pytest.approx(-math.pi / 4)


def test_wheel_speeds_are_scaled_together_at_the_chairs_wheel_limit() -> None:
    limits = LimitParams(wheel_max_radps=0.5 / GEOM.wheel_radius_m)  # 0.5 m/s at the rim
    tsk = _tsk(limits=limits)
    cmd = tsk.step(0.0, 0.01, _at_rest(), _est(-2.0, 0.0, 0.3))
    vl, vr = tsk.internals()["fuzzy.v_left_mps"], tsk.internals()["fuzzy.v_right_mps"]
    assert max(abs(vl), abs(vr)) == pytest.approx(0.5)
    unlimited = _tsk().infer(tsk.internals()["fuzzy.d_e_m"], 0.3)
    assert vl / vr == pytest.approx(unlimited[0] / unlimited[1])  # same turn radius
    assert math.isfinite(cmd.v_mps)


def test_it_stops_for_good_at_the_end_of_the_route() -> None:
    tsk = _tsk()
    ref = _at_rest(done=True)
    cmd = tsk.step(90.0, 0.01, ref, _est(-0.02, 0.01, 0.01))
    assert (cmd.v_mps, cmd.omega_radps) == (0.0, 0.0)
    # parked: a later estimate jump does not restart it
    cmd = tsk.step(90.01, 0.01, ref, _est(-0.2, 0.0, 0.0))
    assert (cmd.v_mps, cmd.omega_radps) == (0.0, 0.0)
    assert tsk.internals()["parked"] == 1.0


def test_bad_membership_breakpoints_are_a_configuration_error() -> None:
    with pytest.raises(ConfigError, match="d_far_m"):
        _tsk(ResilientTSK.Params(d_near_m=0.5, d_far_m=0.4))
    with pytest.raises(ConfigError, match="theta_large_rad"):
        _tsk(ResilientTSK.Params(theta_small_rad=0.5, theta_large_rad=0.5))


def test_the_gains_file_section_loads_with_its_declared_defaults() -> None:
    assert registry.load_params("resilient") == ResilientTSK.Params()


finite = st.floats(-1e4, 1e4, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(finite, finite, st.floats(-100, 100), finite, finite, st.floats(-100, 100))
def test_commands_are_finite_and_within_the_rim_bound_for_any_finite_input(
    x: float, y: float, h: float, xr: float, yr: float, hr: float
) -> None:
    tsk = _tsk(ResilientTSK.Params(), limits=LimitParams())
    cmd = tsk.step(1.0, 0.01, ReferenceSample(1.0, xr, yr, hr, 1.0, 0.2), _est(x, y, h))
    assert math.isfinite(cmd.v_mps) and math.isfinite(cmd.omega_radps)
    lim = LimitParams().wheel_max_radps * GEOM.wheel_radius_m
    assert abs(cmd.v_mps) + B * abs(cmd.omega_radps) <= lim + 1e-9


def test_non_finite_estimates_give_a_stop_not_an_exception() -> None:
    tsk = _tsk()
    cmd = tsk.step(0.0, 0.01, _at_rest(), _est(math.nan, 0.0, 0.0))
    assert (cmd.v_mps, cmd.omega_radps) == (0.0, 0.0)


# ------------------------------------------------------------------ closed loop


def _simulate(tsk: ResilientTSK, traj, pose: tuple[float, float, float], tail_s: float = 4.0):
    """Unicycle with a 40 ms first-order velocity lag, the law at 100 Hz."""
    x, y, h = pose
    v = w = 0.0
    dt = 0.01
    log = []
    for k in range(int((traj.duration_s + tail_s) / dt)):
        t = k * dt
        ref = traj.sample(t)
        cmd = tsk.step(t, dt, ref, StateEstimate(t, x, y, h, v, w))
        for _ in range(5):
            v += (cmd.v_mps - v) * (dt / 5) / 0.04
            w += (cmd.omega_radps - w) * (dt / 5) / 0.04
            x += v * math.cos(h) * dt / 5
            y += v * math.sin(h) * dt / 5
            h += w * dt / 5
        log.append((t, tracking_error(x, y, h, ref), cmd))
    return log


def test_the_chair_trails_the_reference_by_about_v_over_k_d_and_parks_at_the_end(
    short,
) -> None:
    params = ResilientTSK.Params()
    tsk = _tsk(params, short, LimitParams())
    log = _simulate(tsk, short, (0.0, 0.0, 0.0))
    # at the cruise speed (1 m/s) on the first straight: the lag of a P law without
    # feed-forward, d_e = v / k_d with k_d between the near-small and far-small gains
    lag = [-e.x_e_m for t, e, _ in log if 3.0 <= t <= 3.5]
    assert 1.0 / params.k_d_far_small < min(lag) and max(lag) < 1.0 / params.k_d_near_small
    _, e, cmd = log[-1]
    assert math.hypot(e.x_e_m, e.y_e_m) < params.stop_radius_m
    assert (cmd.v_mps, cmd.omega_radps) == (0.0, 0.0)


@pytest.mark.parametrize(
    "pose",
    [(0.0, -0.3, 0.0), (0.0, 0.0, math.pi / 2), (0.0, 0.0, -math.pi / 2)],
    ids=["start-right-of-path", "start-heading-90", "start-heading-minus-90"],
)
def test_hazard_starts_converge_to_the_trailing_regime(short, pose) -> None:
    tsk = _tsk(ResilientTSK.Params(), short, LimitParams())
    log = _simulate(tsk, short, pose)
    assert all(math.isfinite(c.v_mps) and math.isfinite(c.omega_radps) for _, _, c in log)
    lateral = [abs(e.y_e_m) for t, e, _ in log if 6.0 <= t <= 8.0]
    assert max(lateral) < 0.1
