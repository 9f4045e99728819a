"""ANTIFRAGILE as the paper defines it: a real switch, no speed blend, curvature regimes."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from controller.config import GeometryParams, LimitParams, load_config
from controller.tracking import registry
from controller.tracking.antifragile import Antifragile, switch
from controller.types import ReferenceSample, StateEstimate, Trajectory, tracking_error
from dbc.runtime.errors import ConfigError

ROOT = Path(__file__).resolve().parents[4]
GEOM = GeometryParams()
#: The believed motor the registry passes (controller.toml [motor]).
MOTOR = load_config().motor


class Line:
    """A virtual robot on the x axis at constant speed."""

    def __init__(self, v: float = 1.0, duration: float = 30.0) -> None:
        self.v, self.duration_s = v, duration

    def sample(self, t: float) -> ReferenceSample:
        return ReferenceSample(t, self.v * t, 0.0, 0.0, self.v, 0.0)


#: Chair limits wide enough never to act, so that the law's own (a_c, omega_c) are applied.
WIDE = LimitParams(
    v_max_mps=3.0, v_reverse_max_mps=3.0, accel_max_mps2=5.0, decel_max_mps2=5.0,
    jerk_max_mps3=500.0, omega_max_radps=10.0, alpha_max_radps2=100.0, wheel_max_radps=50.0,
)  # fmt: skip


def make(
    traj: Trajectory | None = None, *, limits: LimitParams | None = None, **over: float
) -> Antifragile:
    p = registry.load_params("antifragile", over or None)
    return Antifragile(p, GEOM, traj or Line(), motor=MOTOR, limits=limits or LimitParams())


def _one_step(ctl: Antifragile, ref: ReferenceSample, x, y, h, v, w, dt: float = 1.0):
    est = StateEstimate(ref.t_s, x, y, h, v, w)
    ctl.reset(est, ref.t_s)
    cmd = ctl.step(ref.t_s, dt, ref, est)
    return cmd, ctl.internals()


def test_the_sign_is_a_switch_at_the_scale_of_the_tracking_error() -> None:
    w = Antifragile.Params().sign_width_m
    assert w <= 0.001
    # at the route's y_e RMSE (~5 mm) the switch is fully engaged (tanh(5 mm / 2 cm) = 0.24)
    assert switch(0.005, w) == 1.0 and switch(-0.005, w) == -1.0
    assert switch(0.0005, 0.001) == 0.5  # a saturation inside its threshold
    assert (switch(1e-12, 0.0), switch(-1e-12, 0.0), switch(0.0, 0.0)) == (1.0, -1.0, 0.0)


def test_the_coupling_sign_follows_y_e_at_low_speed_too() -> None:
    """No speed blend: D = v cos(phi_e) + l0 sgn(y_e) at every speed, as in the paper."""
    ref = Line(0.4).sample(1.0)
    ctl = make(Line(0.4))
    l0 = ctl.p.lambda0_mps
    for ye in (-0.01, 0.01):
        _, i = _one_step(ctl, ref, ref.x_m, ye, 0.05, 0.4, 0.0)
        assert i["sign"] == math.copysign(1.0, ye)
        assert i["authority_mps"] == pytest.approx(0.4 * math.cos(0.05) + l0 * i["sign"])


def test_omega_switches_when_y_e_changes_side() -> None:
    """The variable structure acts: crossing the path flips s2's coupling term by 2 l0 phi_e."""
    ctl = make()
    ref = Line().sample(1.0)
    pe = 0.05
    _, a = _one_step(ctl, ref, ref.x_m, 0.003, pe, 1.0, 0.0)
    _, b = _one_step(ctl, ref, ref.x_m, -0.003, pe, 1.0, 0.0)
    l0 = ctl.p.lambda0_mps
    assert a["s2_mps"] - b["s2_mps"] == pytest.approx(
        2 * l0 * pe
        + 2 * ctl.p.lambda2_per_s * ctl.lateral_bound_m * math.tanh(0.003 / ctl.lateral_bound_m),
        rel=1e-6,
    )
    assert a["omega_c_radps"] != pytest.approx(b["omega_c_radps"], abs=1e-3)


def test_the_regime_is_the_sign_of_the_planned_paths_curvature() -> None:
    """Eq. (curvature) of the reference: k < 0 antifragile (base gains), otherwise fragile
    (rapid gains); the chair's own motion does not change it."""
    base = Line().sample(1.0)
    right = dataclasses.replace(base, curvature_1pm=-0.5)
    left = dataclasses.replace(base, curvature_1pm=0.5)
    ctl = make()
    for w in (0.3, -0.3):  # the deviation bending away or back: no say in the regime
        _, af = _one_step(ctl, right, right.x_m, 0.02, 0.05, 1.0, w)
        assert af["regime_fragile"] == 0.0 and af["curvature"] == -0.5
        _, fr = _one_step(ctl, left, left.x_m, 0.02, 0.05, 1.0, w)
        assert fr["regime_fragile"] == 1.0 and fr["curvature"] == 0.5
    # a straight (k = 0, or within the dead band) is "otherwise": fragile
    wobble = dataclasses.replace(base, curvature_1pm=-0.5 * ctl.p.curvature_deadband_1pm)
    assert _one_step(ctl, wobble, base.x_m, 0.02, 0.05, 1.0, 0.0)[1]["regime_fragile"] == 1.0


def test_the_fragile_regime_gets_the_rapid_reaching_gains() -> None:
    """Same state; on a left bend (fragile) the law reaches its surface faster than on a
    right bend (antifragile) by fragile_gain."""
    base = Line().sample(1.0)
    ctl = make()
    _, fr = _one_step(
        ctl, dataclasses.replace(base, curvature_1pm=0.2), base.x_m, 0.02, 0.05, 1.0, 0.3
    )
    _, af = _one_step(
        ctl, dataclasses.replace(base, curvature_1pm=-0.2), base.x_m, 0.02, 0.05, 1.0, 0.3
    )
    assert fr["omega_c_radps"] < af["omega_c_radps"]  # rapid: turns right harder
    one = make(fragile_gain=1.0)
    _, fr1 = _one_step(
        one, dataclasses.replace(base, curvature_1pm=0.2), base.x_m, 0.02, 0.05, 1.0, 0.3
    )
    assert fr1["omega_c_radps"] == pytest.approx(af["omega_c_radps"])


def test_activity_counts_regimes_layers_and_the_papers_l0_condition() -> None:
    base = Line().sample(1.0)
    ctl = make()
    est = _placed(base, 0.0, 0.02, 0.05, 1.0, 0.0)
    ctl.reset(est, 1.0)
    # y_e > 0, phi_e > 0 pointing away, l0 |phi_e| against l2 |y_e|
    ctl.step(1.0, 0.01, dataclasses.replace(base, curvature_1pm=-0.3), est)
    ctl.step(1.01, 0.01, base, est)
    act = ctl.activity()
    assert act["ticks"] == 2 and act["regime_fragile"] == 1 and act["regime_flips"] == 1
    p = ctl.p
    fails = p.lambda0_mps * 0.05 >= p.lambda2_per_s * ctl.lateral_bound_m * math.tanh(
        0.02 / ctl.lateral_bound_m
    )
    assert act["l0_condition_fails"] == (2 if fails else 0)
    assert 0 <= act["outside_boundary2"] <= 2
    ctl.reset(est, 2.0)
    assert ctl.activity()["ticks"] == 0


def test_the_turn_rate_makes_s2_follow_the_reaching_law() -> None:
    """Finite differences of s2 (recomputed here) along the kinematics equal -Q2 s2 - P2 sat.

    ``sgn(y_e)`` is held at its value, as the paper differentiates it (piecewise constant);
    the third state lies inside the 1 mm saturation, where that is the only approximation.
    """
    traj = Line()
    for ye, pe, w in ((0.03, 0.1, 0.0), (-0.04, -0.05, 0.1), (0.0005, 0.02, -0.1)):
        ctl = make(traj, limits=WIDE, omega_priority_radps=8.0)
        p = ctl.p
        ref = traj.sample(2.0)
        x, y, h, v = ref.x_m - 0.01, ye, pe, 1.0
        # a 0.1 s step: the widest limits' rates (alpha 100 rad/s^2) cannot bind over it
        cmd, i = _one_step(ctl, ref, x, y, h, v, w, dt=0.1)
        a, wc = i["a_c_mps2"], cmd.omega_radps
        sig = i["sign"]
        eps = 1e-5

        def s2_at(hh: float, x=x, y=y, h=h, v=v, a=a, wc=wc, p=p, sig=sig, ctl=ctl) -> float:
            vv = v + a * hh
            hd = h + wc * hh
            xx = x + v * math.cos(h) * hh
            yy = y + v * math.sin(h) * hh + 0.5 * (a * math.sin(h) + v * wc * math.cos(h)) * hh**2
            r = traj.sample(2.0 + hh)
            e = tracking_error(xx, yy, hd, r)
            ye_d = vv * math.sin(e.phi_e_rad) - r.omega_radps * e.x_e_m
            yb = ctl.lateral_bound_m * math.tanh(e.y_e_m / ctl.lateral_bound_m)
            return ye_d + p.lambda2_per_s * yb + p.lambda0_mps * sig * e.phi_e_rad

        s2 = i["s2_mps"]
        assert s2 == pytest.approx(s2_at(0.0), abs=1e-12)
        boost = p.fragile_gain if i["regime_fragile"] else 1.0
        z = max(-1.0, min(1.0, s2 / i["layer2_mps"]))
        want = -(p.q2_per_s * s2 + p.p2_mps2 * z) * boost
        assert (s2_at(eps) - s2_at(-eps)) / (2 * eps) == pytest.approx(want, abs=2e-4)


def _placed(ref: ReferenceSample, xe: float, ye: float, pe: float, v: float, w: float):
    """A chair at the path errors ``(xe, ye, pe)`` moving with ``(v, w)``."""
    c, s = math.cos(ref.heading_rad), math.sin(ref.heading_rad)
    x, y = ref.x_m + c * xe - s * ye, ref.y_m + s * xe + c * ye
    return StateEstimate(ref.t_s, x, y, ref.heading_rad + pe, v, w)


def test_error_rates_match_finite_differences_of_the_paper_errors(short) -> None:
    """Eq. derrorvector with the estimated twist, against central differences along it."""
    ctl = make(short)
    h = 1e-5
    for i in range(40):
        t = 1.0 + (short.duration_s - 2.0) * i / 39
        ref = short.sample(t)
        est = _placed(
            ref, 0.1 * math.sin(3 * i), 0.1 * math.cos(5 * i), 0.4 * math.sin(i), 0.8, 0.3
        )
        ctl.reset(est, t)
        ctl.step(t, 0.01, ref, est)
        it = ctl.internals()
        e = []
        for sgn in (1.0, -1.0):
            x = est.x_m + sgn * h * est.v_mps * math.cos(est.heading_rad)
            y = est.y_m + sgn * h * est.v_mps * math.sin(est.heading_rad)
            e.append(
                tracking_error(x, y, est.heading_rad + sgn * h * 0.3, short.sample(t + sgn * h))
            )
        assert (e[0].x_e_m - e[1].x_e_m) / (2 * h) == pytest.approx(it["x_e_dot_mps"], abs=1e-6)
        assert (e[0].y_e_m - e[1].y_e_m) / (2 * h) == pytest.approx(it["y_e_dot_mps"], abs=1e-6)


def test_acceleration_stays_finite_and_continuous_through_a_perpendicular_heading(short) -> None:
    """The division by cos(phi_e) blends into speed matching: no singular growth at 90 deg."""
    # limits and a steering priority that do not bind: the law's own a_c
    ctl = make(short, limits=WIDE, omega_priority_radps=8.0)
    ref = short.sample(6.0)
    prev = None
    for i in range(-180, 181):
        pe = math.radians(i)
        est = _placed(ref, -0.05, 0.02, pe, 0.5, ref.omega_radps)
        ctl.reset(est, 6.0)
        ctl.step(6.0, 0.01, ref, est)
        it = ctl.internals()
        a = it["a_c_mps2"]
        assert math.isfinite(a) and math.isfinite(it["omega_c_radps"])
        if prev is not None and abs(i) != 180:
            assert abs(a - prev) < 0.25  # m/s^2 per degree: continuous through the blend
            if 62 <= abs(i) <= 118:  # speed matching alone: k v_d sin(phi_e) per radian
                assert abs(a - prev) < 0.05
        prev = a
        if abs(pe) >= math.acos(ctl.p.cos_off):
            assert it["gate_accel"] == 0.0


def test_config_rules_name_the_keys() -> None:
    with pytest.raises(ConfigError, match="lateral_speed_lo_mps"):
        make(lambda0_mps=0.3)
    with pytest.raises(ConfigError, match="cos_full"):
        make(cos_off=0.9, cos_full=0.8)


def _closed_loop(ctl, traj, seconds: float, *, dy: float = 0.0, dh: float = 0.0):
    s0 = traj.sample(0.0)
    x, y, h, v, w = s0.x_m, s0.y_m + dy, s0.heading_rad + dh, 0.0, 0.0
    ctl.reset(StateEstimate(0.0, x, y, h, v, w), 0.0)
    errs, cmds = [], []
    for k in range(int(seconds / 0.01)):
        t = 0.01 * k
        cmd = ctl.step(t, 0.01, traj.sample(t), StateEstimate(t, x, y, h, v, w))
        v += (cmd.v_mps - v) * 0.01 / 0.03
        w += (cmd.omega_radps - w) * 0.01 / 0.03
        x, y, h = x + v * math.cos(h) * 0.01, y + v * math.sin(h) * 0.01, h + w * 0.01
        errs.append(tracking_error(x, y, h, traj.sample(t + 0.01)))
        cmds.append(cmd)
    return errs, cmds


def test_it_tracks_the_short_route_and_stops_exactly_at_its_end(short) -> None:
    errs, cmds = _closed_loop(make(short), short, short.duration_s + 3.0)
    assert max(math.hypot(e.x_e_m, e.y_e_m) for e in errs) < 0.03
    assert max(abs(e.phi_e_rad) for e in errs) < math.radians(4.0)
    assert (cmds[-1].v_mps, cmds[-1].omega_radps) == (0.0, 0.0)


@pytest.mark.parametrize("dy", [-0.3, 0.3])
def test_recovers_from_a_lateral_offset_at_rest_on_either_side(short, dy: float) -> None:
    """y_e < 0 at low speed is where the paper's manifold is unstable (D = v - l0)."""
    errs, cmds = _closed_loop(make(short), short, 14.0, dy=dy)
    assert abs(errs[-1].y_e_m) < 0.02
    # at rest it does not spin after the lateral error
    assert all(abs(c.omega_radps) < 0.05 for c in cmds[:20])


def test_unusable_estimates_brake_to_exactly_zero() -> None:
    ctl = make()
    ref = Line().sample(1.0)
    ctl.reset(StateEstimate(1.0, ref.x_m, 0.0, 0.0, 1.0, 0.0), 1.0)
    ctl.vc = 1.0
    bad = StateEstimate(1.0, math.nan, 0.0, 0.0, 1.0, 0.0)
    cmds = [ctl.step(1.0 + 0.01 * k, 0.01, ref, bad) for k in range(300)]
    assert all(math.isfinite(c.v_mps) and math.isfinite(c.omega_radps) for c in cmds)
    assert (cmds[-1].v_mps, cmds[-1].omega_radps) == (0.0, 0.0)
    assert ctl.internals()["braking"] == 2.0


def test_gains_toml_section_loads_with_its_declared_defaults() -> None:
    p = registry.load_params("antifragile")
    assert p == Antifragile.Params()
    assert p.omega_priority_radps < LimitParams().omega_max_radps  # the priority acts
    ctl = make()
    assert ctl.drive_gains == ctl.inner.drive_gains  # the singular-perturbation PID
