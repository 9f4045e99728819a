"""The pose EKF: an extended Kalman filter fusing wheel odometry with localization fixes.

This module owns what the controller believes about the chair's pose ([x, y, φ] of the axle
midpoint) and its uncertainty:

* **predict** with each :class:`~controller.odometry.OdometryIncrement`: the exact arc motion
  model of :func:`~controller.odometry.arc_step` (so without fixes the filter *is* dead
  reckoning), Jacobians ``F = ∂f/∂x`` and ``G = ∂f/∂(ds_L, ds_R)``, and process noise
  ``Q = G diag(σ_L², σ_R²) Gᵀ`` with, per wheel, ``σ² = wheel_noise · |ds| + (radius_rel_std ·
  ds)²``: proportional to the distance travelled and to the radius uncertainty;
* **correct** with a ``Pose_Fix`` [x, y, φ] (H = I, heading residual wrapped to (-π, π],
  Joseph-form update),
  Mahalanobis gating (χ², 3 dof) of outliers, and a recovery: after
  ``max_consecutive_rejections`` gated fixes in a row (3, 0.3 s of 10 Hz fixes: a physical
  flat tire's odometry error drifts the belief further with every fix refused; docs/planner.md
  "EKF" says why 3) the filter concludes that *it* has drifted, inflates its covariance by
  the innovation and accepts the fix;
* :meth:`PoseEstimator.estimate` -- the :class:`~controller.types.StateEstimate` the
  controllers use, with v and ω from the latest odometry interval.  Its pose is the
  *published* pose, not the filter's: it moves with every odometry interval exactly as the
  filter does (the same arc), but takes over a correction of the filter (a fix) by at most
  ``max_correction_step_m`` and ``max_correction_step_rad`` per odometry interval (one per
  tick of the loop), so that the estimate never jumps however fixes and odometry disagree.
  Each correction is released as a first-order approach (``correction_time_constant_s``,
  0.05 s: the 10 Hz fixes' corrections reach the controllers as ramps over about the fix
  period instead of a staircase, so no law's command steps with the fixes' noise), and never
  faster than the steps; a 0.3 m recovery is released over about 17 ticks.  The filter's state and covariance
  (:attr:`PoseEstimator.pose`, :attr:`PoseEstimator.covariance`) are the filter's belief,
  which the release does not touch.

filterpy's :class:`~filterpy.kalman.ExtendedKalmanFilter` shows the state
(:attr:`PoseEstimator.filter`) with filterpy's prediction equations (``x = f(x, u)``,
``P = F P Fᵀ + Q``, priors saved) and update equations (Joseph form; the gate's S⁻¹ reused
instead of filterpy's own ``update``, which would invert S a second time).  On a 4-state
filter building numpy arrays costs more than the arithmetic: both steps are written out in
floats (:mod:`controller.kernels`, compiled where the package was built so; the update is the
fault bank's, every sum in index order), and the filter's arrays (x, P, F, Q, the priors, and
y, S, SI, K of the last fix) are filled from them when something reads the filter, with the
same numbers.  Bad input (non-finite increments or fixes) is counted and ignored; a
numerically failed step is rolled back.  Nothing here raises at tick time.

Pure computation: no bus, no clock, no logging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from controller.ekf import ExtendedKalmanFilter
from controller.kernels import all_finite, bank_innovation, bank_update, pose_predict
from controller.odometry import OdometryIncrement, arc_step
from controller.types import Pose, StateEstimate, wrap_angle
from dbc.runtime.params import param


@dataclass(frozen=True)
class EstimatorParams:
    """Noise model and gating of the pose EKF."""

    wheel_noise_m2_per_m: float = param(
        2e-4,
        unit="m^2/m",
        doc="variance of each wheel's travel per metre it travels (slip, quantization)",
        lo=0.0,
        hi=1.0,
    )
    radius_rel_std: float = param(
        0.01, unit="1", doc="1-sigma relative uncertainty of the believed wheel radii", lo=0.0,
        hi=0.5,
    )  # fmt: skip
    fix_pos_std_m: float = param(
        0.05, unit="m", doc="1-sigma error of a Pose_Fix position", lo=0.0, lo_open=True, hi=100.0
    )
    fix_heading_std_rad: float = param(
        0.03, unit="rad", doc="1-sigma error of a Pose_Fix heading", lo=0.0, lo_open=True, hi=3.2
    )
    gate_chi2: float = param(
        16.27,
        unit="1",
        doc="Mahalanobis^2 gate of a fix (chi^2, 3 dof; 16.27 = 99.9 %)",
        lo=0.0,
        lo_open=True,
        hi=1e6,
    )
    max_consecutive_rejections: int = param(
        3,
        unit="fixes",
        doc="gated fixes in a row after which the filter inflates its covariance and accepts",
        lo=1,
        hi=100000,
    )
    initial_pos_std_m: float = param(
        0.02, unit="m", doc="1-sigma of the initial position", lo=0.0, lo_open=True, hi=1000.0
    )
    initial_heading_std_rad: float = param(
        0.01, unit="rad", doc="1-sigma of the initial heading", lo=0.0, lo_open=True, hi=3.2
    )
    odometry_timeout_s: float = param(
        0.1, unit="s", doc="estimate is invalid when odometry is older than this", lo=0.0,
        lo_open=True, hi=10.0,
    )  # fmt: skip
    max_correction_step_m: float = param(
        0.02,
        unit="m",
        doc="most a fix's correction moves the published position per odometry interval "
        "(tick) beyond the odometry's own motion; larger corrections are released gradually",
        lo=0.0,
        lo_open=True,
        hi=100.0,
    )
    max_correction_step_rad: float = param(
        0.02,
        unit="rad",
        doc="most a fix's correction turns the published heading per odometry interval "
        "(tick) beyond the odometry's own turn; larger corrections are released gradually",
        lo=0.0,
        lo_open=True,
        hi=3.2,
    )
    scale_initial_std: float = param(
        0.01,
        unit="1",
        doc="1-sigma of the wheels' differential scale delta at the start (the odometry's "
        "systematic heading drift; 0 with scale_drift_std_per_sqrt_m 0: no such state)",
        lo=0.0,
        hi=0.5,
    )
    scale_drift_std_per_sqrt_m: float = param(
        0.02,
        unit="1/sqrt(m)",
        doc="random walk of delta per square root of the distance the wheels travel: how fast "
        "the filter follows a tire that goes soft (a 16 % slower wheel is learnt within about "
        "2 m; 0: delta is held where it is)",
        lo=0.0,
        hi=1.0,
    )
    scale_max: float = param(
        0.4,
        unit="1",
        doc="|delta| is held within this (a 40 % differential scale is a wheel off the ground "
        "or gone, not a tire)",
        lo=0.0,
        lo_open=True,
        hi=1.0,
    )
    correction_time_constant_s: float = param(
        0.05,
        unit="s",
        doc="a correction is released as a first-order approach with this time constant "
        "(within the steps above): the 10 Hz fixes' corrections become ramps instead of "
        "staircases; 0 publishes a correction within the step at once",
        lo=0.0,
        hi=10.0,
    )


def _square4(P: tuple[float, ...]) -> np.ndarray:
    """The 4x4 covariance of its upper triangle ``(p00, p01, p02, p03, p11, ..., p33)``."""
    p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = P
    return np.array(
        [[p00, p01, p02, p03], [p01, p11, p12, p13], [p02, p12, p22, p23], [p03, p13, p23, p33]]
    )


class _PoseLike(Protocol):
    @property
    def x_m(self) -> float: ...
    @property
    def y_m(self) -> float: ...
    @property
    def heading_rad(self) -> float: ...


#: Below these a correction's rest is published at once (the first-order release's end).
_SNAP_M = 1e-4
_SNAP_RAD = 1e-4


class PoseEstimator:
    """EKF over [x, y, φ, δ] driven by odometry increments and corrected by pose fixes.

    ``δ`` is the wheels' differential scale: the odometry's wheel travels are taken as
    ``ds_L (1 - δ/2)`` and ``ds_R (1 + δ/2)``.  A tire that goes soft, or a believed radius
    that is off, turns the odometry's heading by ``δ ds / (2 b)`` per metre ``ds`` it does not
    see; with ``δ`` in the state the fixes teach the filter that drift, and the odometry
    between fixes stops drawing the sawtooth that the fixes would otherwise cut back every
    0.1 s (docs/planner.md "EKF")."""

    def __init__(
        self,
        half_track_m: float,
        params: EstimatorParams | None = None,
        pose: Pose | None = None,
        t_s: float = 0.0,
    ) -> None:
        self.params = params or EstimatorParams()
        self.half_track_m = half_track_m
        p = self.params
        self._R = np.diag([p.fix_pos_std_m**2, p.fix_pos_std_m**2, p.fix_heading_std_rad**2])
        self._R9 = self._R.ravel().tolist()
        self._ekf = ExtendedKalmanFilter(dim_x=4, dim_z=3)
        self._ekf.R = self._R.copy()
        # The state in floats, what predict() works on: [x, y, phi, delta], P's upper
        # triangle row by row (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33), and F's and
        # Q's entries of the last prediction (fa, fb, c0, c1, c2, qxx, qxy, qxp, qyy, qyp,
        # qpp, qdd); _stale: the filter's arrays lag behind.
        self._x: list[float] = [0.0, 0.0, 0.0, 0.0]
        self._P: tuple[float, ...] = (0.0,) * 10
        self._FQ: tuple[float, ...] | None = None
        self._prior: tuple[list[float], tuple[float, ...]] = (self._x, self._P)
        self._update: tuple[list[float], list[float]] | None = None
        self._stale = False
        # The published pose (estimate()): the filter's, less the correction not yet
        # released (_pending); the release budget left in this odometry interval (m, rad).
        self._pub: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._pending = False
        self._budget_m = self._budget_rad = 0.0
        self.predictions = 0
        #: The wheel travels (m, left and right) of the latest prediction as the filter
        #: believes them (the odometry's, scaled by delta): the arc its pose moved.
        self.travel_m = (0.0, 0.0)
        self.fixes_accepted = 0
        self.fixes_rejected = 0  # gated outliers
        self.gate_recoveries = 0
        self.nonfinite_count = 0
        self.numerical_failures = 0
        #: Corrections and rebases that would have taken delta beyond ``scale_max``: it was
        #: held at the bound (a wheel off the ground or gone, or a filter misled)
        self.scale_held = 0
        self.last_mahalanobis2 = math.nan
        self.reset(pose or Pose(0.0, 0.0, 0.0), t_s)

    def reset(
        self,
        pose: Pose,
        t_s: float,
        pos_std_m: float | None = None,
        heading_std_rad: float | None = None,
    ) -> None:
        """Restart from ``pose`` with the initial (or given) uncertainty; v = ω = 0."""
        p = self.params
        ps = p.initial_pos_std_m if pos_std_m is None else pos_std_m
        hs = p.initial_heading_std_rad if heading_std_rad is None else heading_std_rad
        ds = p.scale_initial_std
        self._ekf.x = np.array([pose.x_m, pose.y_m, wrap_angle(pose.heading_rad), 0.0])
        self._ekf.P = np.diag([ps * ps, ps * ps, hs * hs, ds * ds])
        self._stale = False
        self._pull()
        x, y, phi, _ = self._x
        self._pub = (x, y, phi)
        self._pending = False
        self._budget_m = p.max_correction_step_m
        self._budget_rad = p.max_correction_step_rad
        self._v_mps = 0.0
        self._omega_radps = 0.0
        self._t_odom: float | None = None
        self._t_reset = t_s
        self._streak = 0

    # -- the filter's arrays and their float copy ----------------------------------------

    @property
    def filter(self) -> ExtendedKalmanFilter:
        """The filterpy filter, its arrays up to date (x, P, and F, Q and the priors of the
        last prediction), to read: predictions and fixes go through this estimator."""
        self._push()
        return self._ekf

    def _push(self) -> None:
        """Fill the filter's arrays from the floats of the predictions since the last push."""
        if not self._stale:
            return
        ekf = self._ekf
        ekf.x = np.array(self._x)
        ekf.P = _square4(self._P)
        if self._FQ is not None:
            fa, fb, c0, c1, c2, qxx, qxy, qxp, qyy, qyp, qpp, qdd = self._FQ
            ekf.F = np.array(
                [[1.0, 0.0, fa, c0], [0.0, 1.0, fb, c1], [0.0, 0.0, 1.0, c2], [0.0, 0.0, 0.0, 1.0]]
            )
            ekf.Q = np.array(
                [
                    [qxx, qxy, qxp, 0.0],
                    [qxy, qyy, qyp, 0.0],
                    [qxp, qyp, qpp, 0.0],
                    [0.0, 0.0, 0.0, qdd],
                ]
            )
        # the priors are the last prediction's (a fix update or a rebase since leaves them)
        x_prior, P_prior = self._prior
        ekf.x_prior = np.array(x_prior)
        ekf.P_prior = _square4(P_prior)
        if self._update is not None:  # the last fix update's, as filterpy's update() leaves them
            ysi, K = self._update
            ekf.y = np.array(ysi[:3])
            ekf.S = np.array(ysi[3:12]).reshape(3, 3)
            ekf.SI = np.array(ysi[12:]).reshape(3, 3)
            ekf.K = np.array(K).reshape(4, 3)
            ekf._mahalanobis = ekf._log_likelihood = ekf._likelihood = None
            self._update = None
        self._stale = False

    def _pull(self) -> None:
        """Take the floats from the filter's arrays (after they were changed as arrays)."""
        ekf = self._ekf
        self._x = ekf.x.tolist()
        (p00, p01, p02, p03), (_, p11, p12, p13), (_, _, p22, p23), (*_, p33) = ekf.P.tolist()
        self._P = (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33)
        self._prior = (self._x, self._P)

    # -- filter steps ----------------------------------------------------------------------

    def predict(self, inc: OdometryIncrement, t_s: float) -> bool:
        """Propagate with one odometry interval ending at ``t_s``; False if it was ignored."""
        dl, dr = inc.ds_left_m, inc.ds_right_m
        if not (math.isfinite(dl) and math.isfinite(dr) and math.isfinite(t_s)):
            self.nonfinite_count += 1
            return False
        p = self.params
        b = self.half_track_m
        step = pose_predict(
            self._x,
            self._P,
            dl,
            dr,
            b,
            p.wheel_noise_m2_per_m,
            p.radius_rel_std,
            p.scale_drift_std_per_sqrt_m,
        )
        if step is None:
            self.numerical_failures += 1
            return False
        x, P, FQ, dl, dr, ds, dphi = step
        x1, y1, phi1, _ = x
        self._x = x
        self._P = P
        self._prior = (x, P)
        self.travel_m = (dl, dr)
        # the published pose moves the same arc; a new interval, a new release budget
        self._budget_m = p.max_correction_step_m
        self._budget_rad = p.max_correction_step_rad
        if self._pending:
            sx, sy, sphi = self._pub
            sx, sy, sphi, _, _ = arc_step(sx, sy, sphi, dl, dr, b)
            self._pub = (sx, sy, sphi)
            tau = p.correction_time_constant_s
            h = inc.dt_s
            self._release(1.0 if tau <= 0.0 or not h > 0.0 else min(1.0, h / tau))
        else:
            self._pub = (x1, y1, phi1)
        self._FQ = FQ
        self._stale = True
        self.predictions += 1
        dt = inc.dt_s
        if not (dt == dt and dt > 0.0) and self._t_odom is not None:
            dt = t_s - self._t_odom
        if dt == dt and dt > 0.0:
            self._v_mps = ds / dt
            self._omega_radps = dphi / dt
        self._t_odom = t_s
        return True

    def correct(self, fix: _PoseLike) -> bool:
        """Fuse a pose fix (anything with x_m, y_m, heading_rad); False if it was rejected."""
        zx, zy, zh = fix.x_m, fix.y_m, fix.heading_rad
        if not (math.isfinite(zx) and math.isfinite(zy) and math.isfinite(zh)):
            self.nonfinite_count += 1
            return False
        accepted = self._correct(zx, zy, zh)
        if accepted:
            self._pending = True
            if self.params.correction_time_constant_s <= 0.0:
                self._release(1.0)
        return accepted

    def _release(self, share: float) -> None:
        """Move the published pose toward the filter's by ``share`` of the gap (all of it
        once it is below 0.1 mm and 0.1 mrad), at most by what is left of this interval's
        budget (the position along the straight line, the heading the short way round)."""
        x, y, phi, _ = self._x
        sx, sy, sphi = self._pub
        dx, dy = x - sx, y - sy
        d = math.hypot(dx, dy)
        dh = wrap_angle(phi - sphi)
        if share < 1.0 and (d > _SNAP_M or abs(dh) > _SNAP_RAD):
            # a share of the gap: the same straight line and the same short way round
            x, y = sx + share * dx, sy + share * dy
            phi = wrap_angle(sphi + share * dh)
            dx, dy, d, dh = share * dx, share * dy, share * d, share * dh
        bm = self._budget_m
        if d <= bm:
            sx, sy = x, y
            self._budget_m = bm - d
        else:
            f = bm / d
            sx, sy = sx + f * dx, sy + f * dy
            self._budget_m = 0.0
        bh = self._budget_rad
        if abs(dh) <= bh:
            sphi = phi
            self._budget_rad = bh - abs(dh)
        else:
            sphi = wrap_angle(sphi + math.copysign(bh, dh))
            self._budget_rad = 0.0
        if not (math.isfinite(sx) and math.isfinite(sy) and math.isfinite(sphi)):
            self.numerical_failures += 1  # (not with finite poses) stay, rather than jump
            return
        self._pub = (sx, sy, sphi)
        fx, fy, fphi, _ = self._x
        self._pending = not (sx == fx and sy == fy and sphi == fphi)

    def _correct(self, zx: float, zy: float, zh: float) -> bool:
        x = self._x
        P = self._full_P()
        z = [zx, zy, zh]
        inn = bank_innovation(x, P, 4, z, self._R9)  # H = [I 0]: the fix sees the pose
        if inn is None:
            self.numerical_failures += 1
            return False
        d2, _, ysi = inn
        self.last_mahalanobis2 = d2
        if not d2 <= self.params.gate_chi2:
            self._streak += 1
            if self._streak < self.params.max_consecutive_rejections:
                self.fixes_rejected += 1
                return False
            # persistent disagreement: the filter, not the fixes, has drifted
            y = ysi[:3]
            P = list(P)
            for i in range(3):
                for j in range(3):
                    P[i * 4 + j] += y[i] * y[j]
            inn = bank_innovation(x, P, 4, z, self._R9)
            if inn is None:
                self.numerical_failures += 1
                return False
            ysi = inn[2]
            self.gate_recoveries += 1
        # filterpy's update() would recompute S and invert it with scipy (≈20 µs); the gate
        # already has S⁻¹, so the Joseph-form equations (H = [I 0]) are applied here, in
        # floats (controller.kernels.bank_update, the fault bank's), and the filter's
        # y/S/SI/K attributes are filled as filterpy would when it is read
        X, Pn, K = bank_update(x, P, 4, ysi, self._R9)
        if not (all_finite(X) and all_finite(Pn)):
            self.numerical_failures += 1
            return False
        X[2] = wrap_angle(X[2])
        dmax = self.params.scale_max
        d = X[3]
        if not -dmax <= d <= dmax:
            self.scale_held += 1
            X[3] = min(max(d, -dmax), dmax)
        self._x = X
        self._P = (Pn[0], Pn[1], Pn[2], Pn[3], Pn[5], Pn[6], Pn[7], Pn[10], Pn[11], Pn[15])
        self._update = (ysi, K)
        self._stale = True
        self._streak = 0
        self.fixes_accepted += 1
        return True

    def _full_P(self) -> list[float]:
        """``P`` as 16 floats row by row, from its upper triangle."""
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = self._P
        return [p00, p01, p02, p03, p01, p11, p12, p13, p02, p12, p22, p23, p03, p13, p23, p33]

    # -- outputs ---------------------------------------------------------------------------

    @property
    def pose(self) -> Pose:
        """The filter's belief (what the next fix is gated against)."""
        x, y, phi, _ = self._x
        return Pose(x, y, phi)

    @property
    def scale(self) -> float:
        """``δ``, the wheels' differential scale the filter believes (class doc): the right
        wheel travels ``1 + δ/2``, the left ``1 - δ/2`` of what the odometry reports."""
        return self._x[3]

    def rebase_scale(self, left_factor: float, right_factor: float) -> None:
        """The odometry's wheel travels change by these factors from now on (it believes new
        radii): ``δ`` keeps the travels it believes where they were.  Non-finite or
        non-positive factors are ignored."""
        if not all(math.isfinite(f) and f > 0.0 for f in (left_factor, right_factor)):
            self.nonfinite_count += 1
            return
        d = self._x[3]
        # (1 + d'/2) fr = (1 + d/2) and (1 - d'/2) fl = (1 - d/2), to first order in d'
        dn = (1.0 + 0.5 * d) / right_factor - (1.0 - 0.5 * d) / left_factor
        dmax = self.params.scale_max
        if not -dmax <= dn <= dmax:
            self.scale_held += 1
        self._x = [*self._x[:3], min(max(dn, -dmax), dmax)]
        self._stale = True

    @property
    def published_pose(self) -> Pose:
        """The pose :meth:`estimate` gives: the filter's less :attr:`pending_correction`."""
        x, y, phi = self._pub
        return Pose(x, y, phi)

    @property
    def pending_correction(self) -> tuple[float, float, float]:
        """The filter's pose minus the published one (m, m, rad, the heading wrapped): what
        is still to be released, at most the declared steps per odometry interval."""
        x, y, phi, _ = self._x
        sx, sy, sphi = self._pub
        return (x - sx, y - sy, wrap_angle(phi - sphi))

    @property
    def covariance(self) -> np.ndarray:
        """Copy of the 3x3 covariance of [x (m), y (m), φ (rad)] (the pose's block)."""
        return self.filter.P[:3, :3].copy()

    def estimate(self, t_s: float) -> StateEstimate:
        """The estimate at ``t_s``: the published pose, v and ω of the latest odometry interval.

        ``valid`` is False until the first odometry interval arrives, when odometry is older
        than ``odometry_timeout_s``, or if the state is not finite.
        """
        px, py, ph = self._pub
        fresh = self._t_odom is not None and t_s - self._t_odom <= self.params.odometry_timeout_s
        finite = math.isfinite(px) and math.isfinite(py) and math.isfinite(ph)
        return StateEstimate(t_s, px, py, ph, self._v_mps, self._omega_radps, fresh and finite)
