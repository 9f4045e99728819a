"""ADAPTIVE: the paper's MPC, the robot's dynamic model as the prediction model (after Wang 2019).

The paper (Eq. adaptivectrl, "Parametrization"): the cost ``||Q (y - y_ref)||^2 + ||R u||^2``
with ``y`` the 2D location and heading, weights raised adaptively with ``|y_e|`` and
``|phi_e|``, and "the robot dynamic model is employed as the controller model".

**Model.**  The paper's dynamic model (Eqs. controldynamics, inertia, velocity) in body
coordinates, for the generalized force ``F = (tau_r + tau_l) / r`` and yaw moment
``M = b (tau_r - tau_l) / r`` of the wheel torques::

    m v' - m d omega^2 = F,          I omega' + m d v omega = M
    m = m_body + 2 I_w / r^2,        I = I_body + 2 b^2 I_w / r^2

(``d``: centre of mass ahead of P0; believed values from controller.toml ``[body]``) and
the kinematics of the tracking errors (Eq. derrorvector).  State
``z = (x_e, y_e, phi_e, v~, omega~)`` with ``v~ = v - v_d``, ``omega~ = omega - omega_d``;
input ``u = (F~, M~)``, the deviation from the feed-forward ``F_ref = m a_d - m d omega_d^2``,
``M_ref = I alpha_d + m d v_d omega_d`` that keeps the model on the reference.  Linearized
about the reference, ``z' = A_c(t) z + B u + E d_omega``::

    A_c = [[0, w_d, 0, 1, 0], [-w_d, 0, v_d, 0, 0], [0, 0, 0, 0, 1],
           [0, 0, 0, 0, 2 m d w_d / m], [0, 0, 0, -m d w_d / I, -m d v_d / I]]
    B   = [[0, 0], [0, 0], [0, 0], [1/m, 0], [0, 1/I]],      E = (0, 0, 1, 0, 0)

discretized exactly (zero-order hold, series to 1e-12) over the prediction step ``T``; stage
``k`` uses the reference at ``t + k T``.

**Cost** (Eq. adaptivectrl): ``sum_k e_k' Q e_k + u_k' R u_k`` plus the soft-bound slacks,
``e = (x_e, y_e, phi_e)`` (``y - y_ref`` rotated into the path frame: the same norm for
``q_x = q_y``), ``Q = diag(q_x, s_y q_y, s_phi q_phi)`` with the adaptive factors
``s = 1 + adapt_gain min(1, |err| / err_sat)^2`` (Wang et al.: ride comfort near the path,
accuracy off it), ``R = diag(r_force, r_moment)``: ``u`` is the torque the model needs beyond
the reference's, so a chair on its reference is not penalized for the torque that keeps it
there.

**Constraints.**  The chair's limits (``LimitParams``, the one envelope every law and the
node's limiter share) bound the inputs (``F / m`` within the acceleration and deceleration
limits, ``M / I`` within the turn acceleration limit) and the model twist at every stage's
end (speed forward and reverse, turn rate); soft bounds hold ``y_e`` and ``phi_e``.

**Integral action.**  The paper's cost has none, and Wang's has none: ``adaptive`` runs
without it (``disturbance_rate_per_s = 0``, the paper's form).  The named variant
``adaptive-integral`` (registry ``VARIANTS``: ADAPTIVE's gains, the integral keys on top)
adds the offset-free MPC's disturbance model: ``d_omega`` is a constant yaw-rate
disturbance over the horizon, estimated by a first-order filter of ``omega_est - omega_c``
(0.5 /s, bounded to 0.5 rad/s).  A persistent yaw disturbance -- a flat tyre, a bent shaft
-- is then compensated without a lasting heading or lateral offset.

**Command.**  The drives are velocity controlled.  The model's twist ``(v_c, omega_c)`` is the
controller's state: each tick it advances by the first move's model acceleration over the
control period, and is what the drives are told to follow.

The QP is built once with a fixed sparsity pattern (``mpc.py``), each tick writes the time-varying values in place
(``Px``, ``Ax``, ``l``, ``u``), OSQP is warm-started, and any status other than "solved"
uses the previous plan (counted); nothing raises at tick time.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from controller.config import BodyParams, GeometryParams, LimitParams
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
from controller.tracking.robust import effective_inertias
from controller.types import DriveGains, ReferenceSample, StateEstimate, Trajectory, TwistCommand
from dbc.runtime.params import param

NX, NU = 5, 2
# Preview table columns: reference twist and its rates, then the stage's discretized
# matrices, negated as the dynamics rows hold them (A 5x5 row-major, B 5x2 row-major), E (5),
# the input bounds (F lo, M lo, F hi, M hi), the feed-forward (F_ref, M_ref) and the
# reference twist one prediction step later (v, omega: the box of the stage's end).
_V, _W, _A, _AL = 0, 1, 2, 3
_AD = slice(4, 29)
_BD = slice(29, 39)
_ED = slice(39, 44)
_ULO = slice(44, 46)
_UHI = slice(46, 48)
_FF = slice(48, 50)
_NEXT = slice(50, 52)
_NCOL = 52


def continuous_model(
    v_d: np.ndarray, w_d: np.ndarray, m: float, inertia: float, md: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A_c, B, E)`` of the linearized error and twist dynamics, one per reference point.

    The inputs are ``(F~ / m, M~ / I)``: the force and moment in acceleration units, a change
    of variables that keeps the QP well scaled for OSQP (``R`` is scaled by ``m^2``, ``I^2``).
    """
    n = v_d.shape[0]
    A = np.zeros((n, NX, NX))
    A[:, 0, 1] = w_d
    A[:, 0, 3] = 1.0
    A[:, 1, 0] = -w_d
    A[:, 1, 2] = v_d
    A[:, 2, 4] = 1.0
    A[:, 3, 4] = 2.0 * md * w_d / m
    A[:, 4, 3] = -md * w_d / inertia
    A[:, 4, 4] = -md * v_d / inertia
    B = np.zeros((NX, NU))
    B[3, 0] = 1.0
    B[4, 1] = 1.0
    E = np.zeros(NX)
    E[2] = 1.0
    return A, B, E


def discretize(
    A: np.ndarray, B: np.ndarray, E: np.ndarray, T: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Zero-order hold over ``T``: ``exp([[A, B, E], [0, 0, 0]] T)`` by its series, batched.

    Returns ``(A_d, B_d, E_d)``.  ``||A T||`` is below 0.5 here; 14 terms leave < 1e-12.
    """
    n = A.shape[0]
    k = NX + NU + 1
    M = np.zeros((n, k, k))
    M[:, :NX, :NX] = A * T
    M[:, :NX, NX : NX + NU] = B * T
    M[:, :NX, NX + NU] = E * T
    out = np.broadcast_to(np.eye(k), (n, k, k)).copy()
    term = M.copy()
    out += term
    for j in range(2, 15):
        term = term @ M / j
        out += term
    return out[:, :NX, :NX], out[:, :NX, NX : NX + NU], out[:, :NX, NX + NU]


class AdaptiveMPC(RecedingHorizon):
    """The paper's ADAPTIVE: MPC on the dynamic model with adaptive weights; see the module doc."""

    name: ClassVar[str] = "adaptive"
    #: the drives keep their own velocity-loop gains
    drive_gains: DriveGains | None = None

    @dataclass(frozen=True)
    class Params(MpcParams):
        r_force: float = param(
            1e-4, unit="1/N^2", lo=1e-9, hi=1e3, doc="weight of F~^2 (force beyond the reference's)"
        )
        r_moment: float = param(
            1e-3, unit="1/(N*m)^2", lo=1e-9, hi=1e3, doc="weight of M~^2 (yaw moment beyond)"
        )
        disturbance_rate_per_s: float = param(
            0.0,
            unit="1/s",
            lo=0.0,
            hi=50.0,
            doc="rate of the yaw-rate disturbance estimate (integral action, which the paper's "
            "cost does not have; 0: the paper's form, the variant adaptive-integral: 0.5)",
        )
        disturbance_max_radps: float = param(
            0.5, unit="rad/s", lo=0.0, hi=5.0, doc="bound of the yaw-rate disturbance estimate"
        )

    def __init__(
        self,
        params: Params,
        geometry: GeometryParams,
        trajectory: Trajectory,
        *,
        body: BodyParams,
        limits: LimitParams,
    ) -> None:
        self.p = params
        self.body = body
        #: The chair's limits: the box of the model twist and the bounds of its rates.
        self.limits = limits
        self.m, self.inertia = effective_inertias(self.body, geometry)
        self.md = self.body.mass_kg * self.body.com_offset_m
        self.N = params.horizon
        self.T = params.prediction_step_s
        self._tabulate(trajectory)
        self._build()
        self.status_counts: dict[str, int] = {}
        self._reset_state()
        self._fill(0.0, self.T, 0.0, 0.0, 0.0)
        self._start_solver()

    # ------------------------------------------------------------------ set-up

    def _tabulate(self, trajectory: Trajectory) -> None:
        """The reference and every grid point's discretized stage, on a uniform grid."""
        p, lim = self.p, self.limits
        grid = p.preview_grid_s
        keys = ("v_mps", "omega_radps", "a_mps2", "alpha_radps2")
        t, (v, w, a, al) = reference_columns(trajectory, grid, keys, self.name)
        n = t.shape[0]
        tab = np.empty((n, _NCOL))
        tab[:, _V], tab[:, _W], tab[:, _A], tab[:, _AL] = v, w, a, al
        Ac, B, E = continuous_model(v, w, self.m, self.inertia, self.md)
        Ad, Bd, Ed = discretize(Ac, B, E, self.T)
        tab[:, _AD] = -Ad.reshape(n, NX * NX)
        tab[:, _BD] = -Bd.reshape(n, NX * NU)
        tab[:, _ED] = Ed
        # feed-forward F_ref / m and M_ref / I, and the input bounds, in acceleration units
        f_ref = a - self.md * w * w / self.m
        m_ref = al + self.md * v * w / self.inertia
        tab[:, 48], tab[:, 49] = f_ref, m_ref
        tab[:, 44] = -lim.decel_max_mps2 - f_ref
        tab[:, 45] = -lim.alpha_max_radps2 - m_ref
        tab[:, 46] = lim.accel_max_mps2 - f_ref
        tab[:, 47] = lim.alpha_max_radps2 - m_ref
        tab[:, 50] = np.interp(t + self.T, t, v, right=0.0)
        tab[:, 51] = np.interp(t + self.T, t, w, right=0.0)
        self._preview = Preview(tab, grid, self.T, self.N)

    def _build(self) -> None:
        """Allocate the QP with its fixed sparsity pattern and the index maps for updates."""
        p, N = self.p, self.N
        self._iu = iu = NX * (N + 1)
        self._is = isl = iu + NU * N
        n = isl + 2 * N
        r_dyn = NX
        r_in = r_dyn + NX * N  # per stage: F, M box
        r_box = r_in + NU * N  # per stage k+1: v, omega box
        r_soft = r_box + 2 * N
        r_slack = r_soft + 4 * N
        m = r_slack + 2 * N
        pat = Pattern()
        add = pat.add
        for i in range(NX):
            add(i, i, 1.0)
        var_a = np.zeros((N, NX * NX), dtype=np.int64)
        var_b = np.zeros((N, NX * NU), dtype=np.int64)
        for k in range(N):
            r0, ck, ck1, cu = r_dyn + NX * k, NX * k, NX * (k + 1), iu + NU * k
            for i in range(NX):
                add(r0 + i, ck1 + i, 1.0)
                for j in range(NX):
                    var_a[k, i * NX + j] = add(r0 + i, ck + j, 0.0)
                for j in range(NU):
                    var_b[k, i * NU + j] = add(r0 + i, cu + j, 0.0)
        for k in range(N):
            for j in range(NU):
                add(r_in + NU * k + j, iu + NU * k + j, 1.0)
            ck1 = NX * (k + 1)
            add(r_box + 2 * k, ck1 + 3, 1.0)
            add(r_box + 2 * k + 1, ck1 + 4, 1.0)
        pat.soft_bounds(r_soft, r_slack, NX, N, isl)
        self._A, pos = pat.csc((m, n))
        self._Ax = self._A.data
        self._A_var = np.concatenate([pos[var_a], pos[var_b]], axis=1)  # (N, 35)
        self._stage_buf = np.zeros((N, NX * NX + NX * NU))
        self._P = diagonal(n)
        self._Px = self._P.data
        r_u = np.array([p.r_force * self.m**2, p.r_moment * self.inertia**2])
        self._Px[iu:isl] = 2.0 * np.tile(r_u, N)
        self._Px[isl:] = 2.0 * p.slack_weight_quadratic
        self._q = np.zeros(n)
        self._q[isl:] = p.slack_weight_linear
        self._Qbase = np.zeros((N, NX))
        self._Qbase[:, :3] = 2.0 * np.array([p.q_x, p.q_y, p.q_phi])
        self._Qbase[-1] *= p.terminal_weight
        self._Qdiag = self._Px[NX : NX * (N + 1)].reshape(N, NX)
        self._scale_vec = np.ones(NX)
        self._l = np.zeros(m)
        self._u = np.zeros(m)
        self._dyn_l = self._l[r_dyn:r_in].reshape(N, NX)
        self._dyn_u = self._u[r_dyn:r_in].reshape(N, NX)
        self._in_l = self._l[r_in:r_box].reshape(N, NU)
        self._in_u = self._u[r_in:r_box].reshape(N, NU)
        lim = self.limits
        self._box_lo = np.array([-lim.v_reverse_max_mps, -lim.omega_max_radps])
        self._box_hi = np.array([lim.v_max_mps, lim.omega_max_radps])
        self._box_l = self._l[r_box:r_soft].reshape(N, 2)
        self._box_u = self._u[r_box:r_soft].reshape(N, 2)
        soft_bound_values(self._l[r_soft:], self._u[r_soft:], p, N)
        self._rows_buf = np.zeros((N, _NCOL))
        self._plan_offset = self._rows_buf[:, _FF]
        self._n, self._m = n, m
        self._zeros_n, self._zeros_m = np.zeros(n), np.zeros(m)

    # ------------------------------------------------------------------ run time

    def _reset_state(self) -> None:
        self._v_c = 0.0
        self._w_c = 0.0
        self._d_w = 0.0
        self._fill_nu = (0.0, 0.0)
        self._u0 = (0.0, 0.0)
        self._reset_plan()  # the plan: absolute (F, M) per stage

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        """Start the model's twist at the estimate's (in limits); forget plan and disturbance."""
        self._restart()
        lim = self.limits
        if math.isfinite(estimate.v_mps):
            self._v_c = min(max(estimate.v_mps, -lim.v_reverse_max_mps), lim.v_max_mps)
        if math.isfinite(estimate.omega_radps):
            w = estimate.omega_radps
            self._w_c = min(max(w, -lim.omega_max_radps), lim.omega_max_radps)

    def _fill(self, t_s: float, dt_s: float, ex: float, ey: float, ephi: float) -> None:
        """Write this tick's values into Px, Ax, l and u (in place, fixed pattern)."""
        rows = self._rows_buf
        self._preview.rows(t_s, rows)
        self._Ax[self._A_var] = rows[:, 4:39]
        self._adapt_weights(ey, ephi)
        lo, hi = self._l, self._u
        # reference twist at the stage ends (the box on the model twist applies there)
        nxt = rows[:, _NEXT]
        np.subtract(self._box_lo, nxt, out=self._box_l)
        np.subtract(self._box_hi, nxt, out=self._box_u)
        self._in_l[:] = rows[:, _ULO]
        self._in_u[:] = rows[:, _UHI]
        # the affine disturbance term of every stage, E_d d_omega
        np.multiply(rows[:, _ED], self._d_w, out=self._dyn_l)
        self._dyn_u[:] = self._dyn_l
        vr, wr = float(rows[0, _V]), float(rows[0, _W])
        self._fill_nu = (self._v_c, self._w_c)
        x0 = (ex, ey, ephi, self._v_c - vr, self._w_c - wr)
        for i in range(NX):
            lo[i] = hi[i] = x0[i]

    def _advance(self, v0: float, w0: float, f: float, mom: float, h: float) -> tuple[float, float]:
        """The model twist after ``h`` under the force ``f`` and moment ``mom`` (over m, I)."""
        lim = self.limits
        acc = f + self.md * w0 * w0 / self.m
        wdot = mom - self.md * v0 * w0 / self.inertia
        acc = min(max(acc, -lim.decel_max_mps2), lim.accel_max_mps2)
        wdot = min(max(wdot, -lim.alpha_max_radps2), lim.alpha_max_radps2)
        v = min(max(v0 + acc * h, -lim.v_reverse_max_mps), lim.v_max_mps)
        w = min(max(w0 + wdot * h, -lim.omega_max_radps), lim.omega_max_radps)
        return v, w

    def command_from_solution(self, z: np.ndarray) -> TwistCommand:
        """The command a solution ``z`` of the QP filled last gives (over one control period)."""
        iu = self._iu
        ff = self._rows_buf[0, _FF]
        v0, w0 = self._fill_nu
        v, w = self._advance(v0, w0, float(z[iu] + ff[0]), float(z[iu + 1] + ff[1]), self._h_last)
        return TwistCommand(v, w)

    _h_last = 0.01

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        """The MPC's twist for this tick: the model moved by the plan's first force and moment."""
        p = self.p
        self.steps += 1
        h = dt_s if (dt_s > 0.0 and math.isfinite(dt_s)) else 0.0
        self._h_last = h
        ex, ey, ephi = path_errors(ref, est)
        self._e = (ex, ey, ephi)
        if self._park.check(ref.done, math.hypot(ex, ey), p.stop_radius_m):
            self.parked_steps += 1
            self._v_c = self._w_c = 0.0
            return TwistCommand(0.0, 0.0)
        self._fallback_used = False
        if not (
            est.valid and math.isfinite(ex + ey + ephi + est.omega_radps) and math.isfinite(t_s)
        ):
            return self._fallback(t_s, h)
        if p.disturbance_rate_per_s > 0.0:
            k = min(1.0, p.disturbance_rate_per_s * h)
            dw = self._d_w + k * ((est.omega_radps - self._w_c) - self._d_w)
            lim = p.disturbance_max_radps
            self._d_w = min(max(dw, -lim), lim)
        self._fill(t_s, h, ex, ey, ephi)
        if self._push() != 0:
            return self._fallback(t_s, h)
        plan = self._solve(t_s)
        if plan is None:
            return self._fallback(t_s, h)
        return self._apply(float(plan[0, 0]), float(plan[0, 1]), h)

    def _apply(self, f: float, mom: float, h: float) -> TwistCommand:
        self._u0 = (f, mom)
        self._v_c, self._w_c = self._advance(self._v_c, self._w_c, f, mom, h)
        return TwistCommand(self._v_c, self._w_c)

    def _fallback(self, t_s: float, h: float) -> TwistCommand:
        """The previous plan's force and moment, shifted by its age; braking once used up."""
        planned = self._planned(t_s)
        if planned is not None:
            f, mom = planned
        else:  # brake to rest, stop turning
            f = -min(self.limits.decel_max_mps2, abs(self._v_c) / max(h, 1e-3))
            f = f if self._v_c > 0.0 else -f
            mom = -self._w_c / max(h, 1e-3)
        if not (math.isfinite(f) and math.isfinite(mom)):
            f, mom = 0.0, 0.0
        return self._apply(f, mom, h)

    def internals(self) -> Mapping[str, float]:
        """The QP's figures, the model's force, moment, twist and disturbance estimate, by name."""
        r = self._rows_buf
        return self._qp_internals(run_time=False) | {
            "model.force_n": self._u0[0] * self.m,
            "model.moment_nm": self._u0[1] * self.inertia,
            "model.force_ref_n": float(r[0, 48]) * self.m,
            "model.moment_ref_nm": float(r[0, 49]) * self.inertia,
            "model.v_c_mps": self._v_c,
            "model.omega_c_radps": self._w_c,
            "model.disturbance_omega_radps": self._d_w,
        }
