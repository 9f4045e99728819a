"""ROBUST (Solea et al. on the dynamic model): equivalent control, surfaces, signs, degenerate input."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from controller.config import BodyParams, GeometryParams, LimitParams, load_config
from controller.planner import load_route, plan
from controller.tracking import registry
from controller.tracking.robust import RobustSMC, effective_inertias, sat
from controller.types import ReferenceSample, StateEstimate, Trajectory, tracking_error, wrap_angle

from .trajectories import Circle

ROOT = Path(__file__).resolve().parents[4]
GEOM = GeometryParams()
BODY = BodyParams()


def make(traj: Trajectory | None = None, **over: float) -> RobustSMC:
    p = registry.load_params("robust", over or None)
    return RobustSMC(p, GEOM, traj or Circle(), body=BODY, limits=LimitParams())


def _surfaces(ctl: RobustSMC, ref: ReferenceSample, x, y, h, v, w) -> tuple[float, float]:
    """s1, s2 recomputed from their definitions (module doc), independently of the controller:
    (v, w) is the commanded twist, the model's state."""
    p = ctl.p
    e = tracking_error(x, y, h, ref)
    xe_d = -ref.v_mps + v * math.cos(e.phi_e_rad) + ref.omega_radps * e.y_e_m
    pe_d = w - ref.omega_radps
    s1 = xe_d + p.k1_per_s * e.x_e_m
    k2, zeta, v_top = p.k2_per_s, p.lateral_damping, ctl.limits.v_max_mps
    k0 = (k2 / (2 * zeta * v_top)) ** 2
    big_y = p.heading_max_rad * k2 / (k0 * v_top)
    s2 = pe_d + k2 * e.phi_e_rad + ref.v_mps * k0 * big_y * math.tanh(e.y_e_m / big_y)
    return s1, s2


def test_alpha_and_beta_are_the_papers_of_the_believed_chair() -> None:
    ctl = make()
    m, inertia = effective_inertias(BODY, GEOM)
    r, b = GEOM.wheel_radius_m, GEOM.half_track_m
    assert m == pytest.approx(BODY.mass_kg + 2 * BODY.wheel_inertia_kgm2 / r**2)
    assert inertia == pytest.approx(
        BODY.yaw_inertia_kgm2 + 2 * b * b * BODY.wheel_inertia_kgm2 / r**2
    )
    assert ctl.alpha == pytest.approx(1.0 / (r * m))
    assert ctl.beta == pytest.approx(b / (r * inertia))
    heavy_body = BodyParams(mass_kg=260.0, yaw_inertia_kgm2=30.0)
    heavy = RobustSMC(ctl.p, GEOM, Circle(), body=heavy_body, limits=load_config().limits)
    assert heavy.alpha < 0.6 * ctl.alpha and heavy.beta < 0.6 * ctl.beta


@pytest.mark.parametrize(
    "dx, dy, dh, dv, dw",
    [(-0.05, 0.02, 0.1, -0.1, 0.05), (0.03, -0.04, -0.2, 0.05, -0.1), (0.2, 0.1, 0.4, 0.2, 0.3)],
)
def test_the_torques_make_both_surfaces_follow_the_reaching_law(dx, dy, dh, dv, dw) -> None:
    """Propagating the believed dynamic model with (u1, u2) gives s' = -Q s - P sat(s/Phi)."""
    traj = Circle()
    ctl = make(traj)
    p = ctl.p
    t = 1.0
    ref = traj.sample(t)
    c, s = math.cos(ref.heading_rad), math.sin(ref.heading_rad)
    x, y = ref.x_m + c * dx - s * dy, ref.y_m + s * dx + c * dy
    h, v, w = ref.heading_rad + dh, ref.v_mps + dv, ref.omega_radps + dw
    ctl.reset(StateEstimate(t, x, y, h, v, w), t)
    ctl.step(t, 0.01, ref, StateEstimate(t, x, y, h, v, w))
    i = ctl.internals()
    acc, wdot = ctl.alpha * i["surface.u1_nm"], ctl.beta * i["surface.u2_nm"]
    eps = 1e-5

    def at(sign: float) -> tuple[float, float]:
        hh = sign * eps
        # second-order Taylor step of the unicycle with v' = acc, omega' = wdot
        vv, ww = v + acc * hh, w + wdot * hh
        hd = h + w * hh + 0.5 * wdot * hh * hh
        xx = x + v * math.cos(h) * hh + 0.5 * (acc * math.cos(h) - v * w * math.sin(h)) * hh * hh
        yy = y + v * math.sin(h) * hh + 0.5 * (acc * math.sin(h) + v * w * math.cos(h)) * hh * hh
        return _surfaces(ctl, traj.sample(t + hh), xx, yy, hd, vv, ww)

    (a1, a2), (b1, b2) = at(1.0), at(-1.0)
    s1, s2 = i["surface.s1_mps"], i["surface.s2_radps"]
    assert (s1, s2) == pytest.approx(_surfaces(ctl, ref, x, y, h, v, w), abs=1e-12)
    want1 = -p.q1_per_s * s1 - p.p1_mps2 * sat(s1 / p.boundary1_mps)
    want2 = -p.q2_per_s * s2 - p.p2_radps2 * sat(s2 / p.boundary2_radps)
    assert (a1 - b1) / (2 * eps) == pytest.approx(want1, abs=1e-4)
    assert (a2 - b2) / (2 * eps) == pytest.approx(want2, abs=1e-4)


def test_equivalent_control_is_minus_d_over_alpha_cos_and_minus_d_over_beta() -> None:
    """On the surfaces (s = 0) the torque is the equivalent control alone."""
    traj = Circle()
    ctl = make(traj)
    ref = traj.sample(2.0)
    est = StateEstimate(2.0, ref.x_m, ref.y_m, ref.heading_rad, ref.v_mps, ref.omega_radps)
    ctl.reset(est, 2.0)
    ctl.step(2.0, 0.01, ref, est)
    i = ctl.internals()
    assert i["surface.s1_mps"] == pytest.approx(0.0, abs=1e-12)
    assert i["surface.u1_nm"] == pytest.approx(i["surface.u_eq1_nm"])
    assert i["surface.u2_nm"] == pytest.approx(i["surface.u_eq2_nm"])
    # constant-speed circle, on the reference: nothing to compensate
    assert i["surface.u_eq1_nm"] == pytest.approx(0.0, abs=1e-9)
    assert i["surface.u_eq2_nm"] == pytest.approx(0.0, abs=1e-9)


def test_signs_a_chair_behind_speeds_up_and_one_left_of_the_path_turns_right() -> None:
    traj = Circle()
    ref = traj.sample(0.0)
    ctl = make(traj)
    behind = StateEstimate(0.0, ref.x_m - 0.1, ref.y_m, ref.heading_rad, ref.v_mps, ref.omega_radps)
    ctl.reset(behind, 0.0)
    ctl.step(0.0, 0.01, ref, behind)
    assert ctl.internals()["surface.u1_nm"] > 0.0
    left = StateEstimate(0.0, ref.x_m, ref.y_m + 0.1, ref.heading_rad, ref.v_mps, ref.omega_radps)
    ctl.reset(left, 0.0)
    cmd = ctl.step(0.0, 0.01, ref, left)
    assert ctl.internals()["surface.u2_nm"] < 0.0 and cmd.omega_radps < ref.omega_radps


@pytest.mark.parametrize("dh", [math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-9, 2.0, math.pi])
def test_cos_phi_e_through_zero_gives_finite_torques_and_no_x_e_push(dh: float) -> None:
    traj = Circle()
    ref = traj.sample(0.0)
    ctl = make(traj)
    est = StateEstimate(0.0, ref.x_m - 0.2, ref.y_m, ref.heading_rad + dh, 0.3, 0.0)
    ctl.reset(est, 0.0)
    cmd = ctl.step(0.0, 0.01, ref, est)
    i = ctl.internals()
    assert all(math.isfinite(val) for val in i.values())
    assert math.isfinite(cmd.v_mps) and math.isfinite(cmd.omega_radps)
    if math.cos(wrap_angle(dh)) <= 1e-6:
        assert abs(i["surface.u1_nm"]) < 1e-3  # N*m: the 1/cos(phi_e) gain has faded out
    c_max = math.cos(ctl.p.heading_max_rad)
    assert ctl.inv_cos(c_max) == pytest.approx(1.0 / c_max)  # continuous


def test_non_finite_input_brakes_within_the_envelope_instead_of_raising() -> None:
    traj = Circle()
    ref = traj.sample(0.0)
    ctl = make(traj)
    ctl.reset(StateEstimate(0.0, ref.x_m, ref.y_m, 0.0, 0.8, 0.2), 0.0)
    cmds = [
        ctl.step(0.01 * k, 0.01, ref, StateEstimate(0, math.nan, 0, 0, 0.8, 0.2))
        for k in range(200)
    ]
    assert all(math.isfinite(c.v_mps) and math.isfinite(c.omega_radps) for c in cmds)
    assert cmds[1].v_mps == pytest.approx(cmds[0].v_mps - ctl.limits.decel_max_mps2 * 0.01)
    assert cmds[-1].v_mps == 0.0 and cmds[-1].omega_radps == 0.0


def test_commands_stay_inside_the_envelope_from_a_bad_start() -> None:
    traj = Circle()
    ctl = make(traj)
    ref0 = traj.sample(0.0)
    x, y, h, v, w = ref0.x_m - 1.0, ref0.y_m + 0.5, 1.0, 0.0, 0.0
    ctl.reset(StateEstimate(0.0, x, y, h, v, w), 0.0)
    lim = ctl.limits
    prev = 0.0
    for k in range(1500):
        t = 0.01 * k
        cmd = ctl.step(t, 0.01, traj.sample(t), StateEstimate(t, x, y, h, v, w))
        assert -lim.v_reverse_max_mps <= cmd.v_mps <= lim.v_max_mps
        assert abs(cmd.omega_radps) <= lim.omega_max_radps
        assert (
            -lim.decel_max_mps2 * 0.01 - 1e-12
            <= cmd.v_mps - prev
            <= lim.accel_max_mps2 * 0.01 + 1e-12
        )
        prev = cmd.v_mps
        v, w = cmd.v_mps, cmd.omega_radps
        x, y, h = x + v * math.cos(h) * 0.01, y + v * math.sin(h) * 0.01, h + w * 0.01
    e = tracking_error(x, y, h, traj.sample(15.0))
    assert math.hypot(e.x_e_m, e.y_e_m) < 0.02


def _closed_loop(ctl, traj, seconds: float, *, dy: float = 0.0, omega_bias: float = 0.0):
    """Unicycle at 100 Hz with a 30 ms first-order drive lag; returns the errors."""
    s0 = traj.sample(0.0)
    x, y, h, v, w = s0.x_m, s0.y_m + dy, s0.heading_rad, 0.0, 0.0
    ctl.reset(StateEstimate(0.0, x, y, h, v, w), 0.0)
    errs = []
    for k in range(int(seconds / 0.01)):
        t = 0.01 * k
        cmd = ctl.step(t, 0.01, traj.sample(t), StateEstimate(t, x, y, h, v, w))
        v += (cmd.v_mps - v) * 0.01 / 0.03
        w += (cmd.omega_radps + omega_bias - w) * 0.01 / 0.03
        x, y, h = x + v * math.cos(h) * 0.01, y + v * math.sin(h) * 0.01, h + w * 0.01
        errs.append(tracking_error(x, y, h, traj.sample(t + 0.01)))
    return errs, cmd


def test_it_tracks_the_short_route_with_drive_lag_and_parks_at_its_end() -> None:
    traj = plan(load_route(ROOT / "scenarios" / "routes" / "short.toml"))
    ctl = make(traj)
    errs, cmd = _closed_loop(ctl, traj, traj.duration_s + 3.0)
    rms_y = math.sqrt(sum(e.y_e_m**2 for e in errs) / len(errs))
    assert max(math.hypot(e.x_e_m, e.y_e_m) for e in errs) < 0.03
    assert rms_y < 0.005
    assert ctl.internals()["parked"] == 1.0 and (cmd.v_mps, cmd.omega_radps) == (0.0, 0.0)


def test_a_start_right_of_the_path_is_steered_out_once_the_reference_moves() -> None:
    traj = plan(load_route(ROOT / "scenarios" / "routes" / "short.toml"))
    errs, _ = _closed_loop(make(traj), traj, 12.0, dy=-0.3)
    assert abs(errs[-1].y_e_m) < 0.02
    assert max(abs(e.phi_e_rad) for e in errs) < 1.0


def test_the_gains_file_section_loads_with_its_declared_defaults() -> None:
    assert registry.load_params("robust") == RobustSMC.Params()
    ctl = registry.create("robust", GEOM, Circle(), body=load_config().body)
    assert isinstance(ctl, RobustSMC) and ctl.name == "robust"
    assert ctl.drive_gains is not None and ctl.drive_gains.vel_gain == 70.0  # the plain PID


def test_the_heading_the_surface_asks_for_never_passes_heading_max() -> None:
    """On s2 = 0 with phi_e' = 0 the surface asks phi_e = -v_d L(y_e) / k2: bounded by
    heading_max_rad for every lateral error at every speed up to the chair's top speed."""
    ctl = make()
    v_top = ctl.limits.v_max_mps
    asked = [
        abs(vd * ctl.lateral_term(ye)[0] / ctl.p.k2_per_s)
        for vd in (0.2, 0.8, 1.1, v_top)
        for ye in (-10.0, -1.0, -0.13, -0.01, 0.0, 0.01, 0.13, 1.0, 10.0)
    ]
    assert max(asked) <= ctl.p.heading_max_rad + 1e-12
    assert max(asked) > 0.95 * ctl.p.heading_max_rad  # the bound is reached, not undershot


def test_k0_gives_the_declared_lateral_damping_at_the_top_speed() -> None:
    ctl = make(k2_per_s=5.0, lateral_damping=0.7)
    v_top = ctl.limits.v_max_mps
    # small errors on s2 = 0: y'' + k2 y' + k0 v^2 y = 0, damping k2 / (2 v sqrt(k0))
    assert 5.0 / (2 * v_top * math.sqrt(ctl.k0_per_m2)) == pytest.approx(0.7)
    assert ctl.lateral_term(1e-6)[1] == pytest.approx(ctl.k0_per_m2)  # slope k0 at y_e = 0


@pytest.mark.parametrize(
    "over, key",
    [
        ({"q1_per_s": 8.0, "boundary1_mps": 0.2, "p1_mps2": 0.5}, "q1_per_s * boundary1_mps"),
        ({"q2_per_s": 8.0, "boundary2_radps": 0.5, "p2_radps2": 3.0}, "alpha_max_radps2"),
    ],
)
def test_gains_whose_reaching_law_saturates_inside_its_layer_are_named(over, key, caplog) -> None:
    """Not an error (the envelope still bounds every command; a chair with tighter limits
    runs), but the law says which relation of its sizing fails."""
    with caplog.at_level("WARNING", logger="controller.tracking.robust"):
        make(**over)
    assert re.search(re.escape(key), caplog.text)


def test_the_shipped_gains_meet_the_envelope_relations() -> None:
    """The sizing of docs/controllers.md "ROBUST" on the chair's limits: inside the boundary
    layers the reaching law asks no more than the chair's accelerations, and the tuned and
    the default gains both keep it."""
    from tools.tuning import gainsfile

    lim = load_config().limits
    tuned = gainsfile.load(ROOT / "scenarios" / "tuning" / "gains.toml")["robust"]["gains"]
    for over in ({}, tuned):
        p = registry.load_params("robust", over or None)
        a_lin = min(lim.accel_max_mps2, lim.decel_max_mps2)
        assert p.q1_per_s * p.boundary1_mps + p.p1_mps2 <= a_lin
        assert p.q2_per_s * p.boundary2_radps + p.p2_radps2 <= lim.alpha_max_radps2


def test_the_rates_are_bounded_by_a_third_of_the_drive_loop() -> None:
    from dbc.runtime.errors import ConfigError

    with pytest.raises(ConfigError, match="q2_per_s"):
        registry.load_params("robust", {"q2_per_s": 15.0})


@pytest.mark.parametrize("dy, dh", [(2.0, 0.0), (-1.5, 1.2), (0.5, -2.5)])
def test_from_a_large_error_it_rejoins_the_path_within_the_envelope(dy: float, dh: float) -> None:
    """Metres and radians off, with drive lag: back on the path, every command inside the
    chair's limits, and once it has turned towards the path the heading error stays within
    the bound the surface declares."""
    traj = Circle(v=1.0, radius=4.0, duration=40.0)
    ctl = make(traj)
    lim = ctl.limits
    s0 = traj.sample(0.0)
    x, y, h, v, w = s0.x_m - math.sin(s0.heading_rad) * dy, s0.y_m + dy, s0.heading_rad + dh, 0, 0
    ctl.reset(StateEstimate(0.0, x, y, h, v, w), 0.0)
    worst_phi = 0.0
    for k in range(3000):
        t = 0.01 * k
        ref = traj.sample(t)
        cmd = ctl.step(t, 0.01, ref, StateEstimate(t, x, y, h, v, w))
        assert -lim.v_reverse_max_mps <= cmd.v_mps <= lim.v_max_mps
        assert abs(cmd.omega_radps) <= lim.omega_max_radps
        v += (cmd.v_mps - v) * 0.01 / 0.04
        w += (cmd.omega_radps - w) * 0.01 / 0.04
        x, y, h = x + v * math.cos(h) * 0.01, y + v * math.sin(h) * 0.01, h + w * 0.01
        if k > 1000:
            worst_phi = max(worst_phi, abs(tracking_error(x, y, h, ref).phi_e_rad))
    e = tracking_error(x, y, h, traj.sample(30.0))
    assert math.hypot(e.x_e_m, e.y_e_m) < 0.01
    assert abs(e.phi_e_rad) < 0.01
    assert worst_phi < ctl.p.heading_max_rad


def test_a_persistent_yaw_disturbance_leaves_the_offset_the_surface_predicts() -> None:
    """A yaw-rate error the model does not know (a flat tire's slower wheel, which the
    encoders do not see): the switching term carries it (s2 held at k2 dw / (Q2 + P2/Phi2),
    about half the layer), and the chair settles where s2 = 0 balances the correction,
    y_e = dw / (v_d k0): no integral action, as in Solea's law."""
    traj = Circle(v=1.0, radius=4.0, duration=40.0)
    ctl = make(traj)
    dw = 0.2
    s0 = traj.sample(0.0)
    x, y, h, v, w = s0.x_m, s0.y_m, s0.heading_rad, 1.0, s0.omega_radps
    ctl.reset(StateEstimate(0.0, x, y, h, v, w), 0.0)
    for k in range(2500):
        t = 0.01 * k
        cmd = ctl.step(t, 0.01, traj.sample(t), StateEstimate(t, x, y, h, v, w))
        v += (cmd.v_mps - v) * 0.01 / 0.04
        w += (cmd.omega_radps - dw - w) * 0.01 / 0.04
        x, y, h = x + v * math.cos(h) * 0.01, y + v * math.sin(h) * 0.01, h + w * 0.01
    p = ctl.p
    i = ctl.internals()
    z2 = i["surface.s2_radps"] / p.boundary2_radps
    assert abs(z2) == pytest.approx(
        p.k2_per_s * dw / (p.q2_per_s * p.boundary2_radps + p.p2_radps2), rel=0.1
    )
    assert p.p2_radps2 * abs(z2) > 2 * p.q2_per_s * abs(
        i["surface.s2_radps"]
    )  # switching carries it
    ye = tracking_error(x, y, h, traj.sample(25.0)).y_e_m
    assert abs(ye) == pytest.approx(dw / ctl.k0_per_m2, rel=0.3)  # the circle adds curvature
    assert ctl.activity()["ticks"] == 2500
