"""ADAPTIVE: the QP's structure, its fixed sparsity, the fallback, constraints, closed loop."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import osqp
import pytest
import scipy.linalg

from controller.config import GeometryParams
from controller.planner import load_route, plan
from controller.tracking import registry
from controller.tracking.adaptive_kinematic import AdaptiveKinematicMPC as AdaptiveMPC
from controller.tracking.adaptive_kinematic import qp_data
from controller.tracking.qp import SOLVED
from controller.types import ReferenceSample, StateEstimate, tracking_error

ROOT = Path(__file__).resolve().parents[4]
GEOM = GeometryParams()
P = AdaptiveMPC.Params()


@pytest.fixture(scope="module")
def short():
    return plan(load_route(ROOT / "scenarios" / "routes" / "short.toml"))


def _offset(ref: ReferenceSample, along: float, left: float, dphi: float, v: float = 0.0):
    c, s = math.cos(ref.heading_rad), math.sin(ref.heading_rad)
    return StateEstimate(
        ref.t_s,
        ref.x_m + c * along - s * left,
        ref.y_m + s * along + c * left,
        ref.heading_rad + dphi,
        v,
        0.0,
    )


def _moving_time(traj) -> float:
    """A time at which the reference both moves and turns."""
    for t in np.arange(1.0, traj.duration_s, 0.05):
        r = traj.sample(float(t))
        if r.v_mps > 0.5 and abs(r.omega_radps) > 0.2:
            return float(t)
    raise AssertionError("no turning stretch on the route")


# ------------------------------------------------------------------ QP structure


def test_the_sparsity_pattern_is_the_same_at_rest_moving_and_turning(short) -> None:
    t_move = _moving_time(short)
    # the whole horizon before the start: v_d = omega_d = 0 at every stage
    rest = qp_data(P, GEOM, short, -5.0, _offset(short.sample(0.0), 0.01, 0.02, 0.03))
    moving = qp_data(
        P, GEOM, short, t_move, _offset(short.sample(t_move), -0.05, 0.1, -0.2, 1.0), u_prev=(1, 0)
    )
    for a, b in ((rest.A, moving.A), (rest.P, moving.P)):
        assert a.shape == b.shape and a.nnz == b.nnz
        np.testing.assert_array_equal(a.indptr, b.indptr)
        np.testing.assert_array_equal(a.indices, b.indices)
    # at rest the v_d- and omega_d-dependent entries are stored, as zeros (7 per stage:
    # a01 a02 a10 a12 b1v b0w b1w)
    assert np.count_nonzero(rest.A.data == 0.0) == 7 * P.horizon
    assert np.count_nonzero(moving.A.data == 0.0) < np.count_nonzero(rest.A.data == 0.0)
    # P is diagonal and stored as OSQP takes it (upper triangle)
    assert sp_is_upper_triangular(moving.P)
    assert np.all(moving.P.diagonal() >= 0.0)


def sp_is_upper_triangular(m) -> bool:
    c = m.tocoo()
    return bool(np.all(c.row <= c.col))


def test_each_stage_is_the_exact_discretization_of_the_linearized_error_dynamics(short) -> None:
    t_move = _moving_time(short)
    mpc = AdaptiveMPC(P, GEOM, short)
    d = mpc.qp_data(t_move, 0.01, short.sample(t_move), _offset(short.sample(t_move), 0, 0, 0))
    A = d.A.toarray()
    N, T = P.horizon, P.prediction_step_s
    for k in (0, 7, N - 1):
        ref = short.sample(t_move + k * T)
        vd, wd = ref.v_mps, ref.omega_radps
        Ac = np.array([[0, wd, 0], [-wd, 0, vd], [0, 0, 0]])
        Bc = np.array([[1, 0], [0, 0], [0, 1]])
        M = np.zeros((5, 5))
        M[:3, :3], M[:3, 3:] = Ac, Bc
        E = scipy.linalg.expm(M * T)  # [[A_d, B_d], [0, I]]
        rows = slice(3 + 3 * k, 6 + 3 * k)
        np.testing.assert_allclose(-A[rows, 3 * k : 3 * k + 3], E[:3, :3], atol=2e-4)
        np.testing.assert_allclose(A[rows, 3 * k + 3 : 3 * k + 6], np.eye(3))
        iu = 3 * (N + 1) + 2 * k
        np.testing.assert_allclose(-A[rows, iu : iu + 2], E[:3, 3:], atol=2e-4)


def test_the_first_move_is_rate_limited_against_the_command_applied_last(short) -> None:
    t = 5.0
    ref = short.sample(t)
    up = (0.6, -0.2)
    d = qp_data(P, GEOM, short, t, _offset(ref, 0, 0, 0), dt_s=0.01, u_prev=up)
    N = P.horizon
    iu = 3 * (N + 1)
    A = d.A.tocsr()
    # the rows that constrain u~_0 alone (box and rate of the first stage)
    only_u0 = [
        i
        for i in range(A.shape[0])
        if set(A.indices[A.indptr[i] : A.indptr[i + 1]]) <= {iu, iu + 1}
        and A.indptr[i + 1] > A.indptr[i]
    ]
    lo = sorted(d.l[only_u0] + [ref.v_mps, ref.omega_radps] * 2)
    hi = sorted(d.u[only_u0] + [ref.v_mps, ref.omega_radps] * 2)
    assert any(v == pytest.approx(up[0] - P.decel_max_mps2 * 0.01, abs=1e-9) for v in lo)
    assert any(v == pytest.approx(up[0] + P.accel_max_mps2 * 0.01, abs=1e-9) for v in hi)
    assert any(v == pytest.approx(up[1] - P.alpha_max_radps2 * 0.01, abs=1e-9) for v in lo)
    assert any(v == pytest.approx(P.v_max_mps, abs=1e-9) for v in hi)


def test_the_output_weights_grow_with_the_lateral_and_heading_errors(short) -> None:
    mpc = AdaptiveMPC(P, GEOM, short)
    t = 5.0
    ref = short.sample(t)
    small = mpc.qp_data(t, 0.01, ref, _offset(ref, 0, 0.0, 0.0)).P.diagonal()
    large = mpc.qp_data(t, 0.01, ref, _offset(ref, 0, 0.5, 1.0)).P.diagonal()
    half = mpc.qp_data(t, 0.01, ref, _offset(ref, 0, 0.5 * P.adapt_y_m, 0.0)).P.diagonal()
    q = slice(3, 6)  # stage 1: x, y, phi
    np.testing.assert_allclose(small[q], 2 * np.array([P.q_x, P.q_y, P.q_phi]))
    np.testing.assert_allclose(
        large[q], 2 * np.array([P.q_x, P.q_y, P.q_phi]) * [1, 1 + P.adapt_gain, 1 + P.adapt_gain]
    )
    assert half[4] == pytest.approx(2 * P.q_y * (1 + 0.25 * P.adapt_gain))
    assert large[3 * P.horizon + 1] == pytest.approx(large[4] * P.terminal_weight)


def test_step_solves_the_problem_that_qp_data_returns(short) -> None:
    mpc = AdaptiveMPC(P, GEOM, short)
    t = _moving_time(short)
    ref = short.sample(t)
    est = _offset(ref, -0.05, 0.04, 0.05, v=ref.v_mps)
    mpc._u_prev = (ref.v_mps, ref.omega_radps)
    d = mpc.qp_data(t, 0.01, ref, est)
    fresh = osqp.OSQP()
    fresh.setup(*d, verbose=False, eps_abs=1e-8, eps_rel=1e-8, max_iter=100000, polishing=True)
    res = fresh.solve(raise_error=False)
    assert res.info.status_val == SOLVED
    exact = mpc.command_from_solution(res.x)
    cmd = mpc.step(t, 0.01, ref, est)
    assert mpc.internals()["qp.status"] == SOLVED
    assert cmd.v_mps == pytest.approx(exact.v_mps, abs=2e-3)
    assert cmd.omega_radps == pytest.approx(exact.omega_radps, abs=2e-3)


# ------------------------------------------------------------------ fallback


def test_a_non_solved_status_falls_back_to_the_shifted_previous_plan_and_is_counted(
    short,
) -> None:
    mpc = AdaptiveMPC(P, GEOM, short)
    t0 = 5.0
    ref = short.sample(t0)
    mpc._u_prev = (ref.v_mps, ref.omega_radps)
    mpc.step(t0, 0.01, ref, _offset(ref, -0.05, 0.03, 0.02, v=ref.v_mps))
    assert mpc.internals()["qp.status"] == SOLVED and mpc.fallbacks == 0
    plan_ = mpc._plan.copy()
    # starve the solver: one iteration cannot reach 1e-12 from this far-off state
    mpc._solver.update_settings(max_iter=1, eps_abs=1e-12, eps_rel=1e-12)
    t1 = t0 + 2.5 * P.prediction_step_s  # 2.5 steps later: stage 2 of the old plan
    ref1 = short.sample(t1)
    cmd = mpc.step(t1, 1.0, ref1, _offset(ref1, 0.4, -0.3, 0.6, v=ref1.v_mps))
    st = mpc.internals()
    assert st["qp.status"] != SOLVED
    assert st["qp.fallbacks"] == 1 and st["qp.fallback_used"] == 1.0 and mpc.fallbacks == 1
    assert (cmd.v_mps, cmd.omega_radps) == pytest.approx(tuple(plan_[2]))
    assert sum(mpc.status_counts.values()) == 2
    # once the plan is used up the fallback brakes, rate-limited from the last command
    t2 = t0 + (P.horizon + 1) * P.prediction_step_s
    ref2 = short.sample(t2)
    last = cmd
    cmd2 = mpc.step(t2, 0.01, ref2, _offset(ref2, 0.4, -0.3, 0.6))
    assert cmd2.v_mps == pytest.approx(max(0.0, last.v_mps - P.decel_max_mps2 * 0.01))
    assert mpc.fallbacks == 2


def test_repeated_failures_restart_the_solver_cold_and_it_recovers(short) -> None:
    params = dataclasses.replace(P, cold_start_after=3)
    mpc = AdaptiveMPC(params, GEOM, short)
    t = 5.0
    ref = short.sample(t)
    mpc._solver.update_settings(max_iter=10, eps_abs=1e-12, eps_rel=1e-12)
    for k in range(3):
        mpc.step(t + 0.01 * k, 0.01, ref, _offset(ref, 0.0, 0.05, 0.0, v=ref.v_mps))
    assert mpc.fallbacks == 3 and mpc.cold_starts == 1
    mpc._solver.update_settings(max_iter=P.max_iter, eps_abs=P.eps_abs, eps_rel=P.eps_rel)
    mpc.step(t + 0.03, 0.01, ref, _offset(ref, 0.0, 0.05, 0.0, v=ref.v_mps))
    assert mpc.internals()["qp.status"] == SOLVED and mpc.fallbacks == 3


def test_non_finite_input_uses_the_fallback_instead_of_raising(short) -> None:
    mpc = AdaptiveMPC(P, GEOM, short)
    ref = short.sample(1.0)
    bad = StateEstimate(1.0, math.nan, 0.0, 0.0, 0.0, 0.0)
    cmd = mpc.step(1.0, 0.01, ref, bad)
    assert (cmd.v_mps, cmd.omega_radps) == (0.0, 0.0)
    assert mpc.fallbacks == 1


# ------------------------------------------------------------------ closed loop


def _simulate(mpc: AdaptiveMPC, traj, pose, seconds: float, lag_s: float = 0.04):
    x, y, h = pose
    v = w = 0.0
    dt = 0.01
    mpc.reset(StateEstimate(0.0, x, y, h, 0.0, 0.0), 0.0)
    log = []
    for k in range(int(seconds / dt)):
        t = k * dt
        ref = traj.sample(t)
        cmd = mpc.step(t, dt, ref, StateEstimate(t, x, y, h, v, w))
        for _ in range(5):
            v += (cmd.v_mps - v) * (dt / 5) / lag_s
            w += (cmd.omega_radps - w) * (dt / 5) / lag_s
            x += v * math.cos(h) * dt / 5
            y += v * math.sin(h) * dt / 5
            h += w * dt / 5
        log.append((t, tracking_error(x, y, h, traj.sample(t + dt)), cmd))
    return log


def _check_envelope(log, dt: float = 0.01) -> None:
    prev_v = prev_w = 0.0
    for _, _, c in log:
        assert math.isfinite(c.v_mps) and math.isfinite(c.omega_radps)
        assert P.v_min_mps - 1e-6 <= c.v_mps <= P.v_max_mps + 1e-6
        assert abs(c.omega_radps) <= P.omega_max_radps + 1e-6
        # solver tolerance eps_abs on top of the rate bounds
        assert -P.decel_max_mps2 * dt - 2e-3 <= c.v_mps - prev_v <= P.accel_max_mps2 * dt + 2e-3
        assert abs(c.omega_radps - prev_w) <= P.alpha_max_radps2 * dt + 2e-3
        prev_v, prev_w = c.v_mps, c.omega_radps


def test_it_tracks_the_short_route_within_the_constraints_and_stops_at_the_end(short) -> None:
    mpc = AdaptiveMPC(P, GEOM, short)
    log = _simulate(mpc, short, (0.0, 0.0, 0.0), short.duration_s + 2.0)
    _check_envelope(log)
    pos = [math.hypot(e.x_e_m, e.y_e_m) for t, e, _ in log if t <= short.duration_s]
    assert max(pos) < 0.02
    assert mpc.fallbacks == 0
    cmd = log[-1][2]
    assert (cmd.v_mps, cmd.omega_radps) == (0.0, 0.0) and mpc.internals()["parked"] == 1.0


@pytest.mark.parametrize(
    "pose",
    [(0.0, -0.3, 0.0), (0.0, 0.0, math.pi / 2), (-0.4, 0.2, -0.8)],
    ids=["start-right-of-path", "start-heading-90", "behind-left-and-turned"],
)
def test_hazard_starts_stay_in_the_envelope_and_converge(short, pose) -> None:
    mpc = AdaptiveMPC(P, GEOM, short)
    log = _simulate(mpc, short, pose, 10.0)
    _check_envelope(log)
    late = [math.hypot(e.x_e_m, e.y_e_m) for t, e, _ in log if t > 8.0]
    assert max(late) < 0.02
    assert mpc.fallbacks <= 5


def test_a_reference_that_pauses_is_followed(short) -> None:
    traj = plan(load_route(ROOT / "scenarios" / "routes" / "short-pause.toml"))
    mpc = AdaptiveMPC(P, GEOM, traj)
    log = _simulate(mpc, traj, (0.0, 0.0, 0.0), traj.duration_s)
    _check_envelope(log)
    assert max(math.hypot(e.x_e_m, e.y_e_m) for _, e, _ in log) < 0.02
    paused = [c for t, _, c in log if traj.sample(t).v_mps == 0.0 and 2.0 < t < traj.duration_s - 2]
    assert len(paused) > 250 and max(abs(c.v_mps) for c in paused[50:]) < 0.01


def test_the_gains_file_section_loads_with_its_declared_defaults() -> None:
    assert registry.load_params("adaptive-kinematic") == AdaptiveMPC.Params()
