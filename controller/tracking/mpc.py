"""The receding-horizon machinery of ADAPTIVE apart from its model: gains, preview, QP pattern,
bookkeeping.

``adaptive.py`` keeps what is its prediction model's (the stage matrices, the input bounds,
the command); the rest is here:

* :class:`MpcParams`, the gains of any such MPC: horizon, adaptive output weights, soft
  bounds with their slacks, the OSQP settings, the cold restart, the preview grid, parking
  (the box and rate constraints are the chair's limits, ``LimitParams``, not gains);
* :func:`reference_columns` and :class:`Preview`, the reference tabulated once on a uniform
  grid and interpolated at the horizon's stages each tick;
* :class:`Pattern`, the QP's constraint matrix with its fixed sparsity pattern, and
  :func:`diagonal`, its diagonal cost;
* :class:`RecedingHorizon`, the run-time bookkeeping: the adaptive weights, solving with
  status counts and cold restarts, the plan a fallback shifts, ``qp_data`` and the common
  internals.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

from controller.tracking.common import path_errors, stop_radius
from controller.tracking.parking import RouteEndLatch
from controller.tracking.qp import INF, MAX_ITER, SOLVED, QPData, TickSolver, setup_solver
from controller.types import ReferenceSample, StateEstimate, Trajectory
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import param


@dataclass(frozen=True)
class MpcParams:
    """The gains of the MPC apart from its model's (``AdaptiveMPC.Params`` adds those)."""

    horizon: int = param(20, unit="steps", lo=2, hi=100, doc="prediction horizon N")
    prediction_step_s: float = param(
        0.1, unit="s", lo=0.01, hi=0.5, doc="prediction step T (the horizon spans N*T)"
    )
    q_x: float = param(40.0, unit="1/m^2", lo=0.0, hi=1e6, doc="weight of x_e^2")
    q_y: float = param(100.0, unit="1/m^2", lo=0.0, hi=1e6, doc="base weight of y_e^2")
    q_phi: float = param(10.0, unit="1/rad^2", lo=0.0, hi=1e6, doc="base weight of phi_e^2")
    terminal_weight: float = param(
        5.0, unit="1", lo=1.0, hi=1000.0, doc="factor on Q at the last stage"
    )
    adapt_gain: float = param(
        3.0, unit="1", lo=0.0, hi=100.0, doc="largest relative increase of q_y and q_phi"
    )
    adapt_y_m: float = param(
        0.1, unit="m", lo=1e-3, hi=10.0, doc="|y_e| at which q_y reaches its largest value"
    )
    adapt_phi_rad: float = param(
        0.3, unit="rad", lo=1e-3, hi=3.2, doc="|phi_e| at which q_phi reaches its largest value"
    )
    y_soft_max_m: float = param(
        0.15, unit="m", lo=0.0, hi=10.0, doc="soft bound on |y_e| over the horizon"
    )
    phi_soft_max_rad: float = param(
        0.5, unit="rad", lo=0.0, hi=3.2, doc="soft bound on |phi_e| over the horizon"
    )
    slack_weight_quadratic: float = param(
        1e4, unit="1/m^2", lo=0.0, hi=1e9, doc="weight of the squared slack variables"
    )
    slack_weight_linear: float = param(
        1e2, unit="1/m", lo=0.0, hi=1e9, doc="weight of the slack variables (exact penalty)"
    )
    max_iter: int = param(200, unit="iterations", lo=10, hi=100000, doc="OSQP max_iter")
    eps_abs: float = param(1e-3, unit="1", lo=1e-9, hi=1e-1, doc="OSQP eps_abs")
    eps_rel: float = param(1e-3, unit="1", lo=1e-9, hi=1e-1, doc="OSQP eps_rel")
    rho: float = param(30.0, unit="1", lo=1e-6, hi=1e6, doc="OSQP initial ADMM step")
    adaptive_rho_interval: int = param(
        0, unit="iterations", lo=0, hi=100000, doc="OSQP rho update interval (0: automatic)"
    )
    check_termination: int = param(
        5, unit="iterations", lo=1, hi=1000, doc="OSQP convergence check interval"
    )
    scaling: int = param(
        0,
        unit="iterations",
        lo=0,
        hi=100,
        doc="OSQP Ruiz scaling iterations (0: off; every matrix update repeats them)",
    )
    cold_start_after: int = param(
        10,
        unit="ticks",
        lo=1,
        hi=100000,
        doc="consecutive non-solved ticks after which the solver restarts cold",
    )
    preview_grid_s: float = param(
        0.01, unit="s", lo=0.001, hi=0.1, doc="grid of the tabulated reference"
    )
    stop_radius_m: float = stop_radius()


def reference_columns(
    trajectory: Trajectory, grid_s: float, keys: tuple[str, ...], who: str
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The grid times and the reference's ``keys`` (ReferenceSample fields) on them.

    The last grid point is the route's end, where the reference rests: its values are set
    to zero.  ConfigError (naming ``who``) for a route that cannot be tabulated.
    """
    duration = float(trajectory.duration_s)
    if not math.isfinite(duration) or duration < 0.0:
        raise ConfigError(f"{who}: trajectory duration {duration} s is not usable")
    if duration / grid_s > 1e6:  # 160 MB of table
        raise ConfigError(
            f"{who}: a {duration} s route needs a coarser preview_grid_s than {grid_s} s"
        )
    n = max(math.ceil(duration / grid_s) + 1, 2)
    t = np.minimum(np.arange(n) * grid_s, duration)
    many = getattr(trajectory, "sample_many", None)
    if many is not None:
        s = many(t)
        cols = [np.asarray(s[k], float) for k in keys]
    else:
        refs = [trajectory.sample(float(ti)) for ti in t]
        cols = [np.array([getattr(r, k) for r in refs]) for k in keys]
    if not all(np.all(np.isfinite(c)) for c in cols):
        raise ConfigError(f"{who}: the trajectory's reference twist is not finite")
    for c in cols:
        c[-1] = 0.0  # at rest from the end on
    return t, cols


class Preview:
    """A table of per-grid-point rows, interpolated at the horizon's stages ``t0 + k T``.

    ``Trajectory.sample`` costs a few microseconds per call (``sample_many`` a few hundred
    for a horizon), too much for 20 stages a tick.  So each law tabulates what a stage needs
    from the reference once (its twist, the discretized stage entries, the bounds of its
    input rows); a tick interpolates ``horizon`` rows linearly.  Outside ``[0, duration]``
    the reference rests.
    """

    __slots__ = ("_inv_h", "_last", "_offsets", "_pos", "_stride", "table")

    def __init__(self, table: np.ndarray, grid_s: float, T: float, horizon: int) -> None:
        self.table = table
        n = table.shape[0]
        self._inv_h = 1.0 / grid_s
        self._last = n - 2
        ratio = T / grid_s
        self._stride = round(ratio) if abs(ratio - round(ratio)) < 1e-9 else 0
        self._offsets = np.arange(horizon, dtype=float) * T
        self._pos = np.zeros(horizon)

    def rows(self, t0: float, out: np.ndarray) -> None:
        """Rows at ``t0 + k T``, ``k = 0..N-1``, interpolated linearly into ``out``.

        When ``T`` is a multiple of the grid the stages are two strided slices of the table
        (the common, fast case).
        """
        tab = self.table
        stride = self._stride
        p0 = t0 * self._inv_h
        if stride and p0 >= 0.0:
            i0 = int(p0)
            end = i0 + stride * (len(self._offsets) - 1)
            if end <= self._last:
                lo = tab[i0 : end + 1 : stride]
                np.subtract(tab[i0 + 1 : end + 2 : stride], lo, out=out)
                out *= p0 - i0
                out += lo
                return
        pos = self._pos
        np.add(self._offsets, t0, out=pos)
        pos *= self._inv_h
        np.maximum(pos, 0.0, out=pos)
        np.minimum(pos, self._last + 1.0, out=pos)
        i = pos.astype(np.int64)
        np.minimum(i, self._last, out=i)
        pos -= i
        lo = tab[i]
        np.subtract(tab[i + 1], lo, out=out)
        out *= pos[:, None]
        out += lo


class Pattern:
    """A sparse matrix built entry by entry, whose CSC positions are known afterwards.

    Every entry added is structural, whatever its value (zero included): OSQP refactors its
    KKT matrix with the same symbolic pattern each tick, so an entry that depends on the
    reference must exist even where its value is zero.
    """

    def __init__(self) -> None:
        self.rows: list[int] = []
        self.cols: list[int] = []
        self.vals: list[float] = []

    def add(self, r: int, c: int, v: float) -> int:
        """Add entry ``(r, c)`` with value ``v``; returns its entry number."""
        self.rows.append(r)
        self.cols.append(c)
        self.vals.append(v)
        return len(self.rows) - 1

    def soft_bounds(self, r_soft: int, r_slack: int, nx: int, horizon: int, isl: int) -> None:
        """Rows of the soft bounds on ``y_e`` (state 1) and ``phi_e`` (state 2) of stages
        ``1..N`` with their slacks (columns from ``isl``), and the slacks' own rows."""
        add = self.add
        for k in range(horizon):
            r0, ck1, cs = r_soft + 4 * k, nx * (k + 1), isl + 2 * k
            add(r0, ck1 + 1, 1.0)  # y_e + eps_y >= -y_max
            add(r0, cs, 1.0)
            add(r0 + 1, ck1 + 1, 1.0)  # y_e - eps_y <= y_max
            add(r0 + 1, cs, -1.0)
            add(r0 + 2, ck1 + 2, 1.0)  # same for phi_e
            add(r0 + 2, cs + 1, 1.0)
            add(r0 + 3, ck1 + 2, 1.0)
            add(r0 + 3, cs + 1, -1.0)
        for j in range(2 * horizon):
            add(r_slack + j, isl + j, 1.0)

    def csc(self, shape: tuple[int, int]) -> tuple[sp.csc_matrix, np.ndarray]:
        """The matrix in CSC form and each entry's position in its ``data``.

        A marker per entry survives the conversion (no entry is dropped for being zero),
        then the real values replace the markers.
        """
        nnz = len(self.rows)
        marker = sp.coo_matrix(
            (np.arange(1, nnz + 1, dtype=float), (self.rows, self.cols)), shape=shape
        ).tocsc()
        marker.sort_indices()
        order = marker.data.astype(np.int64) - 1  # CSC position -> entry number
        pos = np.empty(nnz, dtype=np.int64)
        pos[order] = np.arange(nnz)
        A = sp.csc_matrix(
            (np.asarray(self.vals, float)[order], marker.indices.copy(), marker.indptr.copy()),
            shape=shape,
        )
        return A, pos


def diagonal(n: int) -> sp.csc_matrix:
    """An ``n x n`` diagonal CSC matrix of zeros, every diagonal entry structural."""
    return sp.csc_matrix(
        (np.zeros(n), np.arange(n, dtype=np.int64), np.arange(n + 1, dtype=np.int64)),
        shape=(n, n),
    )


def soft_bound_values(lo: np.ndarray, hi: np.ndarray, p: MpcParams, horizon: int) -> None:
    """The bounds of :meth:`Pattern.soft_bounds`' rows: ``lo``, ``hi`` are the views of
    ``l``, ``u`` from ``r_soft`` to the end."""
    soft_l = lo[: 4 * horizon].reshape(horizon, 4)
    soft_u = hi[: 4 * horizon].reshape(horizon, 4)
    soft_l[:] = (-p.y_soft_max_m, -INF, -p.phi_soft_max_rad, -INF)
    soft_u[:] = (INF, p.y_soft_max_m, INF, p.phi_soft_max_rad)
    hi[4 * horizon :] = INF


class RecedingHorizon:
    """The run-time bookkeeping of the MPC around its QP.

    A subclass builds ``_P`` (with ``_Px``), ``_q``, ``_A`` (with ``_Ax``), ``_l``, ``_u``,
    ``_Qbase``, ``_Qdiag``, ``_scale_vec``, the variable offsets ``_iu`` (inputs) and
    ``_is`` (slacks), ``_zeros_n``, ``_zeros_m`` and ``_plan_offset`` (what a solution's
    inputs are added to: the reference's), and implements ``_fill``; its ``step`` counts
    ``steps`` and ``parked_steps`` (:meth:`activity`).
    """

    name: ClassVar[str]
    p: Any
    N: int
    T: float
    _P: sp.csc_matrix
    _Px: np.ndarray
    _q: np.ndarray
    _A: sp.csc_matrix
    _Ax: np.ndarray
    _l: np.ndarray
    _u: np.ndarray
    _Qbase: np.ndarray
    _Qdiag: np.ndarray
    _scale_vec: np.ndarray
    _iu: int
    _is: int
    _zeros_n: np.ndarray
    _zeros_m: np.ndarray
    _plan_offset: np.ndarray

    def _fill(self, t_s: float, dt_s: float, ex: float, ey: float, ephi: float) -> None:
        raise NotImplementedError

    def _start_solver(self) -> None:
        """Set OSQP up on the filled QP (OSQP classifies each row, equality or not, at
        set-up: it needs a real instance)."""
        self._solver = setup_solver(self._P, self._q, self._A, self._l, self._u, self.p, self.name)
        self._tick = TickSolver(self._solver)

    def _reset_plan(self) -> None:
        self._plan: np.ndarray | None = None  # absolute inputs per stage
        self._plan_t = 0.0
        self._park = RouteEndLatch()
        self._e = (0.0, 0.0, 0.0)
        self._status = 0
        self._iter = 0
        self._solve_us = 0.0
        self._run_us = 0.0
        self._slack_z: np.ndarray | None = None
        self._scale = (1.0, 1.0)
        self._fallback_used = False
        self._failed_in_row = 0
        self.solved = 0
        self.fallbacks = 0
        self.cold_starts = 0
        self.max_iter_hits = 0
        self.steps = 0
        self.parked_steps = 0

    def _restart(self) -> None:
        """What ``reset`` does: fresh bookkeeping, counts cleared, a cold solver."""
        self._reset_state()
        self.status_counts.clear()
        self._solver.warm_start(x=self._zeros_n, y=self._zeros_m)

    def _reset_state(self) -> None:
        raise NotImplementedError

    status_counts: dict[str, int]

    def _adapt_weights(self, ey: float, ephi: float) -> None:
        """The paper's adaptive output weights: ``q_y``, ``q_phi`` raised with ``|y_e|``,
        ``|phi_e|`` (written into the cost's diagonal in place)."""
        p = self.p
        sy = 1.0 + p.adapt_gain * min(1.0, abs(ey) / p.adapt_y_m) ** 2
        sphi = 1.0 + p.adapt_gain * min(1.0, abs(ephi) / p.adapt_phi_rad) ** 2
        self._scale = (sy, sphi)
        sv = self._scale_vec
        sv[1] = sy
        sv[2] = sphi
        np.multiply(self._Qbase, sv, out=self._Qdiag)

    def _push(self) -> int:
        """Hand this tick's Px, Ax, l, u to OSQP (same pattern); non-zero: OSQP error code."""
        return self._tick.push(self._Px, self._Ax, self._l, self._u)

    def _solve(self, t_s: float) -> np.ndarray | None:
        """Solve the pushed QP; the plan (absolute inputs per stage), or None if not solved.

        Counts every status; after ``cold_start_after`` failures in a row the next solve
        starts from scratch (the iterate may be far off by then).
        """
        info, z = self._tick.solve()
        self._status = status = int(info.status_val)
        self._iter = int(info.iter)
        self._solve_us = float(info.solve_time) * 1e6
        self._run_us = float(info.run_time) * 1e6
        key = str(info.status)
        self.status_counts[key] = self.status_counts.get(key, 0) + 1
        if status == MAX_ITER:
            self.max_iter_hits += 1
        if status != SOLVED or z is None or not math.isfinite(float(z.sum())):
            self._failed_in_row += 1
            if self._failed_in_row >= self.p.cold_start_after:
                self._failed_in_row = 0
                self.cold_starts += 1
                self._solver.warm_start(x=self._zeros_n, y=self._zeros_m)
            return None
        self._failed_in_row = 0
        self.solved += 1
        iu, isl, N = self._iu, self._is, self.N
        plan = z[iu:isl].reshape(N, -1) + self._plan_offset
        self._plan = plan
        self._plan_t = t_s
        self._slack_z = z[isl:].copy()  # reduced in internals(), outside the timed step
        return plan

    def _planned(self, t_s: float) -> tuple[float, float] | None:
        """A fallback: the previous plan's stage at ``t_s`` (shifted by its age), or None
        once it is used up (counted)."""
        self.fallbacks += 1
        self._fallback_used = True
        plan = self._plan
        age = (t_s - self._plan_t) / self.T
        j = int(age + 1e-9) if plan is not None and math.isfinite(age) else -1
        if plan is not None and 0 <= j < self.N:
            return float(plan[j, 0]), float(plan[j, 1])
        return None

    def activity(self) -> Mapping[str, int]:
        """Counts since the last reset: steps (``ticks``), steps parked at the route's end,
        solves that succeeded (``qp_solved``), steps that used the previous plan or braked
        instead (``qp_fallback``: unsolved, or no valid estimate), solves stopped at
        ``max_iter`` (``qp_max_iter``, a fallback too) and cold restarts."""
        return {
            "ticks": self.steps,
            "parked": self.parked_steps,
            "qp_solved": self.solved,
            "qp_fallback": self.fallbacks,
            "qp_max_iter": self.max_iter_hits,
            "qp_cold_start": self.cold_starts,
        }

    def qp_data(self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate) -> QPData:
        """The QP this controller would solve now, as independent copies (the solver and
        the plan are left alone)."""
        ex, ey, ephi = path_errors(ref, est)
        self._fill(t_s, dt_s, ex, ey, ephi)
        P = sp.csc_matrix(
            (self._Px.copy(), self._P.indices.copy(), self._P.indptr.copy()), shape=self._P.shape
        )
        A = sp.csc_matrix(
            (self._Ax.copy(), self._A.indices.copy(), self._A.indptr.copy()), shape=self._A.shape
        )
        return QPData(P, self._q.copy(), A, self._l.copy(), self._u.copy())

    def _qp_internals(self, *, run_time: bool) -> dict[str, float]:
        """The internals: errors, parking, solver, fallbacks, slacks, weights."""
        z = self._slack_z
        slack = (0.0, 0.0) if z is None else tuple(float(a) for a in z.reshape(-1, 2).max(axis=0))
        out = {
            "e_x_m": self._e[0],
            "e_y_m": self._e[1],
            "e_phi_rad": self._e[2],
            "parked": float(self._park.parked),
            "qp.status": float(self._status),
            "qp.iter": float(self._iter),
            "qp.solve_us": self._solve_us,
        }
        if run_time:
            out["qp.run_us"] = self._run_us
        out.update(
            {
                "qp.solved": float(self.solved),
                "qp.fallbacks": float(self.fallbacks),
                "qp.fallback_used": float(self._fallback_used),
                "qp.cold_starts": float(self.cold_starts),
                "qp.slack_y_m": slack[0],
                "qp.slack_phi_rad": slack[1],
                "weights.scale_y": self._scale[0],
                "weights.scale_phi": self._scale[1],
            }
        )
        return out
