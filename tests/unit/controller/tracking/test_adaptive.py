"""ADAPTIVE (MPC on the dynamic model, OSQP): model, feed-forward, signs, adaptation, integral action."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from controller.config import BodyParams, GeometryParams
from controller.tracking import registry
from controller.tracking.adaptive import AdaptiveMPC, continuous_model, discretize
from controller.tracking.robust import effective_inertias
from controller.types import StateEstimate, Trajectory, tracking_error

from .trajectories import Circle

ROOT = Path(__file__).resolve().parents[4]
GEOM = GeometryParams()
BODY = BodyParams()


def make(traj: Trajectory | None = None, **over: float) -> AdaptiveMPC:
    return AdaptiveMPC(
        registry.load_params("adaptive", over or None), GEOM, traj or Circle(), body=BODY
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


def test_the_disturbance_estimate_removes_the_offset_the_papers_form_keeps() -> None:
    """A constant yaw-rate bias (a flat tyre's): integral action against none (the paper's)."""
    traj = Circle(duration=40.0)
    tail = slice(-1000, None)
    with_i, _ = _closed_loop(make(traj), traj, 30.0, omega_bias=0.1)
    without, _ = _closed_loop(make(traj, disturbance_rate_per_s=0.0), traj, 30.0, omega_bias=0.1)
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
