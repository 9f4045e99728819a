"""ADAPTIVE-KINEMATIC: linear-error *kinematic* MPC on OSQP.

This was the project's ADAPTIVE before the paper's (``adaptive.py``: the dynamic model as
the prediction model) replaced it; it stays available as ``--controller adaptive-kinematic``.

The state is the paper's tracking error ``e = (x_e, y_e, phi_e)`` (Eq. errorvector, actual
minus desired in the desired frame), the input the deviation ``u~ = (v - v_d, omega - omega_d)``
from the reference twist.  The exact error dynamics (Eq. derrorvector)::

    x_e' = -v_d + v cos(phi_e) + omega_d y_e
    y_e' =  v sin(phi_e) - omega_d x_e
    phi_e' = omega - omega_d

linearized about the reference (``e = 0``, ``u~ = 0``) give ``e' = A_c(t) e + B_c u~`` with
``A_c = [[0, w_d, 0], [-w_d, 0, v_d], [0, 0, 0]]`` and ``B_c = [[1, 0], [0, 0], [0, 1]]``.
Because ``A_c^3 = -w_d^2 A_c`` the zero-order-hold discretization over a prediction step
``T`` has a closed form (:func:`_discretize`); stage ``k`` uses the reference at ``t + k T``.

The QP, in the sparse formulation (states and inputs are both variables)::

    z = [e_0 .. e_N,  u~_0 .. u~_{N-1},  (eps_y,k, eps_phi,k) k = 1..N]

    min  sum_{k=1..N} e_k' Q e_k + sum_{k=0..N-1} u~_k' R u~_k
         + rho2 sum eps^2 + rho1 sum eps
    s.t. e_0 = measured error
         e_{k+1} = A_k e_k + B_k u~_k
         u_min <= u~_k + u_ref,k <= u_max                            box on v and omega
         rate_lo dt <= u_0 - u_prev <= rate_hi dt                    the command applied last
         rate_lo T <= u_k - u_{k-1} <= rate_hi T                     rates along the horizon
         |y_e,k| <= y_max + eps_y,k,  |phi_e,k| <= phi_max + eps_phi,k,  eps >= 0   soft states

``Q = diag(q_x, s_y q_y, s_phi q_phi)`` (times ``terminal_weight`` at ``k = N``) with the
adaptive factors ``s = 1 + adapt_gain min(1, |err| / err_sat)^2`` of the measured ``|y_e|`` and
``|phi_e|``: small deviations leave the input weight in charge (ride comfort), large ones
raise the tracking weight (accuracy), as the paper's "Parametrization" asks.

The problem is set up once.  Every tick writes the time-varying values into preallocated
arrays (``Px``, ``Ax``, ``l``, ``u``) and hands them to OSQP, which refactors its KKT
matrix with the same symbolic pattern: every entry that depends on ``v_d`` or ``omega_d`` is
a structural non-zero even when its value is zero (reference at rest, straight line).  A
status other than "solved" uses the previous plan, shifted by the time elapsed since it was
computed, and is counted (``fallbacks``); nothing raises at tick time.

:func:`qp_data` returns ``(P, q, A, l, u)`` for a given state so that another solver can be
checked against the same problem.  ``docs/controllers.md`` has the derivation and figures.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from controller.config import GeometryParams
from controller.tracking.common import path_errors
from controller.tracking.mpc import (
    MpcParams,
    Pattern,
    Preview,
    RecedingHorizon,
    diagonal,
    reference_columns,
    soft_bound_values,
)
from controller.tracking.qp import QPData
from controller.types import DriveGains, ReferenceSample, StateEstimate, Trajectory, TwistCommand
from dbc.runtime.params import param

# Columns of the preview table (and of one interpolated row per stage).
_V, _W = 0, 1
_STAGE = slice(2, 12)  # a00 a01 a02 a10 a11 a12 b0v b1v b0w b1w, negated (see _discretize)
_LOWER = slice(12, 16)  # lower bounds of the stage's [box v, box w, rate v, rate w] rows
_UPPER = slice(16, 20)  # upper bounds of the same rows
_NCOL = 20


def _discretize(v: np.ndarray, w: np.ndarray, T: float, out: np.ndarray) -> None:
    """Exact ZOH discretization of ``(A_c(v, w), B_c)``, per element of ``v, w``, into ``out``.

    ``exp(A_c T) = I + f1 A_c + f2 A_c^2`` and ``int_0^T exp(A_c s) ds = T I + f2 A_c +
    g2 A_c^2`` with ``f1 = sin(wT)/w``, ``f2 = (1 - cos wT)/w^2``, ``g2 = (wT - sin wT)/w^3``
    (Taylor series near ``w = 0``).  Columns: a00 a01 a02 a10 a11 a12 b0v b1v b0w b1w, stored
    negated because the dynamics rows read ``e_{k+1} - A_k e_k - B_k u~_k = 0``
    (``a20 = a21 = 0``, ``a22 = 1``, ``b2v = 0`` and ``b2w = T`` are constant).
    """
    th = w * T
    th2 = th * th
    small = np.abs(th) < 0.3
    ws = np.where(small, 1.0, w)
    cos_t, sin_t = np.cos(th), np.sin(th)
    f1 = np.where(small, T * (1.0 - th2 / 6.0 * (1.0 - th2 / 20.0)), sin_t / ws)
    f2 = np.where(small, T * T * (0.5 - th2 / 24.0 * (1.0 - th2 / 30.0)), (1.0 - cos_t) / (ws * ws))
    g2 = np.where(
        small, T**3 * (1.0 / 6.0 - th2 / 120.0 * (1.0 - th2 / 42.0)), (th - sin_t) / ws**3
    )
    out[:, 0] = -cos_t
    out[:, 1] = -sin_t
    out[:, 2] = -f2 * w * v
    out[:, 3] = sin_t
    out[:, 4] = -cos_t
    out[:, 5] = -f1 * v
    out[:, 6] = -(T - g2 * w * w)
    out[:, 7] = f2 * w
    out[:, 8] = -g2 * w * v
    out[:, 9] = -f2 * v


def _tabulate(
    trajectory: Trajectory, grid_s: float, T: float, p: AdaptiveKinematicMPC.Params
) -> np.ndarray:
    """The :class:`~controller.tracking.mpc.Preview` table: each grid point's reference
    twist, discretized stage entries and the bounds of its input rows (box and horizon
    rates depend only on the reference)."""
    t, (v, w) = reference_columns(
        trajectory, grid_s, ("v_mps", "omega_radps"), AdaptiveKinematicMPC.name
    )
    tab = np.empty((t.shape[0], _NCOL))
    tab[:, _V], tab[:, _W] = v, w
    _discretize(v, w, T, tab[:, _STAGE])
    # change of the reference twist over the preceding prediction step (rest before 0)
    dv = v - np.interp(t - T, t, v, left=0.0)
    dw = w - np.interp(t - T, t, w, left=0.0)
    tab[:, 12] = p.v_min_mps - v
    tab[:, 13] = -p.omega_max_radps - w
    tab[:, 14] = -p.decel_max_mps2 * T - dv
    tab[:, 15] = -p.alpha_max_radps2 * T - dw
    tab[:, 16] = p.v_max_mps - v
    tab[:, 17] = p.omega_max_radps - w
    tab[:, 18] = p.accel_max_mps2 * T - dv
    tab[:, 19] = p.alpha_max_radps2 * T - dw
    return tab


class AdaptiveKinematicMPC(RecedingHorizon):
    """Receding-horizon tracking with adaptive output weights; see the module doc."""

    name: ClassVar[str] = "adaptive-kinematic"
    #: the drives keep their own velocity-loop gains
    drive_gains: DriveGains | None = None

    @dataclass(frozen=True)
    class Params(MpcParams):
        r_v: float = param(1.0, unit="s^2/m^2", lo=1e-6, hi=1e6, doc="weight of (v - v_d)^2")
        r_omega: float = param(
            2.0, unit="s^2/rad^2", lo=1e-6, hi=1e6, doc="weight of (omega - omega_d)^2"
        )
        rho: float = param(
            3000.0,
            unit="1",
            lo=1e-6,
            hi=1e6,
            doc="OSQP initial ADMM step (large: the cost is not rescaled, see scaling)",
        )

    def __init__(self, params: Params, geometry: GeometryParams, trajectory: Trajectory) -> None:
        p = self.p = params
        self._check_box()
        self.N = p.horizon
        self.T = p.prediction_step_s
        table = _tabulate(trajectory, p.preview_grid_s, self.T, p)
        self._preview = Preview(table, p.preview_grid_s, self.T, self.N)
        self._build()
        self.status_counts: dict[str, int] = {}
        self._reset_state()
        self._fill(0.0, self.T, 0.0, 0.0, 0.0)
        self._start_solver()

    # ------------------------------------------------------------------ set-up

    def _build(self) -> None:
        """Allocate the QP with its fixed sparsity pattern and the index maps for updates."""
        p, N, T = self.p, self.N, self.T
        nx, nu = 3, 2
        self._iu = iu = nx * (N + 1)
        self._is = isl = iu + nu * N
        n = isl + 2 * N
        r_dyn = nx
        r_in = r_dyn + nx * N  # per stage: box v, box w, rate v, rate w
        r_soft = r_in + 4 * N  # per stage: y lower, y upper, phi lower, phi upper
        r_slack = r_soft + 4 * N
        m = r_slack + 2 * N
        self._r_in, self._r_soft = r_in, r_soft

        pat = Pattern()
        add = pat.add
        for i in range(nx):  # e_0 = measured error
            add(i, i, 1.0)
        varying = np.zeros((N, 10), dtype=np.int64)
        for k in range(N):
            r0, ck, ck1, cu = r_dyn + nx * k, nx * k, nx * (k + 1), iu + nu * k
            for i in range(nx):
                add(r0 + i, ck1 + i, 1.0)
            # structural entries: allocated whatever v_d and omega_d are
            e = varying[k]
            e[0] = add(r0, ck, -1.0)
            e[1] = add(r0, ck + 1, 0.0)
            e[2] = add(r0, ck + 2, 0.0)
            e[3] = add(r0 + 1, ck, 0.0)
            e[4] = add(r0 + 1, ck + 1, -1.0)
            e[5] = add(r0 + 1, ck + 2, 0.0)
            add(r0 + 2, ck + 2, -1.0)
            e[6] = add(r0, cu, -T)
            e[7] = add(r0 + 1, cu, 0.0)
            e[8] = add(r0, cu + 1, 0.0)
            e[9] = add(r0 + 1, cu + 1, 0.0)
            add(r0 + 2, cu + 1, -T)
        for k in range(N):
            r0, cu = r_in + 4 * k, iu + nu * k
            for j in range(nu):
                add(r0 + j, cu + j, 1.0)  # box
                add(r0 + 2 + j, cu + j, 1.0)  # rate
                if k > 0:
                    add(r0 + 2 + j, cu - nu + j, -1.0)
        pat.soft_bounds(r_soft, r_slack, nx, N, isl)
        self._A, pos = pat.csc((m, n))
        self._Ax = self._A.data  # written in place every tick
        self._A_var = pos[varying]  # (N, 10) CSC positions of the time-varying entries

        # P: diagonal, every entry structural (e_0's stay zero: it is fixed anyway).
        self._P = diagonal(n)
        self._Px = self._P.data
        self._Px[iu:isl] = 2.0 * np.tile(np.array([p.r_v, p.r_omega], dtype=float), N)
        self._Px[isl:] = 2.0 * p.slack_weight_quadratic
        self._q = np.zeros(n)
        self._q[isl:] = p.slack_weight_linear
        self._Qbase = 2.0 * np.tile(np.array([p.q_x, p.q_y, p.q_phi], dtype=float), N).reshape(N, 3)
        self._Qbase[-1] *= p.terminal_weight
        self._Qdiag = self._Px[nx : nx * (N + 1)].reshape(N, 3)  # view into Px
        self._scale_vec = np.ones(3)

        self._l = np.zeros(m)
        self._u = np.zeros(m)
        soft_bound_values(self._l[r_soft:], self._u[r_soft:], p, N)
        self._in_l = self._l[r_in:r_soft].reshape(N, 4)  # views written every tick
        self._in_u = self._u[r_in:r_soft].reshape(N, 4)
        self._rows_buf = np.zeros((N, _NCOL))
        self._uref = self._rows_buf[:, :2]
        self._plan_offset = self._uref
        self._stage_vals = self._rows_buf[:, _STAGE]
        self._n, self._m = n, m
        self._zeros_n, self._zeros_m = np.zeros(n), np.zeros(m)

    # ------------------------------------------------------------------ run time

    def _reset_state(self) -> None:
        self._u_prev = (0.0, 0.0)
        self._reset_plan()

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        self._restart()

    def _fill(self, t_s: float, dt_s: float, ex: float, ey: float, ephi: float) -> None:
        """Write this tick's values into Px, Ax, l and u (in place, fixed pattern)."""
        p = self.p
        rows = self._rows_buf
        self._preview.rows(t_s, rows)
        self._Ax[self._A_var] = self._stage_vals
        self._adapt_weights(ey, ephi)
        lo, hi = self._l, self._u
        lo[0] = hi[0] = ex
        lo[1] = hi[1] = ey
        lo[2] = hi[2] = ephi
        in_l, in_u = self._in_l, self._in_u
        in_l[:] = rows[:, _LOWER]
        in_u[:] = rows[:, _UPPER]
        # the first move's rates: against the command applied last, over the control period
        h = dt_s if dt_s > 0.0 else self.T
        v0, w0 = self._u_prev
        vr, wr = float(rows[0, _V]), float(rows[0, _W])
        in_l[0, 2] = v0 - p.decel_max_mps2 * h - vr
        in_l[0, 3] = w0 - p.alpha_max_radps2 * h - wr
        in_u[0, 2] = v0 + p.accel_max_mps2 * h - vr
        in_u[0, 3] = w0 + p.alpha_max_radps2 * h - wr

    def command_from_solution(self, z: np.ndarray) -> TwistCommand:
        """The first move (absolute v, omega) of a solution ``z`` of the QP filled last."""
        iu = self._iu
        return TwistCommand(float(z[iu] + self._uref[0, 0]), float(z[iu + 1] + self._uref[0, 1]))

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        ex, ey, ephi = path_errors(ref, est)
        self._e = (ex, ey, ephi)
        if self._park.check(ref.done, math.hypot(ex, ey), self.p.stop_radius_m):
            return self._out(0.0, 0.0)
        self._fallback_used = False
        if not (math.isfinite(ex + ey + ephi) and math.isfinite(t_s)):
            return self._fallback(t_s, dt_s)
        self._fill(t_s, dt_s, ex, ey, ephi)
        if self._push() != 0:
            return self._fallback(t_s, dt_s)
        plan = self._solve(t_s)
        if plan is None:
            return self._fallback(t_s, dt_s)
        # project the first move onto its bounds: the solver meets them only to eps_abs
        return self._bounded(float(plan[0, 0]), float(plan[0, 1]), dt_s)

    def _fallback(self, t_s: float, dt_s: float) -> TwistCommand:
        """The previous plan, shifted by the time since it was made; braking once used up.

        The result is held inside the box and rate bounds around the command applied last.
        """
        v, w = self._planned(t_s) or (0.0, 0.0)
        if not (math.isfinite(v) and math.isfinite(w)):
            v, w = 0.0, 0.0
        return self._bounded(v, w, dt_s)

    def _bounded(self, v: float, w: float, dt_s: float) -> TwistCommand:
        """``(v, w)`` held inside the box and the rate bounds around the last command."""
        p = self.p
        h = dt_s if dt_s > 0.0 else self.T
        v0, w0 = self._u_prev
        v = min(
            max(v, p.v_min_mps, v0 - p.decel_max_mps2 * h), p.v_max_mps, v0 + p.accel_max_mps2 * h
        )
        w = min(
            max(w, -p.omega_max_radps, w0 - p.alpha_max_radps2 * h),
            p.omega_max_radps,
            w0 + p.alpha_max_radps2 * h,
        )
        return self._out(v, w)

    def _out(self, v: float, w: float) -> TwistCommand:
        self._u_prev = (v, w)
        return TwistCommand(v, w)

    def internals(self) -> Mapping[str, float]:
        return self._qp_internals(run_time=True)


def qp_data(
    params: AdaptiveKinematicMPC.Params,
    geometry: GeometryParams,
    trajectory: Trajectory,
    t_s: float,
    est: StateEstimate,
    *,
    dt_s: float = 0.01,
    u_prev: tuple[float, float] = (0.0, 0.0),
) -> QPData:
    """The ADAPTIVE controller's QP at route time ``t_s`` for the estimate ``est``.

    ``u_prev`` is the command applied in the previous tick (the first move's rate bounds
    are anchored there).  ``P`` is upper-triangular (OSQP's form); a solver that wants the
    full matrix takes ``P + P.T - diag(P)``.  :meth:`AdaptiveKinematicMPC.command_from_solution` of
    the same controller turns a solution into the command.
    """
    mpc = AdaptiveKinematicMPC(params, geometry, trajectory)
    mpc._u_prev = (float(u_prev[0]), float(u_prev[1]))
    return mpc.qp_data(t_s, dt_s, trajectory.sample(t_s), est)
