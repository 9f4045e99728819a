"""ROBUST: sliding surfaces are reached and held (kinematic simulation), hazards, inner loop."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.config import GeometryParams
from controller.planner import load_route, plan
from controller.tracking import registry
from controller.tracking.robust_kinematic import PlainPid
from controller.tracking.robust_kinematic import RobustKinematicSMC as RobustSMC
from controller.types import DriveGains, ReferenceSample, StateEstimate, tracking_error

from .trajectories import Circle

ROOT = Path(__file__).resolve().parents[4]
GEOM = GeometryParams()


def _simulate(ctl, traj, pose, seconds, *, lag_s=0.0, omega_bias=0.0, v0=0.0):
    """Unicycle at 100 Hz; optional first-order velocity lag and a turn-rate disturbance."""
    x, y, h = pose
    v, w = v0, 0.0
    dt = 0.01
    ctl.reset(StateEstimate(0.0, x, y, h, v, w), 0.0)
    log = []
    for k in range(int(seconds / dt)):
        t = k * dt
        ref = traj.sample(t)
        cmd = ctl.step(t, dt, ref, StateEstimate(t, x, y, h, v, w))
        surf = dict(ctl.internals())
        sub = 5
        for _ in range(sub):
            if lag_s > 0.0:
                v += (cmd.v_mps - v) * (dt / sub) / lag_s
                w += (cmd.omega_radps + omega_bias - w) * (dt / sub) / lag_s
            else:
                v, w = cmd.v_mps, cmd.omega_radps + omega_bias
            x += v * math.cos(h) * dt / sub
            y += v * math.sin(h) * dt / sub
            h += w * dt / sub
        log.append((t, tracking_error(x, y, h, traj.sample(t + dt)), cmd, surf))
    return log


def _reaching_time(q: float, p: float, s0: float) -> float:
    """Gao's reaching time of s' = -Q s - P sgn(s) (the paper's Eq. reachingtime)."""
    return math.log((q * abs(s0) + p) / p) / q


# ------------------------------------------------------------------ reaching and sliding


def test_both_surfaces_are_reached_in_finite_time_and_held() -> None:
    p = RobustSMC.Params()
    ctl = RobustSMC(p, GEOM, Circle())
    # start 0.3 m behind, 0.2 m left, 0.3 rad off, already moving like the reference
    ref0 = Circle().sample(0.0)
    log = _simulate(ctl, Circle(), (ref0.x_m - 0.3, ref0.y_m + 0.2, 0.3), 12.0, v0=0.8)
    s1 = np.array([s["surface.s1_mps"] for *_, s in log])
    s2 = np.array([s["surface.s2_rad"] for *_, s in log])
    assert abs(s1[0]) > 3 * p.boundary_x and abs(s2[0]) > 3 * p.boundary_phi
    # outside the boundary layer s' = -Q s - P sgn(s); inside it decays at Q + P / Phi
    t1 = _reaching_time(p.reach_x, p.switch_x, s1[0] - math.copysign(p.boundary_x, s1[0]))
    t2 = _reaching_time(p.reach_phi, p.switch_phi, s2[0] - math.copysign(p.boundary_phi, s2[0]))
    k1, k2 = int(1.5 * t1 / 0.01) + 10, int(1.5 * t2 / 0.01) + 10
    assert np.all(np.abs(s1[k1:]) < p.boundary_x)
    assert np.all(np.abs(s2[k2:]) < p.boundary_phi)
    # on the surfaces the errors go to zero
    e = log[-1][1]
    assert abs(e.x_e_m) < 0.002 and abs(e.y_e_m) < 0.005 and abs(e.phi_e_rad) < 0.01


def test_the_surfaces_decay_at_the_reaching_law_rate_inside_the_boundary_layer() -> None:
    p = RobustSMC.Params()
    ctl = RobustSMC(p, GEOM, Circle())
    ref0 = Circle().sample(0.0)
    log = _simulate(ctl, Circle(), (ref0.x_m - 0.01, ref0.y_m, 0.0), 2.0, v0=0.8)
    s1 = np.array([s["surface.s1_mps"] for *_, s in log])
    # s1' = -(Q1 + P1/Phi1) s1 inside the layer: 0.5 s later s1 has shrunk by exp(-rate 0.5)
    rate = p.reach_x + p.switch_x / p.boundary_x
    ratio = s1[60] / s1[10]
    assert ratio == pytest.approx(math.exp(-rate * 0.5), rel=0.25)


def test_the_switching_term_rejects_a_turn_rate_disturbance() -> None:
    """A constant yaw-rate bias (a flat tyre, say) is held off by the heading surface."""
    p = RobustSMC.Params()
    bias = 0.3  # rad/s
    ref0 = Circle().sample(0.0)
    log = _simulate(
        RobustSMC(p, GEOM, Circle()), Circle(), (ref0.x_m, ref0.y_m, 0.0), 15.0, omega_bias=bias
    )
    s2 = np.array([s["surface.s2_rad"] for *_, s in log[500:]])
    # steady state inside the layer: (Q2 + P2/Phi2) s2 = bias ...
    s2_ss = bias / (p.reach_phi + p.switch_phi / p.boundary_phi)
    assert np.max(np.abs(s2)) == pytest.approx(s2_ss, rel=0.1)
    # ... held by a lateral offset atan(k_y y_e) = s2 (phi_e -> 0), not by a drift
    ye = np.array([e.y_e_m for _, e, *_ in log[500:]])
    assert np.max(np.abs(ye)) == pytest.approx(math.tan(s2_ss) / p.k_y, rel=0.1)
    assert np.ptp(ye[-500:]) < 1e-3


def test_it_tracks_the_short_route_with_drive_lag_and_stops_at_the_end(short) -> None:
    p = RobustSMC.Params()
    log = _simulate(
        RobustSMC(p, GEOM, short), short, (0.0, 0.0, 0.0), short.duration_s + 3.0, lag_s=0.04
    )
    pos = [math.hypot(e.x_e_m, e.y_e_m) for t, e, *_ in log if t <= short.duration_s]
    assert max(pos) < 0.01
    _, _, cmd, surf = log[-1]
    assert (cmd.v_mps, cmd.omega_radps) == (0.0, 0.0) and surf["parked"] == 1.0


# ------------------------------------------------------------------ hazards


def test_a_start_right_of_the_path_at_rest_turns_toward_it_only_once_the_reference_moves(
    short,
) -> None:
    p = RobustSMC.Params()
    log = _simulate(RobustSMC(p, GEOM, short), short, (0.0, -0.3, 0.0), 10.0, lag_s=0.04)
    assert abs(log[0][2].omega_radps) < 1e-9  # reference at rest: no turning on the spot
    first_turn = next(t for t, _, c, _ in log if c.omega_radps > 0.05)
    assert short.sample(first_turn).v_mps > 0.0
    assert max(c.omega_radps for *_, c, _ in log) > 0.3  # toward the path (left)
    late = [abs(e.y_e_m) for t, e, *_ in log if t > 8.0]
    assert max(late) < 0.01


@pytest.mark.parametrize("dphi", [math.pi / 2, -math.pi / 2, 3.0])
def test_a_large_initial_heading_error_turns_first_then_tracks(short, dphi) -> None:
    p = RobustSMC.Params()
    log = _simulate(RobustSMC(p, GEOM, short), short, (0.0, 0.0, dphi), 10.0, lag_s=0.04)
    # the x_e control fades out between ~70 and 90 deg: no driving off sideways or away
    # while the heading surface turns the chair
    away = [c.v_mps for t, e, c, _ in log if abs(e.phi_e_rad) > 1.45]
    assert len(away) >= 5 and max(map(abs, away)) < 0.05
    late = [math.hypot(e.x_e_m, e.y_e_m) for t, e, *_ in log if t > 8.0]
    assert max(late) < 0.01


def test_a_reference_that_pauses_is_followed_to_rest_and_on_again() -> None:
    traj = plan(load_route(ROOT / "scenarios" / "routes" / "short-pause.toml"))
    log = _simulate(
        RobustSMC(RobustSMC.Params(), GEOM, traj),
        traj,
        (0.0, 0.0, 0.0),
        traj.duration_s,
        lag_s=0.04,
    )
    paused = [
        (t, c)
        for t, _, c, _ in log
        if traj.sample(t).v_mps == 0.0 and 1.0 < t < traj.duration_s - 1.0
    ]
    assert len(paused) > 250  # the 3 s pause
    assert max(abs(c.v_mps) for _, c in paused[50:]) < 0.01
    assert max(math.hypot(e.x_e_m, e.y_e_m) for _, e, *_ in log) < 0.01


# ------------------------------------------------------------------ bounds, degradation


finite = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(
    finite,
    finite,
    st.floats(-50, 50),
    finite,
    st.floats(-5, 5),
    st.floats(-3, 3),
    st.floats(-10, 10),
)
def test_commands_are_finite_and_within_the_declared_bounds(x, y, h, v, w, vd, wd) -> None:
    p = RobustSMC.Params()
    ctl = RobustSMC(p, GEOM, Circle())
    ref = ReferenceSample(0.0, 0.0, 0.0, 0.3, vd, wd, a_mps2=0.4, alpha_radps2=-1.0)
    for _ in range(3):
        cmd = ctl.step(0.0, 0.01, ref, StateEstimate(0.0, x, y, h, v, w))
        assert math.isfinite(cmd.v_mps) and math.isfinite(cmd.omega_radps)
        assert p.v_min_mps <= cmd.v_mps <= p.v_max_mps
        assert abs(cmd.omega_radps) <= p.omega_max_radps


def test_the_speed_command_changes_at_most_by_the_acceleration_bounds() -> None:
    p = RobustSMC.Params()
    ctl = RobustSMC(p, GEOM, Circle())
    ref = Circle().sample(0.0)
    prev = 0.0
    for k in range(100):
        cmd = ctl.step(k * 0.01, 0.01, ref, StateEstimate(0.0, -5.0, 0.0, 0.0, 0.0, 0.0))
        assert (
            -p.decel_max_mps2 * 0.01 - 1e-12 <= cmd.v_mps - prev <= p.accel_max_mps2 * 0.01 + 1e-12
        )
        prev = cmd.v_mps


def test_non_finite_input_ramps_the_speed_down_instead_of_raising() -> None:
    p = RobustSMC.Params()
    ctl = RobustSMC(p, GEOM, Circle())
    ctl.reset(StateEstimate(0.0, 0.0, 0.0, 0.0, 1.0, 0.0), 0.0)
    cmd = ctl.step(
        0.0, 0.01, Circle().sample(0.0), StateEstimate(0.0, math.nan, 0.0, 0.0, 1.0, 0.0)
    )
    assert cmd.v_mps == pytest.approx(1.0 - p.decel_max_mps2 * 0.01)
    assert cmd.omega_radps == 0.0


# ------------------------------------------------------------------ inner loop


def test_the_inner_loop_is_a_plain_pid_in_the_drive_units() -> None:
    ctl = registry.create("robust-kinematic", GEOM, Circle())
    g = ctl.drive_gains
    assert isinstance(g, DriveGains)
    pid = PlainPid()
    assert (g.vel_gain, g.vel_integrator_gain, g.vel_derivative_gain) == (
        pid.vel_gain,
        pid.vel_integrator_gain,
        pid.vel_derivative_gain,
    )
    # all three terms present, inside the DBC's signal ranges
    assert (
        0 < g.vel_gain <= 100
        and 0 < g.vel_integrator_gain <= 1000
        and 0 < g.vel_derivative_gain <= 100
    )
    # the documented design: (1 + G Kd) s^2 + G Kp s + G Ki with zeta = 1, omega_n = 25 rad/s
    J = 0.14 + 0.30**2 * 130.0 / 2  # I_w + r^2 m / 2: the common mode (docs/physics.md)
    G = 0.9 * 32.0 / (2 * math.pi * J)
    a2 = 1 + G * g.vel_derivative_gain
    wn = math.sqrt(G * g.vel_integrator_gain / a2)
    zeta = G * g.vel_gain / a2 / (2 * wn)
    assert wn == pytest.approx(25.0, rel=0.02)
    assert zeta == pytest.approx(1.0, rel=0.02)


def test_the_gains_file_section_loads_with_its_declared_defaults() -> None:
    assert registry.load_params("robust-kinematic") == RobustSMC.Params()
