"""Fault diagnosis: a bank of Kalman filters, one per fault hypothesis (multiple-model estimation).

This module owns what the controller believes about the chair's wheels: which fault is most
likely (the paper's "Faults and uncertainty injection system": one filter per fault, each
encapsulating the chair's kinematic model with that fault's parameters, all fed the same
inputs) and the effective rolling radii that follow from it.

Every filter is a filterpy :class:`~filterpy.kalman.ExtendedKalmanFilter` over the pose
``[x, y, phi]`` of the axle midpoint plus the parameters of its hypothesis:

============  ===============  ==================================================================
hypothesis    parameters       ground distance of wheel i per interval (``r0``: nominal radius)
============  ===============  ==================================================================
NOMINAL       none             ``r0 dtheta_i``
FLAT_LEFT     ``r_L``          left: ``r_L dtheta_L``, ``r_L`` in ``[r_min, r0 - flat_min_deflection]``
FLAT_RIGHT    ``r_R``          right: likewise
BUMP_LEFT     ``a, b``         left: ``int (r0 + a cos theta + b sin theta) dtheta`` (eccentric
                               wheel, one period per revolution), ``|(a, b)|`` in
                               ``[bump_min_amplitude, bump_max_amplitude]``
BUMP_RIGHT    ``a, b``         right: likewise
SLIP          ``s``            both: ``r0 (1 - s) dtheta_i``, ``s`` in ``[slip_min_ratio, slip_max]``
============  ===============  ==================================================================

The inputs are the drives' encoder positions (every odometry interval, the exact-arc motion
model of :func:`controller.odometry.arc_step`); the measurements are the localizer's pose fixes.
A fault hypothesis constrains its parameter to differ from nominal by at least a minimum
detectable fault (projection after each step): otherwise a hypothesis with a free parameter
would contain the nominal one and explain fault-free data just as well.  The parameters follow
random walks per metre travelled, so they track a deflating tire, and nothing changes at rest.

Hypothesis probabilities (multiple-model adaptive estimation): at each fix, each filter's
innovation ``y`` with covariance ``S`` gives a Gaussian likelihood; ``p_i <- p_i L_i``,
normalised.  Before that, a Markov switching step ``p <- (1 - eps) p + eps prior`` with
``eps = 1 - exp(-switch_rate_per_m * distance)`` lets a hypothesis that lost come back when the
fault changes; it acts per metre travelled, so a chair at rest keeps its diagnosis.  A fix that
no filter explains (Mahalanobis^2 of the best filter above ``outlier_chi2``) updates nothing.
Fixes taken at rest do not change the probabilities (the wheels tell nothing about their
radius when they do not turn) but still correct every filter's pose.

:meth:`FaultBank.radii` gives the effective rolling radii to use in odometry: those of the
most likely hypothesis when its probability reaches ``radius_feed_probability``, otherwise the
probability-weighted mean.  Pure computation: no bus, no clock, no logging; nothing raises at
tick time (non-finite input is counted and ignored, a numerically failed step rolled back).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from controller.types import Pose, wrap_angle
from dbc.codec import Hypothesis
from dbc.params import param

TWO_PI = 2.0 * math.pi

#: Scenario-style names of the hypotheses (``none`` = nominal), as the summary reports them.
HYPOTHESIS_NAMES: dict[Hypothesis, str] = {
    Hypothesis.NOMINAL: "none",
    Hypothesis.FLAT_LEFT: "flat-left",
    Hypothesis.FLAT_RIGHT: "flat-right",
    Hypothesis.BUMP_LEFT: "bump-left",
    Hypothesis.BUMP_RIGHT: "bump-right",
    Hypothesis.SLIP: "slip",
}


@dataclass(frozen=True)
class DiagnosisParams:
    """Noise model, minimum detectable faults and switching of the filter bank."""

    fix_pos_std_m: float = param(
        0.025,
        unit="m",
        lo=0.0,
        lo_open=True,
        hi=10.0,
        doc="1-sigma error of a Pose_Fix position (the localizer's 2 cm, inflated 25 %)",
    )
    fix_heading_std_rad: float = param(
        0.0125,
        unit="rad",
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="1-sigma error of a Pose_Fix heading (the localizer's 0.01 rad, inflated 25 %)",
    )
    wheel_noise_m2_per_m: float = param(
        1e-6,
        unit="m^2/m",
        lo=0.0,
        hi=1.0,
        doc="variance of each wheel's ground travel per metre (quantisation, unmodelled slip)",
    )
    initial_pos_std_m: float = param(
        0.05, unit="m", lo=0.0, lo_open=True, hi=100.0, doc="1-sigma of the initial position"
    )
    initial_heading_std_rad: float = param(
        0.03, unit="rad", lo=0.0, lo_open=True, hi=3.2, doc="1-sigma of the initial heading"
    )
    flat_min_deflection_m: float = param(
        0.008,
        unit="m",
        lo=0.0,
        hi=0.2,
        doc="flat hypotheses: the radius is at least this much below nominal",
    )
    flat_min_radius_m: float = param(
        0.15, unit="m", lo=0.01, hi=1.0, doc="flat hypotheses: smallest radius considered"
    )
    flat_initial_std_m: float = param(
        0.02, unit="m", lo=0.0, lo_open=True, hi=1.0, doc="flat hypotheses: 1-sigma prior radius"
    )
    flat_walk_m2_per_m: float = param(
        2e-5,
        unit="m^2/m",
        lo=0.0,
        hi=1.0,
        doc="flat hypotheses: random-walk variance of the radius per metre travelled",
    )
    bump_min_amplitude_m: float = param(
        0.005, unit="m", lo=0.0, hi=0.2, doc="bump hypotheses: smallest eccentricity considered"
    )
    bump_max_amplitude_m: float = param(
        0.05, unit="m", lo=0.0, lo_open=True, hi=0.3, doc="bump hypotheses: largest eccentricity"
    )
    bump_initial_std_m: float = param(
        0.01, unit="m", lo=0.0, lo_open=True, hi=1.0, doc="bump hypotheses: 1-sigma prior a, b"
    )
    bump_walk_m2_per_m: float = param(
        2e-6,
        unit="m^2/m",
        lo=0.0,
        hi=1.0,
        doc="bump hypotheses: random-walk variance of a and b per metre travelled",
    )
    slip_min_ratio: float = param(
        0.03, unit="1", lo=0.0, hi=0.9, doc="slip hypothesis: smallest slip ratio considered"
    )
    slip_max_ratio: float = param(
        0.9, unit="1", lo=0.0, lo_open=True, hi=0.99, doc="slip hypothesis: largest slip ratio"
    )
    slip_initial_std: float = param(
        0.05, unit="1", lo=0.0, lo_open=True, hi=1.0, doc="slip hypothesis: 1-sigma prior ratio"
    )
    slip_walk_per_m: float = param(
        2e-4,
        unit="1/m",
        lo=0.0,
        hi=1.0,
        doc="slip hypothesis: random-walk variance of the ratio per metre travelled",
    )
    prior_nominal: float = param(
        0.8,
        unit="1",
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="prior (and switching target) of NOMINAL; the rest is shared by the faults",
    )
    switch_rate_per_m: float = param(
        0.005,
        unit="1/m",
        lo=0.0,
        hi=100.0,
        doc="Markov switching toward the prior, per metre travelled",
    )
    outlier_chi2: float = param(
        25.0,
        unit="1",
        lo=0.0,
        lo_open=True,
        hi=1e6,
        doc="a fix whose best Mahalanobis^2 exceeds this updates nothing (outlier)",
    )
    min_travel_m: float = param(
        0.002,
        unit="m",
        lo=0.0,
        hi=1.0,
        doc="travel since the last fix below which the probabilities are not updated",
    )
    max_pending_intervals: int = param(
        10,
        unit="intervals",
        lo=1,
        hi=1000,
        doc="odometry intervals accumulated before a covariance step (a fix flushes earlier)",
    )
    radius_feed_probability: float = param(
        0.9,
        unit="1",
        lo=0.0,
        hi=1.0,
        doc="radii of the top hypothesis feed odometry from this probability on (else the mean)",
    )


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """The bank's verdict: most likely hypothesis, its probability, all of them, the radii."""

    hypothesis: Hypothesis
    probability: float
    probabilities: tuple[float, ...]  # indexed by Hypothesis
    radius_left_m: float
    radius_right_m: float

    @property
    def name(self) -> str:
        return HYPOTHESIS_NAMES[self.hypothesis]


class _Filter(ExtendedKalmanFilter):
    """One hypothesis: a filterpy EKF over [x, y, phi, params...] with its wheel model."""

    x: np.ndarray
    P: np.ndarray

    def __init__(
        self, hyp: Hypothesis, n_par: int, r0: float, half_track_m: float, p: DiagnosisParams
    ) -> None:
        super().__init__(dim_x=3 + n_par, dim_z=3)
        self.hyp = hyp
        self.n_par = n_par
        self.r0 = r0
        self.b = half_track_m
        self.cfg = p
        self._x_next: np.ndarray | None = None

    # -- the hypothesis' wheel model --------------------------------------------------------

    def wheel_travel(
        self, th_l: float, dth_l: float, th_r: float, dth_r: float
    ) -> tuple[float, float, list[float], list[float]]:
        """Ground travel of each wheel and its derivative w.r.t. the parameters."""
        r0 = self.r0
        h = self.hyp
        x = self.x
        if h == Hypothesis.NOMINAL:
            return r0 * dth_l, r0 * dth_r, [], []
        if h == Hypothesis.FLAT_LEFT:
            return float(x[3]) * dth_l, r0 * dth_r, [dth_l], [0.0]
        if h == Hypothesis.FLAT_RIGHT:
            return r0 * dth_l, float(x[3]) * dth_r, [0.0], [dth_r]
        if h == Hypothesis.SLIP:
            k = 1.0 - float(x[3])
            return r0 * k * dth_l, r0 * k * dth_r, [-r0 * dth_l], [-r0 * dth_r]
        a, b = float(x[3]), float(x[4])
        th0, dth = (th_l, dth_l) if h == Hypothesis.BUMP_LEFT else (th_r, dth_r)
        th1 = th0 + dth
        ja = math.sin(th1) - math.sin(th0)
        jb = math.cos(th0) - math.cos(th1)
        ds = r0 * dth + a * ja + b * jb
        if h == Hypothesis.BUMP_LEFT:
            return ds, r0 * dth_r, [ja, jb], [0.0, 0.0]
        return r0 * dth_l, ds, [0.0, 0.0], [ja, jb]

    def radii(self) -> tuple[float, float]:
        """Mean effective rolling radii under this hypothesis (bump: nominal on average)."""
        r0, h, x = self.r0, self.hyp, self.x
        if h == Hypothesis.FLAT_LEFT:
            return float(x[3]), r0
        if h == Hypothesis.FLAT_RIGHT:
            return r0, float(x[3])
        if h == Hypothesis.SLIP:
            r = r0 * (1.0 - float(x[3]))
            return r, r
        return r0, r0

    def project(self) -> None:
        """Keep the parameters inside the hypothesis' admissible set."""
        c, h, x = self.cfg, self.hyp, self.x
        if h in (Hypothesis.FLAT_LEFT, Hypothesis.FLAT_RIGHT):
            x[3] = min(max(float(x[3]), c.flat_min_radius_m), self.r0 - c.flat_min_deflection_m)
        elif h == Hypothesis.SLIP:
            x[3] = min(max(float(x[3]), c.slip_min_ratio), c.slip_max_ratio)
        elif h in (Hypothesis.BUMP_LEFT, Hypothesis.BUMP_RIGHT):
            a, b = float(x[3]), float(x[4])
            amp = math.hypot(a, b)
            lo, hi = c.bump_min_amplitude_m, c.bump_max_amplitude_m
            if amp < 1e-12:
                x[3], x[4] = lo, 0.0
            elif amp < lo or amp > hi:
                k = (lo if amp < lo else hi) / amp
                x[3], x[4] = a * k, b * k

    @property
    def prior_cov(self) -> np.ndarray:
        return np.diag(self.initial_params()[1])

    def initial_params(self) -> tuple[list[float], list[float]]:
        c, h = self.cfg, self.hyp
        if h in (Hypothesis.FLAT_LEFT, Hypothesis.FLAT_RIGHT):
            return [self.r0 - c.flat_min_deflection_m], [c.flat_initial_std_m**2]
        if h == Hypothesis.SLIP:
            return [c.slip_min_ratio], [c.slip_initial_std**2]
        if h in (Hypothesis.BUMP_LEFT, Hypothesis.BUMP_RIGHT):
            v = c.bump_initial_std_m**2
            return [c.bump_min_amplitude_m, 0.0], [v, v]
        return [], []

    def walk(self, dist_m: float) -> list[float]:
        c, h = self.cfg, self.hyp
        if h in (Hypothesis.FLAT_LEFT, Hypothesis.FLAT_RIGHT):
            return [c.flat_walk_m2_per_m * dist_m]
        if h == Hypothesis.SLIP:
            return [c.slip_walk_per_m * dist_m]
        if h in (Hypothesis.BUMP_LEFT, Hypothesis.BUMP_RIGHT):
            q = c.bump_walk_m2_per_m * dist_m
            return [q, q]
        return []

    # -- prediction: accumulated in floats per interval, one covariance step per flush -------

    def begin(self) -> None:
        """Start accumulating motion from the current state."""
        x = self.x
        self._x0 = (float(x[0]), float(x[1]), float(x[2]))
        self._pose = list(self._x0)
        self._dp = [[0.0] * self.n_par for _ in range(3)]  # d(pose)/d(params)
        self._q = [0.0] * 6  # xx, xy, yy, xp, yp, pp
        self._dist = 0.0
        self._steps = 0

    def accumulate(self, th_l: float, dth_l: float, th_r: float, dth_r: float) -> None:
        """Add one odometry interval (wheel angles in rad) to the pending prediction."""
        ds_l, ds_r, j_l, j_r = self.wheel_travel(th_l, dth_l, th_r, dth_r)
        b = self.b
        pose = self._pose
        ds = 0.5 * (ds_l + ds_r)
        dphi = (ds_r - ds_l) / (2.0 * b)
        half = 0.5 * dphi
        if -1e-4 < half < 1e-4:
            chord = ds * (1.0 - half * half / 6.0)
        else:
            chord = ds * math.sin(half) / half
        m = pose[2] + half
        cm, sm = math.cos(m), math.sin(m)
        dx, dy = chord * cm, chord * sm
        k = chord / (4.0 * b)
        gp = 1.0 / (2.0 * b)
        lx, ly, rx, ry = 0.5 * cm + k * sm, 0.5 * sm - k * cm, 0.5 * cm - k * sm, 0.5 * sm + k * cm
        dp = self._dp
        for j in range(self.n_par):
            a, bb = j_l[j], j_r[j]
            dphi_j = dp[2][j]
            dp[0][j] += -dy * dphi_j + lx * a + rx * bb
            dp[1][j] += dx * dphi_j + ly * a + ry * bb
            dp[2][j] += gp * (bb - a)
        c = self.cfg
        vl = c.wheel_noise_m2_per_m * abs(ds_l)
        vr = c.wheel_noise_m2_per_m * abs(ds_r)
        q = self._q
        q[0] += lx * lx * vl + rx * rx * vr
        q[1] += lx * ly * vl + rx * ry * vr
        q[2] += ly * ly * vl + ry * ry * vr
        q[3] += gp * (rx * vr - lx * vl)
        q[4] += gp * (ry * vr - ly * vl)
        q[5] += gp * gp * (vl + vr)
        pose[0] += dx
        pose[1] += dy
        pose[2] += dphi
        self._dist += 0.5 * (abs(ds_l) + abs(ds_r))
        self._steps += 1

    def predict_x(self, u: object = 0) -> None:
        assert self._x_next is not None
        self.x = self._x_next
        self._x_next = None

    def flush(self) -> bool:
        """Apply the accumulated motion: mean and covariance (filterpy's ``predict``)."""
        if not self._steps:
            return True
        x0, y0, _ = self._x0
        px, py, pphi = self._pose
        n = 3 + self.n_par
        F = np.eye(n)
        F[0, 2] = -(py - y0)
        F[1, 2] = px - x0
        if self.n_par:
            F[:3, 3:] = self._dp
        q = self._q
        Q = np.zeros((n, n))
        Q[:3, :3] = [[q[0], q[1], q[3]], [q[1], q[2], q[4]], [q[3], q[4], q[5]]]
        for j, w in enumerate(self.walk(self._dist)):
            Q[3 + j, 3 + j] = w
        x_new = self.x.copy()
        x_new[0], x_new[1], x_new[2] = px, py, wrap_angle(pphi)
        self.F, self.Q = F, Q
        x_old, p_old = self.x, self.P
        self._x_next = x_new
        self.predict()
        P = self.P
        ok = math.isfinite(float(P.trace())) and math.isfinite(float(self.x.sum()))
        if ok:
            self.P = 0.5 * (P + P.T)
            if self.n_par:
                self.project()
        else:
            self.x, self.P = x_old, p_old
        self.begin()
        return ok


_PARAMS_OF = {
    Hypothesis.NOMINAL: 0,
    Hypothesis.FLAT_LEFT: 1,
    Hypothesis.FLAT_RIGHT: 1,
    Hypothesis.BUMP_LEFT: 2,
    Hypothesis.BUMP_RIGHT: 2,
    Hypothesis.SLIP: 1,
}


def _inv3(S: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Inverse and determinant of a symmetric positive 3x3 matrix (adjugate; None if singular)."""
    (a, b, c), (_, d, e), (_, _, f) = S.tolist()
    A = d * f - e * e
    B = c * e - b * f
    C = b * e - c * d
    det = a * A + b * B + c * C
    if not (det > 0.0 and math.isfinite(det)):
        return None
    D = a * f - c * c
    E = b * c - a * e
    F = a * d - b * b
    r = 1.0 / det
    return np.array([[A * r, B * r, C * r], [B * r, D * r, E * r], [C * r, E * r, F * r]]), det


class FaultBank:
    """The bank of hypothesis filters and their probabilities (see the module docstring)."""

    def __init__(
        self,
        half_track_m: float,
        nominal_radius_m: float,
        params: DiagnosisParams | None = None,
        pose: Pose | None = None,
    ) -> None:
        self.params = p = params or DiagnosisParams()
        self.r0 = nominal_radius_m
        self.half_track_m = half_track_m
        self.filters = [
            _Filter(h, _PARAMS_OF[h], nominal_radius_m, half_track_m, p) for h in Hypothesis
        ]
        n = len(self.filters)
        rest = (1.0 - p.prior_nominal) / (n - 1)
        self.prior = np.array([p.prior_nominal] + [rest] * (n - 1))
        self._R = np.diag([p.fix_pos_std_m**2, p.fix_pos_std_m**2, p.fix_heading_std_rad**2])
        self.fixes_used = 0
        self.fixes_outlier = 0
        self.nonfinite_count = 0
        self.numerical_failures = 0
        self.last_log_likelihoods = np.zeros(n)
        self.reset(pose or Pose(0.0, 0.0, 0.0))

    def reset(self, pose: Pose) -> None:
        """Restart every filter at ``pose`` (e.g. the first fix) with the prior probabilities."""
        p = self.params
        for f in self.filters:
            par, var = f.initial_params()
            f.x = np.array([pose.x_m, pose.y_m, wrap_angle(pose.heading_rad), *par], dtype=float)
            f.P = np.diag(
                [
                    p.initial_pos_std_m**2,
                    p.initial_pos_std_m**2,
                    p.initial_heading_std_rad**2,
                    *var,
                ]
            )
            f.R = self._R.copy()
            f.begin()
        self._pending = 0
        self.prob = self.prior.copy()
        self._c = self.prior.copy()
        self._last: tuple[float, float] | None = None
        self._travel_m = 0.0

    # -- inputs ----------------------------------------------------------------------------

    def predict(self, pos_left_rev: float, pos_right_rev: float) -> bool:
        """Propagate every filter with the drives' encoder positions (wheel revolutions)."""
        pl, pr = float(pos_left_rev), float(pos_right_rev)
        if not (math.isfinite(pl) and math.isfinite(pr)):
            self.nonfinite_count += 1
            return False
        th_l, th_r = pl * TWO_PI, pr * TWO_PI
        last = self._last
        self._last = (th_l, th_r)
        if last is None:
            return False
        dth_l, dth_r = th_l - last[0], th_r - last[1]
        # a jump beyond physics (a drive rebooted, its position reset): re-take the baseline
        if abs(dth_l) * self.r0 > 0.5 or abs(dth_r) * self.r0 > 0.5:
            return False
        for f in self.filters:
            f.accumulate(last[0], dth_l, last[1], dth_r)
        self._pending += 1
        self._travel_m += 0.5 * self.r0 * (abs(dth_l) + abs(dth_r))
        if self._pending >= self.params.max_pending_intervals:
            self._flush()
        return True

    def _flush(self) -> None:
        self._pending = 0
        ok = True
        for f in self.filters:
            ok = f.flush() and ok
        if not ok:
            self.numerical_failures += 1

    def correct(self, x_m: float, y_m: float, heading_rad: float) -> bool:
        """Fuse a pose fix into every filter and update the probabilities; False if ignored."""
        if not (math.isfinite(x_m) and math.isfinite(y_m) and math.isfinite(heading_rad)):
            self.nonfinite_count += 1
            return False
        self._flush()
        n = len(self.filters)
        ll = np.empty(n)
        d2 = np.empty(n)
        innovations: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        R = self._R
        log2pi3 = 3.0 * math.log(TWO_PI)
        for i, f in enumerate(self.filters):
            x = f.x
            y = np.array(
                [x_m - x[0], y_m - x[1], wrap_angle(heading_rad - float(x[2]))], dtype=float
            )
            S = f.P[:3, :3] + R
            inv = _inv3(S)
            if inv is None:
                self.numerical_failures += 1
                return False
            SI, det = inv
            d2[i] = float(y @ SI @ y)
            ll[i] = -0.5 * (d2[i] + math.log(det) + log2pi3)
            innovations.append((y, S, SI))
        if not np.isfinite(ll).all():
            self.numerical_failures += 1
            return False
        if float(d2.min()) > self.params.outlier_chi2:
            self.fixes_outlier += 1
            return False
        for f, (y, S, SI) in zip(self.filters, innovations, strict=True):
            # Joseph-form update with H = [I3 0]; filterpy's update() would invert S again, so
            # the equations are applied here and the filter's y/S/SI/K filled as filterpy does
            P = f.P
            K = P[:, :3] @ SI
            x = f.x + K @ y
            I_KH = np.eye(P.shape[0])
            I_KH[:, :3] -= K
            P = I_KH @ P @ I_KH.T + K @ R @ K.T
            if not (np.isfinite(x).all() and np.isfinite(P).all()):
                self.numerical_failures += 1
                continue
            x[2] = wrap_angle(float(x[2]))
            f.x, f.P = x, 0.5 * (P + P.T)
            f.y, f.S, f.SI, f.K = y, S, SI, K
            f.project()
            f.begin()
        self.fixes_used += 1
        self.last_log_likelihoods = ll
        travel, self._travel_m = self._travel_m, 0.0
        if travel < self.params.min_travel_m:
            return True
        # model probabilities: predicted (c, from the last mixing step) times likelihood
        logp = np.log(np.maximum(self._c, 1e-300)) + ll
        logp -= logp.max()
        post = np.exp(logp)
        self.prob = post / post.sum()
        self._mix(1.0 - math.exp(-self.params.switch_rate_per_m * travel))
        return True

    def _mix(self, eps: float) -> None:
        """IMM mixing of the pose block: unlikely filters restart from the mixture of the likely.

        Transition ``pi_ij = (1 - eps) delta_ij + eps prior_j``; each filter's pose mean and
        covariance become the mixture over ``mu_i|j = pi_ij mu_i / c_j``; its own parameters
        (and their cross-covariance with the pose) are kept.
        """
        prob, prior = self.prob, self.prior
        c = (1.0 - eps) * prob + eps * prior
        self._c = c
        if eps <= 0.0:
            return
        # W[i, j] = mu_i|j = pi_ij mu_i / c_j
        W = eps * np.outer(prob, prior)
        W[np.diag_indices_from(W)] += (1.0 - eps) * prob
        W /= c[None, :]
        filters = self.filters
        poses = np.array([f.x[:3] for f in filters])
        covs = np.array([f.P[:3, :3] for f in filters])
        Wt = W.T  # Wt[j, i] = mu_i|j
        d = poses[None, :, :] - poses[:, None, :]  # d[j, i] = pose_i - pose_j
        d[..., 2] = (d[..., 2] + math.pi) % TWO_PI - math.pi
        mean_d = np.einsum("ji,jik->jk", Wt, d)
        e = d - mean_d[:, None, :]
        pcs = np.einsum("ji,ikl->jkl", Wt, covs) + np.einsum("ji,jik,jil->jkl", Wt, e, e)
        for j, fj in enumerate(filters):
            keep = float(Wt[j, j])
            if keep > 1.0 - 1e-9:
                continue
            x = fj.x.copy()
            x[:3] = poses[j] + mean_d[j]
            x[2] = wrap_angle(float(x[2]))
            P = fj.P.copy()
            pc = pcs[j]
            P[:3, :3] = 0.5 * (pc + pc.T)
            if fj.n_par:
                # an unlikely filter's parameters relax toward their prior uncertainty, so that
                # it can learn its fault quickly when the fault appears
                P[3:, 3:] = keep * P[3:, 3:] + (1.0 - keep) * fj.prior_cov
                P[:3, 3:] *= math.sqrt(keep)
                P[3:, :3] *= math.sqrt(keep)
                try:
                    np.linalg.cholesky(P)
                except np.linalg.LinAlgError:
                    P[:3, 3:] = 0.0
                    P[3:, :3] = 0.0
            fj.x, fj.P = x, P
            fj.begin()

    # -- outputs ---------------------------------------------------------------------------

    def diagnosis(self) -> Diagnosis:
        prob = self.prob
        i = int(np.argmax(prob))
        rl, rr = self.radii()
        return Diagnosis(Hypothesis(i), float(prob[i]), tuple(float(v) for v in prob), rl, rr)

    def radii(self) -> tuple[float, float]:
        """Effective rolling radii (left, right) for odometry (see the module docstring)."""
        prob = self.prob
        i = int(np.argmax(prob))
        if prob[i] >= self.params.radius_feed_probability:
            return self.filters[i].radii()
        rl = rr = 0.0
        for w, f in zip(prob, self.filters, strict=True):
            a, b = f.radii()
            rl += float(w) * a
            rr += float(w) * b
        return rl, rr

    def parameters(self) -> dict[str, list[float]]:
        """Each hypothesis' parameter estimates (for logs)."""
        return {HYPOTHESIS_NAMES[f.hyp]: [float(v) for v in f.x[3:]] for f in self.filters}
