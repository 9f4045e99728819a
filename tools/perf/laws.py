"""The tracking laws' cost: ``step()`` of every controller in an offline closed loop, and ADAPTIVE
against the same MPC problem solved through cvxpy (``controller_step_us``,
``allocations_per_tick``, ``adaptive_vs_cvxpy_ratio``, ``adaptive_vs_osqp_floor``)."""

from __future__ import annotations

import gc
import math
import statistics
import sys
import time
import warnings
from typing import Any

import numpy as np

from controller.config import load_config
from controller.limits import CommandLimiter
from controller.planner import load_route, plan
from controller.tracking import registry
from controller.tracking.adaptive import AdaptiveMPC
from controller.types import StateEstimate
from tools.perf.common import pct
from tools.run.scenario import route_file


def offline_loop(name: str, *, steps: int | None = None) -> dict[str, Any]:
    """Run controller ``name`` on the paper route with ideal wheels; time every step()."""

    cfg = load_config()
    traj = plan(load_route(route_file("paper")))
    ctl = registry.create(name, cfg.geometry, traj, motor=cfg.motor, body=cfg.body)
    lim = CommandLimiter(cfg.limits, cfg.geometry.half_track_m, cfg.geometry.wheel_radius_m)
    dt = cfg.loop.period_s
    n = steps or int(traj.duration_s / dt)
    s0 = traj.sample(0.0)
    x, y, phi, v, w = s0.x_m, s0.y_m, s0.heading_rad, 0.0, 0.0
    ctl.reset(StateEstimate(0.0, x, y, phi, 0.0, 0.0), 0.0)

    times = np.zeros(n, dtype=np.int64)  # preallocated: storing must not allocate
    blocks = np.zeros(n, dtype=np.int64)
    gc.collect()
    gc.disable()
    try:
        for k in range(n):
            t = k * dt
            ref = traj.sample(t)
            est = StateEstimate(t, x, y, phi, v, w)
            b0 = sys.getallocatedblocks()
            t0 = time.perf_counter_ns()
            cmd = ctl.step(t, dt, ref, est)
            times[k] = time.perf_counter_ns() - t0
            out = lim.apply(cmd, dt)
            blocks[k] = sys.getallocatedblocks() - b0
            v, w = out.v_mps, out.omega_radps
            x += v * math.cos(phi) * dt
            y += v * math.sin(phi) * dt
            phi += w * dt
    finally:
        gc.enable()
    us = sorted((times / 1000.0).tolist())
    warm = blocks[n // 10 :]
    return {
        "p50": pct(us, 50),
        "p99": pct(us, 99),
        "steps": n,
        "net_blocks_per_step": float(warm.mean()) if warm.size else math.nan,
        "internals": dict(ctl.internals()),
    }


def adaptive_vs_cvxpy(n_windows: int = 4, window: int = 25) -> dict[str, Any]:
    """Our ADAPTIVE step vs the same QP through cvxpy (with parameters), on the same states.

    The controller runs along the paper route in an offline closed loop (warm-started as
    in operation).  In ``n_windows`` windows of ``window`` consecutive ticks, the QP it is
    about to solve is also handed to cvxpy (warm-started across the window's ticks).
    """

    try:
        import cvxpy as cp  # lazy: the optional [cvxpy] extra
    except ImportError as err:
        return {"error": f"cvxpy not installed ({err}); pip install -e '.[cvxpy]'"}
    cfg = load_config()
    traj = plan(load_route(route_file("paper")))

    ours = registry.create("adaptive", cfg.geometry, traj, body=cfg.body)
    assert isinstance(ours, AdaptiveMPC)
    lim = CommandLimiter(cfg.limits, cfg.geometry.half_track_m, cfg.geometry.wheel_radius_m)
    dt = cfg.loop.period_s
    n_steps = int(traj.duration_s / dt)
    starts = {int(n_steps * (i + 1) / (n_windows + 1)) for i in range(n_windows)}
    sampled = {k for s0 in starts for k in range(s0, s0 + window)}
    s0 = traj.sample(0.0)
    x, y, phi, v, w = s0.x_m, s0.y_m, s0.heading_rad, 0.0, 0.0
    ours.reset(StateEstimate(0.0, x, y, phi, 0.0, 0.0), 0.0)
    prob = None
    big = 1e9
    ours_us, cvx_us, osqp_us, diff = [], [], [], []
    for k in range(n_steps):
        t = k * dt
        ref = traj.sample(t)
        est = StateEstimate(t, x, y, phi, v, w)
        d = ours.qp_data(t, dt, ref, est) if k in sampled else None
        t0 = time.perf_counter_ns()
        cmd = ours.step(t, dt, ref, est)
        step_us = (time.perf_counter_ns() - t0) / 1000.0
        if d is not None:
            if prob is None:
                n, m = d.A.shape[1], d.A.shape[0]
                coo = d.A.tocoo()
                xv = cp.Variable(n)
                p_ = cp.Parameter(n, nonneg=True)
                q_ = cp.Parameter(n)
                a_ = cp.Parameter((m, n), sparsity=(coo.row, coo.col))
                lo = cp.Parameter(m)
                hi = cp.Parameter(m)
                prob = cp.Problem(
                    cp.Minimize(0.5 * cp.sum(cp.multiply(p_, cp.square(xv))) + q_ @ xv),
                    [a_ @ xv >= lo, a_ @ xv <= hi],
                )
            t1 = time.perf_counter_ns()
            p_.value = d.P.diagonal()
            q_.value = d.q
            a_.value_sparse = d.A.tocoo()
            lo.value = np.clip(d.l, -big, big)
            hi.value = np.clip(d.u, -big, big)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                prob.solve(solver=cp.OSQP, warm_start=True)
            cvx_us.append((time.perf_counter_ns() - t1) / 1000.0)
            ours_us.append(step_us)
            osqp_us.append(float(ours.internals().get("qp.solve_us", math.nan)))
            if xv.value is not None:
                first = ours.command_from_solution(np.asarray(xv.value))
                diff.append(abs(first.v_mps - cmd.v_mps) + abs(first.omega_radps - cmd.omega_radps))
        out = lim.apply(cmd, dt)
        v, w = out.v_mps, out.omega_radps
        x += v * math.cos(phi) * dt
        y += v * math.sin(phi) * dt
        phi += w * dt
    ours_med = statistics.median(ours_us)
    cvx_med = statistics.median(cvx_us)
    good = [u for u in osqp_us if u == u]
    osqp_med = statistics.median(good) if good else math.nan
    return {
        "states": len(ours_us),
        "adaptive_step_us_p50": ours_med,
        "cvxpy_solve_us_p50": cvx_med,
        "osqp_own_solve_us_p50": osqp_med,
        "adaptive_vs_cvxpy_ratio": cvx_med / ours_med,
        "adaptive_vs_osqp_floor": ours_med / osqp_med if osqp_med == osqp_med else math.nan,
        "first_move_median_difference": statistics.median(diff) if diff else math.nan,
    }
