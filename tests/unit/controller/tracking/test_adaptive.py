"""ADAPTIVE (MPC on the dynamic model, OSQP): model, feed-forward, signs, adaptation, integral action."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import osqp
import pytest
import scipy.linalg

from controller.config import BodyParams, GeometryParams, load_config
from controller.tracking import registry
from controller.tracking.adaptive import AdaptiveMPC, continuous_model, discretize
from controller.tracking.qp import SOLVED
from controller.tracking.robust import effective_inertias
from controller.types import ReferenceSample, StateEstimate, Trajectory, tracking_error

from .trajectories import Circle

ROOT = Path(__file__).resolve().parents[4]
GEOM = GeometryParams()
BODY = BodyParams()
#: The chair's limits the registry passes (controller.toml [limits]).
LIMITS = load_config().limits


def make(traj: Trajectory | None = None, *, name: str = "adaptive", **over: float) -> AdaptiveMPC:
    return AdaptiveMPC(
        registry.load_params(name, over or None), GEOM, traj or Circle(), body=BODY, limits=LIMITS
    )


def test_the_discretization_is_the_exact_zero_order_hold() -> None:
    m, inertia = effective_inertias(BODY, GEOM)
    md = BODY.mass_kg * BODY.com_offset_m
    v, w = np.array([0.0, 1.1, 0.5]), np.array([0.0, 0.4, -1.2])
    A, B, E = continuous_model(v, w, m, inertia, md)
    Ad, Bd, Ed = discretize(A, B, E, 0.1)
    for k in range(3):
        M = np.zeros((8, 8))
        M[:5, :5], M[:5, 5:7], M[:5, 7] = A[k], B, E
        ex = scipy.linalg.expm(M * 0.1)
        assert np.allclose(Ad[k], ex[:5, :5], atol=1e-12)
        assert np.allclose(Bd[k], ex[:5, 5:7], atol=1e-12)
        assert np.allclose(Ed[k], ex[:5, 7], atol=1e-12)
    # the model is the dynamic one: force over the believed mass, moment over the inertia
    # inputs F~/m and M~/I: the dynamic model's coupling terms carry m, I and d
    assert B[3, 0] == 1.0 and B[4, 1] == 1.0
    assert A[1, 4, 4] == pytest.approx(-md * 1.1 / inertia)  # the m d v omega coupling
    assert A[1, 3, 4] == pytest.approx(2 * md * 0.4 / m)  # the m d omega^2 term


def test_on_the_reference_the_first_move_is_the_feed_forward() -> None:
    traj = Circle()
    ctl = make(traj)
    ref = traj.sample(3.0)
    est = StateEstimate(3.0, ref.x_m, ref.y_m, ref.heading_rad, ref.v_mps, ref.omega_radps)
    ctl.reset(est, 3.0)
    cmd = ctl.step(3.0, 0.01, ref, est)
    i = ctl.internals()
    assert i["qp.status"] == 1.0
    assert i["model.force_n"] == pytest.approx(i["model.force_ref_n"], abs=2.0)  # N
    assert i["model.moment_nm"] == pytest.approx(i["model.moment_ref_nm"], abs=1.0)
    assert cmd.v_mps == pytest.approx(ref.v_mps, abs=2e-3)
    assert cmd.omega_radps == pytest.approx(ref.omega_radps, abs=2e-3)


def test_signs_behind_speeds_up_left_of_the_path_turns_right() -> None:
    traj = Circle()
    ref = traj.sample(3.0)
    ctl = make(traj)
    behind = StateEstimate(3.0, ref.x_m - 0.1 * math.cos(ref.heading_rad),
                           ref.y_m - 0.1 * math.sin(ref.heading_rad), ref.heading_rad,
                           ref.v_mps, ref.omega_radps)  # fmt: skip
    ctl.reset(behind, 3.0)
    ctl.step(3.0, 0.01, ref, behind)
    assert ctl.internals()["model.force_n"] > ctl.internals()["model.force_ref_n"] + 5.0
    n = (-math.sin(ref.heading_rad), math.cos(ref.heading_rad))
    left = StateEstimate(3.0, ref.x_m + 0.05 * n[0], ref.y_m + 0.05 * n[1], ref.heading_rad,
                         ref.v_mps, ref.omega_radps)  # fmt: skip
    ctl.reset(left, 3.0)
    ctl.step(3.0, 0.01, ref, left)
    assert ctl.internals()["model.moment_nm"] < ctl.internals()["model.moment_ref_nm"] - 1.0


def test_the_weights_rise_with_the_lateral_and_heading_errors() -> None:
    traj = Circle()
    ref = traj.sample(3.0)
    ctl = make(traj)
    p = ctl.p
    scales = []
    for off in (0.0, 0.05, 0.2):
        n = (-math.sin(ref.heading_rad), math.cos(ref.heading_rad))
        est = StateEstimate(3.0, ref.x_m + off * n[0], ref.y_m + off * n[1],
                            ref.heading_rad + off, ref.v_mps, ref.omega_radps)  # fmt: skip
        ctl.reset(est, 3.0)
        ctl.step(3.0, 0.01, ref, est)
        scales.append((ctl.internals()["weights.scale_y"], ctl.internals()["weights.scale_phi"]))
    assert scales[0] == (1.0, 1.0)
    assert 1.0 < scales[1][0] < scales[2][0] == pytest.approx(1.0 + p.adapt_gain)
    assert 1.0 < scales[1][1] < scales[2][1] <= 1.0 + p.adapt_gain


def _closed_loop(ctl, traj, seconds: float, *, omega_bias: float = 0.0, dy: float = 0.0):
    s0 = traj.sample(0.0)
    x, y, h, v, w = s0.x_m, s0.y_m + dy, s0.heading_rad, 0.0, 0.0
    ctl.reset(StateEstimate(0.0, x, y, h, v, w), 0.0)
    errs, cmds = [], []
    for k in range(int(seconds / 0.01)):
        t = 0.01 * k
        cmd = ctl.step(t, 0.01, traj.sample(t), StateEstimate(t, x, y, h, v, w))
        v += (cmd.v_mps - v) * 0.01 / 0.03
        w += (cmd.omega_radps + omega_bias - w) * 0.01 / 0.03
        x, y, h = x + v * math.cos(h) * 0.01, y + v * math.sin(h) * 0.01, h + w * 0.01
        errs.append(tracking_error(x, y, h, traj.sample(t + 0.01)))
        cmds.append(cmd)
    return errs, cmds


def test_it_tracks_the_short_route_solving_every_tick_and_parks(short) -> None:
    ctl = make(short)
    errs, cmds = _closed_loop(ctl, short, short.duration_s + 3.0)
    assert max(math.hypot(e.x_e_m, e.y_e_m) for e in errs) < 0.03
    assert ctl.fallbacks <= 0.01 * ctl.solved
    assert (cmds[-1].v_mps, cmds[-1].omega_radps) == (0.0, 0.0)


INTEGRAL_KEYS = {"disturbance_rate_per_s", "disturbance_max_radps"}


def test_adaptive_is_the_papers_form_without_integral_action() -> None:
    assert registry.load_params("adaptive").disturbance_rate_per_s == 0.0


def test_the_variant_has_adaptives_gains_but_the_integral_keys() -> None:
    a, v = registry.load_params("adaptive"), registry.load_params("adaptive-integral")
    assert type(v) is type(a) and registry.controller_class("adaptive-integral") is AdaptiveMPC
    for f in dataclasses.fields(a):
        if f.name not in INTEGRAL_KEYS:
            assert getattr(v, f.name) == getattr(a, f.name), f.name
    assert (v.disturbance_rate_per_s, v.disturbance_max_radps) == (0.5, 0.5)
    assert "adaptive-integral" in registry.names()
    assert registry.gains_section("ADAPTIVE-INTEGRAL") == "adaptive"
    assert registry.gains_section("adaptive") == "adaptive"


def test_gains_given_for_adaptive_reach_the_variant(tmp_path: Path) -> None:
    """The variant reads adaptive's section (tuned gains too) and changes only its own keys."""
    tuned = {"q_y": 296.57, "r_force": 3.3e-5}
    v = registry.load_params("adaptive-integral", tuned)
    assert (v.q_y, v.r_force, v.disturbance_rate_per_s) == (296.57, 3.3e-5, 0.5)
    gains = tmp_path / "gains.toml"
    gains.write_text("[adaptive]\nq_x = 77.0\ndisturbance_rate_per_s = 0.0\n")
    v = registry.load_params("adaptive-integral", gains_path=gains)
    assert v.q_x == 77.0 and v.disturbance_rate_per_s == 0.5
    # the variant's own keys can still be overridden by name
    v = registry.load_params("adaptive-integral", {"disturbance_rate_per_s": 1.0})
    assert v.disturbance_rate_per_s == 1.0


def test_with_a_yaw_disturbance_the_variants_integral_action_acts_and_adaptive_has_none() -> None:
    """A constant yaw-rate bias (a flat tyre's): the variant estimates it and removes most of
    the offset that adaptive, the paper's form, keeps; adaptive's estimate stays exactly 0."""
    traj = Circle(duration=40.0)
    tail = slice(-1000, None)
    paper = make(traj)
    without, cmds_0 = _closed_loop(paper, traj, 30.0, omega_bias=0.1)
    assert paper.internals()["model.disturbance_omega_radps"] == 0.0
    variant = make(traj, name="adaptive-integral")
    with_i, cmds_i = _closed_loop(variant, traj, 30.0, omega_bias=0.1)
    assert variant.internals()["model.disturbance_omega_radps"] == pytest.approx(0.1, abs=0.01)
    assert (
        max(abs(a.omega_radps - b.omega_radps) for a, b in zip(cmds_0, cmds_i, strict=True))
        > 5e-3  # rad/s
    )
    off_i = max(abs(e.y_e_m) for e in with_i[tail])
    off_0 = max(abs(e.y_e_m) for e in without[tail])
    assert off_0 > 0.002  # the paper's form keeps a steady offset ...
    assert off_i < 0.3 * off_0  # ... the disturbance model removes most of it


def test_the_sparsity_pattern_is_the_same_at_rest_moving_and_turning(short) -> None:
    ctl = make(short)
    pats = []
    for t in (0.0, 5.0, short.duration_s * 0.5):
        ref = short.sample(t)
        d = ctl.qp_data(t, 0.01, ref, StateEstimate(t, ref.x_m, ref.y_m, ref.heading_rad, 0, 0))
        pats.append((d.A.indptr.tobytes(), d.A.indices.tobytes(), d.P.indptr.tobytes()))
        assert np.all(d.P.diagonal() >= 0.0) and d.P.nnz == d.P.shape[0]  # diagonal
    assert pats[0] == pats[1] == pats[2]


def test_non_finite_input_never_raises_and_brakes() -> None:
    traj = Circle()
    ctl = make(traj)
    ref = traj.sample(1.0)
    ctl.reset(StateEstimate(1.0, ref.x_m, ref.y_m, ref.heading_rad, 0.8, 0.4), 1.0)
    bad = StateEstimate(1.0, math.nan, 0.0, 0.0, 0.8, 0.4)
    cmds = [ctl.step(1.0 + 0.01 * k, 0.01, ref, bad) for k in range(400)]
    assert all(math.isfinite(c.v_mps) and math.isfinite(c.omega_radps) for c in cmds)
    assert abs(cmds[-1].v_mps) < 1e-6 and abs(cmds[-1].omega_radps) < 1e-6
    assert ctl.fallbacks == 400


def test_the_gains_file_section_loads_with_its_declared_defaults() -> None:
    assert registry.load_params("adaptive") == AdaptiveMPC.Params()


def _offset(ref: ReferenceSample, along: float, left: float, dphi: float) -> StateEstimate:
    """A chair ``along`` ahead of and ``left`` of the reference, moving with its twist."""
    c, s = math.cos(ref.heading_rad), math.sin(ref.heading_rad)
    return StateEstimate(
        ref.t_s, ref.x_m + c * along - s * left, ref.y_m + s * along + c * left,
        ref.heading_rad + dphi, ref.v_mps, ref.omega_radps,
    )  # fmt: skip


def _warm(ctl: AdaptiveMPC, traj: Trajectory, t: float, est: StateEstimate) -> None:
    """Five ticks up to ``t``: the solver then starts from its previous solution."""
    ctl.reset(est, t - 0.05)
    for k in range(5):
        ctl.step(t - 0.05 + 0.01 * k, 0.01, traj.sample(t - 0.05 + 0.01 * k), est)


def test_step_solves_the_problem_that_qp_data_returns() -> None:
    traj = Circle()
    ctl = make(traj)
    ref = traj.sample(3.0)
    est = _offset(ref, -0.05, 0.04, 0.05)
    _warm(ctl, traj, 3.0, est)
    # the measured turn rate equal to the command: no change of the disturbance estimate
    est = dataclasses.replace(est, omega_radps=ctl._w_c)
    d = ctl.qp_data(3.0, 0.01, ref, est)
    fresh = osqp.OSQP()
    fresh.setup(*d, verbose=False, eps_abs=1e-8, eps_rel=1e-8, max_iter=100000, polishing=True)
    res = fresh.solve(raise_error=False)
    assert res.info.status_val == SOLVED
    exact = ctl.command_from_solution(res.x)
    cmd = ctl.step(3.0, 0.01, ref, est)
    assert ctl.internals()["qp.status"] == SOLVED
    assert cmd.v_mps == pytest.approx(exact.v_mps, abs=2e-3)
    assert cmd.omega_radps == pytest.approx(exact.omega_radps, abs=2e-3)


def test_a_non_solved_status_falls_back_to_the_shifted_previous_plan_and_is_counted() -> None:
    traj = Circle()
    ctl = make(traj)
    p = ctl.p
    t0 = 3.0
    ref = traj.sample(t0)
    est = _offset(ref, -0.05, 0.03, 0.02)
    _warm(ctl, traj, t0, est)
    fb, ticks = ctl.fallbacks, sum(ctl.status_counts.values())
    ctl.step(t0, 0.01, ref, est)
    assert ctl.internals()["qp.status"] == SOLVED and ctl.fallbacks == fb
    plan = ctl._plan.copy()
    # starve the solver: one iteration cannot reach 1e-12 from this far-off state
    ctl._solver.update_settings(max_iter=1, eps_abs=1e-12, eps_rel=1e-12)
    t1 = t0 + 2.5 * p.prediction_step_s  # 2.5 steps later: stage 2 of the old plan
    ref1 = traj.sample(t1)
    before = (ctl._v_c, ctl._w_c)
    cmd = ctl.step(t1, 0.01, ref1, _offset(ref1, 0.4, -0.3, 0.6))
    st = ctl.internals()
    assert st["qp.status"] != SOLVED
    assert st["qp.fallback_used"] == 1.0 and ctl.fallbacks == fb + 1
    assert st["qp.fallbacks"] == fb + 1
    want = ctl._advance(*before, float(plan[2, 0]), float(plan[2, 1]), 0.01)
    assert (cmd.v_mps, cmd.omega_radps) == pytest.approx(want)
    assert sum(ctl.status_counts.values()) == ticks + 2
    # once the plan is used up the fallback brakes
    t2 = t0 + (p.horizon + 1) * p.prediction_step_s
    ref2 = traj.sample(t2)
    cmd2 = ctl.step(t2, 0.01, ref2, _offset(ref2, 0.4, -0.3, 0.6))
    assert cmd2.v_mps < cmd.v_mps and ctl.fallbacks == fb + 2


def test_repeated_failures_restart_the_solver_cold_and_it_recovers() -> None:
    traj = Circle()
    ctl = AdaptiveMPC(
        dataclasses.replace(registry.load_params("adaptive"), cold_start_after=3),
        GEOM, traj, body=BODY, limits=LIMITS,
    )  # fmt: skip
    p = ctl.p
    t = 3.0
    ref = traj.sample(t)
    ctl._solver.update_settings(max_iter=10, eps_abs=1e-12, eps_rel=1e-12)
    for k in range(3):
        ctl.step(t + 0.01 * k, 0.01, ref, _offset(ref, 0.0, 0.05, 0.0))
    assert ctl.fallbacks == 3 and ctl.cold_starts == 1
    ctl._solver.update_settings(max_iter=p.max_iter, eps_abs=p.eps_abs, eps_rel=p.eps_rel)
    ctl.step(t + 0.03, 0.01, ref, _offset(ref, 0.0, 0.05, 0.0))
    assert ctl.internals()["qp.status"] == SOLVED and ctl.fallbacks == 3
