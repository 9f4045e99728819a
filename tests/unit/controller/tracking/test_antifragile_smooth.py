"""ANTIFRAGILE tracking law: derivation checked by finite differences, hazard rules, scenarios.

The sliding surfaces are recomputed here from their definitions (docs/antifragile.md),
independently of the controller, and differentiated numerically along the kinematic
model driven by the controller's own commands: ``s' = -Q s - P sat(s / Phi)`` must hold
wherever the paper's law is in force.  Synthetic time throughout.
"""

from __future__ import annotations

import copy
import itertools
import math
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from controller.config import GeometryParams, LimitParams, MotorParams
from controller.limits import CommandLimiter
from controller.planner import load_route, plan
from controller.tracking import registry
from controller.tracking.antifragile_smooth import AntifragileSmooth as Antifragile
from controller.tracking.antifragile_smooth import min_authority, smoothstep
from controller.types import ReferenceSample, StateEstimate, Trajectory, tracking_error
from dbc.runtime import params
from dbc.runtime.errors import ConfigError

ROOT = Path(__file__).resolve().parents[4]
GEOMETRY = GeometryParams()

#: An envelope wide enough never to act, so the law itself can be checked.
WIDE = {
    "accel_max_mps2": 5.0,
    "decel_max_mps2": 5.0,
    "jerk_max_mps3": 1e4,
    "alpha_max_radps2": 1e4,
    "omega_max_radps": 10.0,
    "omega_priority_radps": 10.0,
    "v_max_mps": 3.0,
    "v_reverse_max_mps": 3.0,
    "wheel_max_radps": 50.0,
}


@pytest.fixture(scope="module")
def short_pause() -> Trajectory:
    return plan(load_route(ROOT / "scenarios" / "routes" / "short-pause.toml"))


def make(traj: Trajectory, **overrides: Any) -> Antifragile:
    p = params.replace(Antifragile.Params(), overrides, source="test")
    return Antifragile(p, GEOMETRY, traj, motor=MotorParams())


# ----------------------------------------------------------------- independent model


def surfaces(
    p: Antifragile.Params, ref: ReferenceSample, x: float, y: float, h: float, v: float
) -> tuple[float, float]:
    """s1, s2 from their definitions (the docs' rules 1-3), not from the controller."""
    e = tracking_error(x, y, h, ref)
    xe, ye, pe = e.x_e_m, e.y_e_m, e.phi_e_rad
    xe_d = -ref.v_mps + v * math.cos(pe) + ref.omega_radps * ye
    ye_d = v * math.sin(pe) - ref.omega_radps * xe
    chi, _ = smoothstep((v - p.sign_speed_lo_mps) / (p.sign_speed_hi_mps - p.sign_speed_lo_mps))
    kappa, _ = smoothstep(v / p.lateral_speed_mps)
    sig = chi * math.tanh(ye / p.sign_width_m) + 1.0 - chi
    yb = p.lateral_bound_m * math.tanh(ye / p.lateral_bound_m)
    s1 = xe_d + p.lambda1_per_s * xe
    s2 = ye_d + p.lambda2_per_s * kappa * yb + p.lambda0_mps * sig * pe
    return s1, s2


def reaching(p: Antifragile.Params, s1: float, s2: float, v: float) -> tuple[float, float]:
    """Gao's reaching law; Q2, P2 move from their rest to their moving values with v."""

    def sat(z: float) -> float:
        return max(-1.0, min(1.0, z))

    kappa, _ = smoothstep(v / p.lateral_speed_mps)
    q2 = p.q2_rest_per_s + (p.q2_per_s - p.q2_rest_per_s) * kappa
    p2 = p.p2_rest_mps2 + (p.p2_mps2 - p.p2_rest_mps2) * kappa
    return (
        -p.q1_per_s * s1 - p.p1_mps2 * sat(s1 / p.boundary1_mps),
        -q2 * s2 - p2 * sat(s2 / p.boundary2_mps),
    )


@dataclass
class Chair:
    """Unicycle whose speed integrates the commanded acceleration."""

    x: float
    y: float
    h: float
    v: float

    def advanced(self, a: float, w: float, dt: float) -> Chair:
        def f(s: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
            return (s[3] * math.cos(s[2]), s[3] * math.sin(s[2]), w, a)

        s0 = (self.x, self.y, self.h, self.v)
        k1 = f(s0)
        k2 = f(tuple(s + 0.5 * dt * k for s, k in zip(s0, k1, strict=True)))  # type: ignore[arg-type]
        k3 = f(tuple(s + 0.5 * dt * k for s, k in zip(s0, k2, strict=True)))  # type: ignore[arg-type]
        k4 = f(tuple(s + dt * k for s, k in zip(s0, k3, strict=True)))  # type: ignore[arg-type]
        n = [
            s + dt / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)
            for s, a1, a2, a3, a4 in zip(s0, k1, k2, k3, k4, strict=True)
        ]
        return Chair(*n)


def placed(ref: ReferenceSample, xe: float, ye: float, pe: float, v: float) -> Chair:
    c, s = math.cos(ref.heading_rad), math.sin(ref.heading_rad)
    return Chair(ref.x_m + c * xe - s * ye, ref.y_m + s * xe + c * ye, ref.heading_rad + pe, v)


def command_at(ctl: Antifragile, t: float, ref: ReferenceSample, chair: Chair):
    """The law's (a_c, omega_c) at a state whose measured turn rate is the commanded one."""
    w = ref.omega_radps
    for _ in range(30):  # the paper's a_c uses the measured omega: make it consistent
        c = copy.deepcopy(ctl)
        c.reset(StateEstimate(t, chair.x, chair.y, chair.h, chair.v, w), t)
        cmd = c.step(t, 0.01, ref, StateEstimate(t, chair.x, chair.y, chair.h, chair.v, w))
        if abs(cmd.omega_radps - w) < 1e-13:
            break
        w = cmd.omega_radps
    return c.ac, cmd.omega_radps, c.internals()


# ----------------------------------------------------------------- derivation


def test_error_rates_match_finite_differences_of_the_paper_errors(short: Trajectory) -> None:
    rnd = random.Random(3)
    ctl = make(short, **WIDE)
    for _ in range(40):
        t = rnd.uniform(1.0, short.duration_s - 1.0)
        ref = short.sample(t)
        chair = placed(
            ref, rnd.uniform(-0.1, 0.1), rnd.uniform(-0.1, 0.1), rnd.uniform(-0.4, 0.4), 0.8
        )
        a, w, it = command_at(ctl, t, ref, chair)
        h = 1e-5
        fwd, back = chair.advanced(a, w, h), chair.advanced(a, w, -h)
        ef = tracking_error(fwd.x, fwd.y, fwd.h, short.sample(t + h))
        eb = tracking_error(back.x, back.y, back.h, short.sample(t - h))
        assert (ef.x_e_m - eb.x_e_m) / (2 * h) == pytest.approx(it["x_e_dot_mps"], abs=1e-7)
        assert (ef.y_e_m - eb.y_e_m) / (2 * h) == pytest.approx(it["y_e_dot_mps"], abs=1e-7)


@pytest.mark.parametrize(
    ("v_lo", "v_hi"),
    [(0.05, 0.3), (0.3, 0.7), (0.7, 1.3)],  # rest band, both speed schedules, paper's sign
)
def test_the_law_makes_the_surfaces_follow_the_reaching_law_exactly(
    short: Trajectory, v_lo: float, v_hi: float
) -> None:
    """One-step check at random states: every term of s1', s2' (docs) is in the law."""
    rnd = random.Random(int(v_lo * 100))
    ctl = make(short, **WIDE)
    p = ctl.p
    checked = 0
    for _ in range(60):
        t = rnd.uniform(0.5, short.duration_s - 0.5)
        ref = short.sample(t)
        chair = placed(
            ref,
            rnd.uniform(-0.08, 0.08),
            rnd.uniform(-0.06, 0.06),  # inside and outside the sign's boundary layer
            rnd.uniform(-0.3, 0.3),
            rnd.uniform(v_lo, v_hi),
        )
        a, w, it = command_at(ctl, t, ref, chair)
        if it["gate_accel"] < 1.0 or it["gate_omega"] < 1.0:
            continue
        s1, s2 = surfaces(p, ref, chair.x, chair.y, chair.h, chair.v)
        assert (s1, s2) == pytest.approx((it["s1_mps"], it["s2_mps"]), abs=1e-12)
        h = 1e-5
        fwd, back = chair.advanced(a, w, h), chair.advanced(a, w, -h)
        f1, f2 = surfaces(p, short.sample(t + h), fwd.x, fwd.y, fwd.h, fwd.v)
        b1, b2 = surfaces(p, short.sample(t - h), back.x, back.y, back.h, back.v)
        u1, u2 = reaching(p, s1, s2, chair.v)
        assert (f1 - b1) / (2 * h) == pytest.approx(u1, abs=2e-6)
        assert (f2 - b2) / (2 * h) == pytest.approx(u2, abs=2e-6)
        checked += 1
    assert checked >= 40


def test_in_closed_loop_the_surfaces_reach_the_boundary_layer_at_the_reaching_rate(
    short: Trajectory,
) -> None:
    """Kinematic chair driven by the commands at 1 kHz: finite differences of s follow u."""
    ctl = make(short, **WIDE)
    p = ctl.p
    t, dt = 3.0, 0.001
    ref = short.sample(t)
    chair = placed(ref, -0.05, 0.04, 0.1, ref.v_mps)
    ctl.reset(StateEstimate(t, chair.x, chair.y, chair.h, chair.v, 0.0), t)
    w_meas = ref.omega_radps
    worst = 0.0
    s_hist = []
    for k in range(3000):
        ref = short.sample(t)
        est = StateEstimate(t, chair.x, chair.y, chair.h, chair.v, w_meas)
        cmd = ctl.step(t, dt, ref, est)
        s = surfaces(p, ref, chair.x, chair.y, chair.h, chair.v)
        u = reaching(p, s[0], s[1], chair.v)
        nxt = chair.advanced(ctl.ac, cmd.omega_radps, dt)
        s_next = surfaces(p, short.sample(t + dt), nxt.x, nxt.y, nxt.h, nxt.v)
        for i in (0, 1):
            if k > 0:  # the first measured omega is not the law's own
                worst = max(worst, abs((s_next[i] - s[i]) / dt - u[i]))
        s_hist.append(s)
        chair, w_meas, t = nxt, cmd.omega_radps, t + dt
    assert abs(s_hist[0][0]) > p.boundary1_mps and abs(s_hist[0][1]) > p.boundary2_mps
    assert worst < 2e-3  # O(dt): the measured omega lags the command by one step
    assert all(abs(s1) < 0.2 * p.boundary1_mps for s1, _ in s_hist[-500:])
    assert all(abs(s2) < 0.2 * p.boundary2_mps for _, s2 in s_hist[-500:])


# ----------------------------------------------------------------- hazards


def test_the_omega_denominator_is_positive_at_rest_and_never_crosses_zero_with_ye_negative(
    short: Trajectory,
) -> None:
    ctl = make(short, **WIDE)
    p = ctl.p
    ref = short.sample(5.0)
    # the paper's own denominator v cos(pe) - l0 would cross zero at v = l0 here
    dens = []
    for i in range(151):
        v = 1.5 * i / 150
        _, _, it = command_at(ctl, 5.0, ref, placed(ref, 0.0, -0.1, 0.0, v))
        dens.append(it["authority_mps"])
        assert it["gate_omega"] == 1.0
    assert dens[0] == pytest.approx(p.lambda0_mps, rel=1e-6)  # at rest: D = l0
    assert min(dens) >= p.authority_full_mps
    assert min(dens) == pytest.approx(min_authority(p)[1], abs=0.02)
    paper = [1.5 * i / 150 - p.lambda0_mps for i in range(151)]
    assert min(paper) < 0.0 < max(paper)
    # and at rest with y_e = 0 exactly the law is well posed
    _, w, it = command_at(ctl, 5.0, ref, placed(ref, 0.0, 0.0, 0.0, 0.0))
    assert it["authority_mps"] == pytest.approx(p.lambda0_mps) and math.isfinite(w)


def test_omega_does_not_jump_when_ye_crosses_zero(short: Trajectory) -> None:
    ref = short.sample(8.0)
    v, pe = 1.0, 0.1  # the paper's sign fully engaged

    def jump(ctl: Antifragile) -> float:
        _, w_minus, _ = command_at(ctl, 8.0, ref, placed(ref, 0.0, -1e-7, pe, v))
        _, w_plus, _ = command_at(ctl, 8.0, ref, placed(ref, 0.0, 1e-7, pe, v))
        return abs(w_plus - w_minus)

    smooth = jump(make(short, **WIDE))
    hard = jump(make(short, sign_width_m=1e-9, **WIDE))  # the paper's sgn(y_e)
    assert hard > 0.1  # rad/s in one tick, at every crossing
    assert smooth < 1e-3 * hard


def test_acceleration_stays_finite_and_continuous_through_a_perpendicular_heading(
    short: Trajectory,
) -> None:
    ctl = make(short)
    ref = short.sample(6.0)
    prev = None
    for i in range(-180, 181):
        pe = math.radians(i)
        a, w, it = command_at(ctl, 6.0, ref, placed(ref, -0.05, 0.02, pe, 0.5))
        assert math.isfinite(a) and math.isfinite(w)
        if prev is not None and abs(i) != 180:
            assert abs(a - prev) < 0.2  # m/s^2 per degree: no singular growth near 90 deg
        prev = a
        if abs(pe) >= math.acos(ctl.p.cos_off):
            assert it["gate_accel"] == 0.0


def test_unusable_estimates_and_references_brake_to_exactly_zero(short: Trajectory) -> None:
    ctl = make(short)
    ref = short.sample(5.0)
    ctl.reset(StateEstimate(5.0, ref.x_m, ref.y_m, ref.heading_rad, ref.v_mps, 0.3), 5.0)
    bad = [
        StateEstimate(5.0, math.nan, ref.y_m, ref.heading_rad, ref.v_mps, 0.0),
        StateEstimate(5.0, ref.x_m, ref.y_m, ref.heading_rad, ref.v_mps, 0.0, valid=False),
    ]
    speeds = []
    for k in range(300):
        cmd = ctl.step(5.0, 0.01, ref, bad[k % 2])
        assert math.isfinite(cmd.v_mps) and math.isfinite(cmd.omega_radps)
        speeds.append(cmd.v_mps)
    assert all(b <= a for a, b in itertools.pairwise(speeds))
    assert speeds[0] > 0.0 and speeds[-1] == 0.0 and cmd.omega_radps == 0.0
    assert ctl.internals()["braking"] == 2.0


def test_configure_time_rules_name_the_keys(short: Trajectory) -> None:
    with pytest.raises(ConfigError, match="authority_full_mps"):
        make(short, lambda0_mps=0.9)  # y_e < 0 would make D cross zero inside the band
    with pytest.raises(ConfigError, match="sign_speed_hi_mps"):
        make(short, sign_speed_lo_mps=0.9)
    with pytest.raises(ConfigError, match="cos_full"):
        make(short, cos_off=0.9)


# ----------------------------------------------------------------- closed loop scenarios


@dataclass
class Run:
    max_pos_m: float
    max_phi_rad: float
    final_pos_m: float
    max_omega_radps: float
    ticks_at_omega_limit: int
    limiter_box: int
    limiter_wheel: int
    end_command: tuple[float, float]
    non_finite: int


def simulate(
    traj: Trajectory,
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    *,
    lag_s: float = 0.04,
    tail_s: float = 3.0,
    flat_left_m: float = 0.0,
) -> Run:
    """Wheels with first-order speed lag behind the node's limiter, 100 Hz.

    ``flat_left_m``: the left rolling radius shrinks by this much from t = 2 s (time
    constant 2 s) while the controller keeps believing 0.30 m.
    """
    ctl = make(traj)
    lim = CommandLimiter(LimitParams(), GEOMETRY.half_track_m, GEOMETRY.wheel_radius_m)
    r0 = traj.sample(0.0)
    chair = placed(r0, *offset, 0.0)
    v = w = wl = wr = 0.0
    r, b = GEOMETRY.wheel_radius_m, GEOMETRY.half_track_m
    ctl.reset(StateEstimate(0.0, chair.x, chair.y, chair.h, 0.0, 0.0), 0.0)
    dt, sub = 0.01, 10
    worst_pos = worst_phi = worst_w = 0.0
    at_limit = non_finite = 0
    k = 0
    while k * dt < traj.duration_s + tail_s:
        t = k * dt
        ref = traj.sample(t)
        raw = ctl.step(t, dt, ref, StateEstimate(t, chair.x, chair.y, chair.h, v, w))
        non_finite += not (math.isfinite(raw.v_mps) and math.isfinite(raw.omega_radps))
        cmd = lim.apply(raw, dt)
        worst_w = max(worst_w, abs(cmd.omega_radps))
        at_limit += abs(raw.omega_radps) >= ctl.p.omega_max_radps - 1e-9
        r_left = r - flat_left_m * (1.0 - math.exp(-(t - 2.0) / 2.0)) if t > 2.0 else r
        wl_cmd, wr_cmd = (
            (cmd.v_mps - b * cmd.omega_radps) / r,
            (cmd.v_mps + b * cmd.omega_radps) / r,
        )
        for _ in range(sub):
            h = dt / sub
            wl += (wl_cmd - wl) * h / lag_s
            wr += (wr_cmd - wr) * h / lag_s
            v, w = (r * wr + r_left * wl) / 2.0, (r * wr - r_left * wl) / (2.0 * b)
            chair = Chair(
                chair.x + v * math.cos(chair.h) * h, chair.y + v * math.sin(chair.h) * h,
                chair.h + w * h, v,
            )  # fmt: skip
        k += 1
        if t + dt <= traj.duration_s:
            e = tracking_error(chair.x, chair.y, chair.h, traj.sample(t + dt))
            worst_pos = max(worst_pos, math.hypot(e.x_e_m, e.y_e_m))
            worst_phi = max(worst_phi, abs(e.phi_e_rad))
    e = tracking_error(chair.x, chair.y, chair.h, traj.sample(traj.duration_s))
    return Run(
        worst_pos,
        worst_phi,
        math.hypot(e.x_e_m, e.y_e_m),
        worst_w,
        at_limit,
        lim.counters.box,
        lim.counters.wheel,
        (cmd.v_mps, cmd.omega_radps),
        non_finite,
    )


def test_starts_from_rest_tracks_the_route_and_stops_exactly_at_its_end(
    short: Trajectory,
) -> None:
    r = simulate(short)
    assert r.max_pos_m < 0.01 and r.max_phi_rad < math.radians(1.0)
    assert r.final_pos_m < 0.01
    assert r.end_command == (0.0, 0.0)
    assert r.limiter_box == r.limiter_wheel == 0 and r.non_finite == 0


def test_a_pause_in_the_reference_is_held_and_left_cleanly(short_pause: Trajectory) -> None:
    r = simulate(short_pause)
    assert r.max_pos_m < 0.01 and r.max_phi_rad < math.radians(1.0)
    assert r.end_command == (0.0, 0.0)


@pytest.mark.parametrize("side", [-1.0, 1.0])
def test_recovers_from_a_lateral_offset_at_rest_on_either_side(
    short: Trajectory, side: float
) -> None:
    r = simulate(short, (0.0, 0.3 * side, 0.0))
    assert r.max_pos_m < 0.3 + 1e-3  # never further away than it started
    assert r.max_phi_rad < math.radians(35.0)
    assert r.final_pos_m < 0.01
    assert r.ticks_at_omega_limit == 0 and r.limiter_box == 0 and r.non_finite == 0


@pytest.mark.parametrize("side", [-1.0, 1.0])
def test_recovers_from_a_perpendicular_start_turning_in_place_first(
    short: Trajectory, side: float
) -> None:
    r = simulate(short, (0.0, 0.0, side * math.pi / 2))
    assert r.max_pos_m < 0.2  # it falls behind while it turns
    assert r.final_pos_m < 0.01
    assert r.ticks_at_omega_limit == 0 and r.limiter_box == 0 and r.non_finite == 0
    assert r.max_omega_radps <= 1.5 + 1e-9  # the steering-priority budget


def test_a_flat_tyre_within_the_switching_gain_costs_only_centimetres(short: Trajectory) -> None:
    """0.30 -> 0.26 m on the left: a yaw disturbance of about 0.24 v rad/s (< P2 / D)."""
    r = simulate(short, flat_left_m=0.04)
    assert r.max_pos_m < 0.04 and r.max_phi_rad < math.radians(3.0)
    assert r.end_command == (0.0, 0.0) and r.limiter_box == 0


# ----------------------------------------------------------------- configuration


def test_gains_toml_section_loads_and_stays_inside_the_loop_limits() -> None:
    p = registry.load_params("antifragile-smooth")
    assert isinstance(p, Antifragile.Params)
    lim = LimitParams()
    assert p.v_max_mps < lim.v_max_mps and p.v_reverse_max_mps < lim.v_reverse_max_mps
    assert p.accel_max_mps2 < lim.accel_max_mps2 and p.decel_max_mps2 < lim.decel_max_mps2
    assert p.jerk_max_mps3 < lim.jerk_max_mps3
    assert p.omega_max_radps < lim.omega_max_radps
    assert p.alpha_max_radps2 < lim.alpha_max_radps2
    assert p.wheel_max_radps < lim.wheel_max_radps
    assert p.omega_priority_radps < p.omega_max_radps


def test_the_controller_offers_the_inner_loop_gains_for_arming(short: Trajectory) -> None:
    ctl = make(short)
    assert ctl.drive_gains == ctl.inner.drive_gains
    assert ctl.drive_gains.vel_gain > 0.0 and ctl.drive_gains.vel_integrator_gain > 0.0
    with pytest.raises(ConfigError, match="k2"):
        make(short, inner_loop={"k2": 0.5})
