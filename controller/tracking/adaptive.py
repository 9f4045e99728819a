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

**Integral action.**  The paper's cost has none, and Wang's has none.  We add the offset-free
MPC's disturbance model: ``d_omega`` is a constant yaw-rate disturbance over the horizon,
estimated by a first-order filter of ``omega_est - omega_c`` (``disturbance_rate_per_s``;
0 turns it off and leaves the paper's form).  A persistent yaw disturbance -- a flat tyre, a
bent shaft -- is then compensated without a lasting heading or lateral offset.

**Command.**  The drives are velocity controlled.  The model's twist ``(v_c, omega_c)`` is the
controller's state: each tick it advances by the first move's model acceleration over the
control period, and is what the drives are told to follow.

Everything else follows the kinematic variant (``adaptive_kinematic.py``): the QP is built
once with a fixed sparsity pattern, each tick writes the time-varying values in place
(``Px``, ``Ax``, ``l``, ``u``), OSQP is warm-started, and any status other than "solved"
uses the previous plan (counted); nothing raises at tick time.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import osqp
import scipy.sparse as sp

from controller.config import BodyParams, GeometryParams, load_config
from controller.tracking.parking import RouteEndLatch
from controller.tracking.qp import INF, SOLVED, QPData, TickSolver
from controller.tracking.robust import effective_inertias
from controller.types import (
    DriveGains,
    ReferenceSample,
    StateEstimate,
    Trajectory,
    TwistCommand,
    wrap_angle,
)
from dbc.runtime.errors import ConfigError
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


class AdaptiveMPC:
    """The paper's ADAPTIVE: MPC on the dynamic model with adaptive weights; see the module doc."""

    name: ClassVar[str] = "adaptive"
    #: the drives keep their own velocity-loop gains
    drive_gains: DriveGains | None = None

    @dataclass(frozen=True)
    class Params:
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
        r_force: float = param(
            1e-4, unit="1/N^2", lo=1e-9, hi=1e3, doc="weight of F~^2 (force beyond the reference's)"
        )
        r_moment: float = param(
            1e-3, unit="1/(N*m)^2", lo=1e-9, hi=1e3, doc="weight of M~^2 (yaw moment beyond)"
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
        disturbance_rate_per_s: float = param(
            0.5,
            unit="1/s",
            lo=0.0,
            hi=50.0,
            doc="rate of the yaw-rate disturbance estimate (integral action; 0: the paper's form)",
        )
        disturbance_max_radps: float = param(
            0.5, unit="rad/s", lo=0.0, hi=5.0, doc="bound of the yaw-rate disturbance estimate"
        )
        v_min_mps: float = param(-0.4, unit="m/s", lo=-3.0, hi=0.0, doc="lowest speed (reverse)")
        v_max_mps: float = param(1.45, unit="m/s", lo=0.1, hi=3.0, doc="highest speed")
        omega_max_radps: float = param(1.9, unit="rad/s", lo=0.1, hi=10.0, doc="|omega| bound")
        accel_max_mps2: float = param(
            0.95, unit="m/s^2", lo=0.05, hi=5.0, doc="largest F / m when speeding up"
        )
        decel_max_mps2: float = param(
            1.4, unit="m/s^2", lo=0.05, hi=5.0, doc="largest -F / m when braking"
        )
        alpha_max_radps2: float = param(
            5.5, unit="rad/s^2", lo=0.1, hi=100.0, doc="largest |M| / I"
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
            0, unit="iterations", lo=0, hi=100, doc="OSQP Ruiz scaling iterations (0: off)"
        )
        cold_start_after: int = param(
            10, unit="ticks", lo=1, hi=100000, doc="non-solved ticks before a cold restart"
        )
        preview_grid_s: float = param(
            0.01, unit="s", lo=0.001, hi=0.1, doc="grid of the tabulated reference"
        )
        stop_radius_m: float = param(
            0.05,
            unit="m",
            lo=0.0,
            hi=1.0,
            doc="after the route end, stop for good once the position error is below this",
        )

    def __init__(
        self,
        params: Params,
        geometry: GeometryParams,
        trajectory: Trajectory,
        *,
        body: BodyParams | None = None,
    ) -> None:
        p = self.p = params
        if p.v_min_mps >= p.v_max_mps:
            raise ConfigError("adaptive: v_min_mps must be below v_max_mps")
        self.body = body if body is not None else load_config().body
        self.m, self.inertia = effective_inertias(self.body, geometry)
        self.md = self.body.mass_kg * self.body.com_offset_m
        self.N = p.horizon
        self.T = p.prediction_step_s
        self._tabulate(trajectory)
        self._build()
        self.status_counts: dict[str, int] = {}
        self._reset_state()
        self._fill(0.0, self.T, 0.0, 0.0, 0.0)
        self._solver = osqp.OSQP()
        try:
            self._solver.setup(
                self._P,
                self._q,
                self._A,
                self._l,
                self._u,
                verbose=False,
                warm_starting=True,
                polishing=False,
                max_iter=p.max_iter,
                eps_abs=p.eps_abs,
                eps_rel=p.eps_rel,
                rho=p.rho,
                adaptive_rho_interval=p.adaptive_rho_interval,
                check_termination=p.check_termination,
                scaling=p.scaling,
            )
        except Exception as err:  # OSQPException / ValueError from the extension
            raise ConfigError(f"adaptive: OSQP set-up failed: {err}") from err
        self._tick = TickSolver(self._solver)

    # ------------------------------------------------------------------ set-up

    def _tabulate(self, trajectory: Trajectory) -> None:
        """The reference and every grid point's discretized stage, on a uniform grid."""
        p = self.p
        duration = float(trajectory.duration_s)
        if not math.isfinite(duration) or duration < 0.0:
            raise ConfigError(f"adaptive: trajectory duration {duration} s is not usable")
        grid = p.preview_grid_s
        if duration / grid > 1e6:
            raise ConfigError(
                f"adaptive: a {duration} s route needs a coarser preview_grid_s than {grid} s"
            )
        n = max(math.ceil(duration / grid) + 1, 2)
        t = np.minimum(np.arange(n) * grid, duration)
        many = getattr(trajectory, "sample_many", None)
        if many is not None:
            s = many(t)
            cols = [
                np.asarray(s[k], float) for k in ("v_mps", "omega_radps", "a_mps2", "alpha_radps2")
            ]
        else:
            refs = [trajectory.sample(float(ti)) for ti in t]
            cols = [
                np.array([getattr(r, k) for r in refs])
                for k in ("v_mps", "omega_radps", "a_mps2", "alpha_radps2")
            ]
        v, w, a, al = cols
        if not all(np.all(np.isfinite(c)) for c in cols):
            raise ConfigError("adaptive: the trajectory's reference twist is not finite")
        v[-1] = w[-1] = a[-1] = al[-1] = 0.0  # at rest from the end on
        tab = self.table = np.empty((n, _NCOL))
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
        tab[:, 44] = -p.decel_max_mps2 - f_ref
        tab[:, 45] = -p.alpha_max_radps2 - m_ref
        tab[:, 46] = p.accel_max_mps2 - f_ref
        tab[:, 47] = p.alpha_max_radps2 - m_ref
        tab[:, 50] = np.interp(t + self.T, t, v, right=0.0)
        tab[:, 51] = np.interp(t + self.T, t, w, right=0.0)
        self._inv_h = 1.0 / grid
        self._last_row = n - 2
        ratio = self.T / grid
        self._stride = round(ratio) if abs(ratio - round(ratio)) < 1e-9 else 0

    def _rows(self, t0: float, out: np.ndarray) -> None:
        """Table rows at ``t0 + k T``, ``k = 0..N-1``, interpolated linearly into ``out``."""
        tab = self.table
        pos0 = t0 * self._inv_h
        stride = self._stride
        if stride and pos0 >= 0.0:
            i0 = int(pos0)
            end = i0 + stride * (self.N - 1)
            if end <= self._last_row:
                lo = tab[i0 : end + 1 : stride]
                np.subtract(tab[i0 + 1 : end + 2 : stride], lo, out=out)
                out *= pos0 - i0
                out += lo
                return
        pos = (t0 + self._t_stage) * self._inv_h
        np.clip(pos, 0.0, self._last_row + 1.0, out=pos)
        i = np.minimum(pos.astype(np.int64), self._last_row)
        frac = pos - i
        lo = tab[i]
        np.subtract(tab[i + 1], lo, out=out)
        out *= frac[:, None]
        out += lo

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
        rows: list[int] = []
        cols: list[int] = []
        vals: list[float] = []

        def add(r: int, c: int, v: float) -> int:
            rows.append(r)
            cols.append(c)
            vals.append(v)
            return len(rows) - 1

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
        for k in range(N):
            r0, ck1, cs = r_soft + 4 * k, NX * (k + 1), isl + 2 * k
            add(r0, ck1 + 1, 1.0)
            add(r0, cs, 1.0)
            add(r0 + 1, ck1 + 1, 1.0)
            add(r0 + 1, cs, -1.0)
            add(r0 + 2, ck1 + 2, 1.0)
            add(r0 + 2, cs + 1, 1.0)
            add(r0 + 3, ck1 + 2, 1.0)
            add(r0 + 3, cs + 1, -1.0)
        for j in range(2 * N):
            add(r_slack + j, isl + j, 1.0)
        nnz = len(rows)
        marker = sp.coo_matrix(
            (np.arange(1, nnz + 1, dtype=float), (rows, cols)), shape=(m, n)
        ).tocsc()
        marker.sort_indices()
        order = marker.data.astype(np.int64) - 1
        pos = np.empty(nnz, dtype=np.int64)
        pos[order] = np.arange(nnz)
        self._A = sp.csc_matrix(
            (np.asarray(vals, float)[order], marker.indices.copy(), marker.indptr.copy()),
            shape=(m, n),
        )
        self._Ax = self._A.data
        self._A_var = np.concatenate([pos[var_a], pos[var_b]], axis=1)  # (N, 35)
        self._stage_buf = np.zeros((N, NX * NX + NX * NU))
        self._P = sp.csc_matrix(
            (np.zeros(n), np.arange(n, dtype=np.int64), np.arange(n + 1, dtype=np.int64)),
            shape=(n, n),
        )
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
        self._box_lo = np.array([p.v_min_mps, -p.omega_max_radps])
        self._box_hi = np.array([p.v_max_mps, p.omega_max_radps])
        self._box_l = self._l[r_box:r_soft].reshape(N, 2)
        self._box_u = self._u[r_box:r_soft].reshape(N, 2)
        soft_l = self._l[r_soft:r_slack].reshape(N, 4)
        soft_u = self._u[r_soft:r_slack].reshape(N, 4)
        soft_l[:] = (-p.y_soft_max_m, -INF, -p.phi_soft_max_rad, -INF)
        soft_u[:] = (INF, p.y_soft_max_m, INF, p.phi_soft_max_rad)
        self._u[r_slack:] = INF
        self._t_stage = np.arange(N, dtype=float) * self.T
        self._rows_buf = np.zeros((N, _NCOL))
        self._n, self._m = n, m
        self._zeros_n, self._zeros_m = np.zeros(n), np.zeros(m)

    # ------------------------------------------------------------------ run time

    def _reset_state(self) -> None:
        self._v_c = 0.0
        self._w_c = 0.0
        self._d_w = 0.0
        self._fill_nu = (0.0, 0.0)
        self._plan: np.ndarray | None = None  # absolute (F, M) per stage
        self._plan_t = 0.0
        self._park = RouteEndLatch()
        self._e = (0.0, 0.0, 0.0)
        self._status = 0
        self._iter = 0
        self._solve_us = 0.0
        self._slack_z: np.ndarray | None = None
        self._scale = (1.0, 1.0)
        self._fallback_used = False
        self._failed_in_row = 0
        self._u0 = (0.0, 0.0)
        self.solved = 0
        self.fallbacks = 0
        self.cold_starts = 0

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        self._reset_state()
        self.status_counts.clear()
        p = self.p
        if math.isfinite(estimate.v_mps):
            self._v_c = min(max(estimate.v_mps, p.v_min_mps), p.v_max_mps)
        if math.isfinite(estimate.omega_radps):
            self._w_c = min(max(estimate.omega_radps, -p.omega_max_radps), p.omega_max_radps)
        self._solver.warm_start(x=self._zeros_n, y=self._zeros_m)

    def _fill(self, t_s: float, dt_s: float, ex: float, ey: float, ephi: float) -> None:
        """Write this tick's values into Px, Ax, l and u (in place, fixed pattern)."""
        p = self.p
        rows = self._rows_buf
        self._rows(t_s, rows)
        self._Ax[self._A_var] = rows[:, 4:39]
        sy = 1.0 + p.adapt_gain * min(1.0, abs(ey) / p.adapt_y_m) ** 2
        sphi = 1.0 + p.adapt_gain * min(1.0, abs(ephi) / p.adapt_phi_rad) ** 2
        self._scale = (sy, sphi)
        sv = self._scale_vec
        sv[1] = sy
        sv[2] = sphi
        np.multiply(self._Qbase, sv, out=self._Qdiag)
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

    def _push(self) -> int:
        return self._tick.push(self._Px, self._Ax, self._l, self._u)

    def qp_data(self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate) -> QPData:
        """The QP this controller would solve now, as independent copies."""
        ex, ey, ephi = _errors(ref, est)
        self._fill(t_s, dt_s, ex, ey, ephi)
        P = sp.csc_matrix(
            (self._Px.copy(), self._P.indices.copy(), self._P.indptr.copy()), shape=self._P.shape
        )
        A = sp.csc_matrix(
            (self._Ax.copy(), self._A.indices.copy(), self._A.indptr.copy()), shape=self._A.shape
        )
        return QPData(P, self._q.copy(), A, self._l.copy(), self._u.copy())

    def _advance(self, v0: float, w0: float, f: float, mom: float, h: float) -> tuple[float, float]:
        """The model twist after ``h`` under the force ``f`` and moment ``mom`` (over m, I)."""
        p = self.p
        acc = f + self.md * w0 * w0 / self.m
        wdot = mom - self.md * v0 * w0 / self.inertia
        acc = min(max(acc, -p.decel_max_mps2), p.accel_max_mps2)
        wdot = min(max(wdot, -p.alpha_max_radps2), p.alpha_max_radps2)
        v = min(max(v0 + acc * h, p.v_min_mps), p.v_max_mps)
        w = min(max(w0 + wdot * h, -p.omega_max_radps), p.omega_max_radps)
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
        p = self.p
        h = dt_s if (dt_s > 0.0 and math.isfinite(dt_s)) else 0.0
        self._h_last = h
        ex, ey, ephi = _errors(ref, est)
        self._e = (ex, ey, ephi)
        if self._park.check(ref.done, math.hypot(ex, ey), p.stop_radius_m):
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
        info, z = self._tick.solve()
        self._status = status = int(info.status_val)
        self._iter = int(info.iter)
        self._solve_us = float(info.solve_time) * 1e6
        key = str(info.status)
        self.status_counts[key] = self.status_counts.get(key, 0) + 1
        if status != SOLVED or z is None or not math.isfinite(float(z.sum())):
            self._failed_in_row += 1
            if self._failed_in_row >= p.cold_start_after:
                self._failed_in_row = 0
                self.cold_starts += 1
                self._solver.warm_start(x=self._zeros_n, y=self._zeros_m)
            return self._fallback(t_s, h)
        self._failed_in_row = 0
        self.solved += 1
        iu, isl, N = self._iu, self._is, self.N
        plan = z[iu:isl].reshape(N, NU) + self._rows_buf[:, _FF]
        self._plan = plan
        self._plan_t = t_s
        self._slack_z = z[isl:].copy()
        return self._apply(float(plan[0, 0]), float(plan[0, 1]), h)

    def _apply(self, f: float, mom: float, h: float) -> TwistCommand:
        self._u0 = (f, mom)
        self._v_c, self._w_c = self._advance(self._v_c, self._w_c, f, mom, h)
        return TwistCommand(self._v_c, self._w_c)

    def _fallback(self, t_s: float, h: float) -> TwistCommand:
        """The previous plan's force and moment, shifted by its age; braking once used up."""
        self.fallbacks += 1
        self._fallback_used = True
        plan = self._plan
        age = (t_s - self._plan_t) / self.T
        j = int(age + 1e-9) if plan is not None and math.isfinite(age) else -1
        if plan is not None and 0 <= j < self.N:
            f, mom = float(plan[j, 0]), float(plan[j, 1])
        else:  # brake to rest, stop turning
            f = -min(self.p.decel_max_mps2, abs(self._v_c) / max(h, 1e-3))
            f = f if self._v_c > 0.0 else -f
            mom = -self._w_c / max(h, 1e-3)
        if not (math.isfinite(f) and math.isfinite(mom)):
            f, mom = 0.0, 0.0
        return self._apply(f, mom, h)

    def internals(self) -> Mapping[str, float]:
        z = self._slack_z
        slack = (0.0, 0.0) if z is None else tuple(float(a) for a in z.reshape(-1, 2).max(axis=0))
        r = self._rows_buf
        return {
            "e_x_m": self._e[0],
            "e_y_m": self._e[1],
            "e_phi_rad": self._e[2],
            "parked": float(self._park.parked),
            "qp.status": float(self._status),
            "qp.iter": float(self._iter),
            "qp.solve_us": self._solve_us,
            "qp.solved": float(self.solved),
            "qp.fallbacks": float(self.fallbacks),
            "qp.fallback_used": float(self._fallback_used),
            "qp.cold_starts": float(self.cold_starts),
            "qp.slack_y_m": slack[0],
            "qp.slack_phi_rad": slack[1],
            "weights.scale_y": self._scale[0],
            "weights.scale_phi": self._scale[1],
            "model.force_n": self._u0[0] * self.m,
            "model.moment_nm": self._u0[1] * self.inertia,
            "model.force_ref_n": float(r[0, 48]) * self.m,
            "model.moment_ref_nm": float(r[0, 49]) * self.inertia,
            "model.v_c_mps": self._v_c,
            "model.omega_c_radps": self._w_c,
            "model.disturbance_omega_radps": self._d_w,
        }


def _errors(ref: ReferenceSample, est: StateEstimate) -> tuple[float, float, float]:
    c, s = math.cos(ref.heading_rad), math.sin(ref.heading_rad)
    dx, dy = est.x_m - ref.x_m, est.y_m - ref.y_m
    h = est.heading_rad
    return c * dx + s * dy, -s * dx + c * dy, wrap_angle(h - ref.heading_rad)
