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

from controller import kernels
from controller.ekf import ExtendedKalmanFilter
from controller.kernels import bank_step
from controller.kinematics import TWO_PI
from controller.pose_ekf import inv_sym3
from controller.types import Pose, wrap_angle
from dbc.codec import Hypothesis
from dbc.runtime.params import param

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
        """The most likely hypothesis' name (:data:`HYPOTHESIS_NAMES`)."""
        return HYPOTHESIS_NAMES[self.hypothesis]


_NOMINAL = int(Hypothesis.NOMINAL)
_FLAT_LEFT = int(Hypothesis.FLAT_LEFT)
_FLAT_RIGHT = int(Hypothesis.FLAT_RIGHT)
_BUMP_LEFT = int(Hypothesis.BUMP_LEFT)
_BUMP_RIGHT = int(Hypothesis.BUMP_RIGHT)
_SLIP = int(Hypothesis.SLIP)
# the compiled wheel models know the hypotheses by these numbers
assert (_NOMINAL, _FLAT_LEFT, _FLAT_RIGHT, _BUMP_LEFT, _BUMP_RIGHT, _SLIP) == (
    kernels.NOMINAL,
    kernels.FLAT_LEFT,
    kernels.FLAT_RIGHT,
    kernels.BUMP_LEFT,
    kernels.BUMP_RIGHT,
    kernels.SLIP,
)

#: The bank handles its filters' matrices as one stack, each zero-padded to this size.
_N = 5

#: Where the values of :meth:`_Filter.step` go in a filter's ``F`` and ``Q`` (zero-padded to
#: :data:`_N`), as indices into ``[F.ravel(), Q.ravel()]``: ``F[:3, 2:]``, ``Q[:3, :3]``,
#: ``Q[3, 3]``, ``Q[4, 4]``.
_STEP_ENTRIES = np.array(
    [r * _N + c for r in range(3) for c in range(2, 5)]
    + [_N * _N + r * _N + c for r in range(3) for c in range(3)]
    + [_N * _N + 3 * _N + 3, _N * _N + 4 * _N + 4]
)

#: One odometry interval: previous wheel angles and their increments (rad), and the nominal
#: ground travel ``r0 dtheta`` of each wheel (m): ``(th_l, dth_l, th_r, dth_r, ds_l, ds_r)``.
_Interval = tuple[float, float, float, float, float, float]


class _Filter(ExtendedKalmanFilter):
    """One hypothesis: a filterpy EKF over [x, y, phi, params...] with its wheel model.

    :meth:`begin` snapshots the state; :meth:`step` integrates the odometry intervals since
    then into the mean and the ``F`` and ``Q`` of one covariance step, which the bank applies to
    all filters at once (:meth:`FaultBank._flush`), setting ``F``, ``Q``, ``x_prior`` and
    ``P_prior`` as filterpy's ``predict`` does.
    """

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
        self._kind = int(hyp)
        walk = self.walk(1.0)
        self._walk_per_m = walk[0] if walk else 0.0
        self._noise = p.wheel_noise_m2_per_m
        if hyp in (Hypothesis.FLAT_LEFT, Hypothesis.FLAT_RIGHT):
            self._bounds = (p.flat_min_radius_m, r0 - p.flat_min_deflection_m)
        elif hyp == Hypothesis.SLIP:
            self._bounds = (p.slip_min_ratio, p.slip_max_ratio)
        else:
            self._bounds = (p.bump_min_amplitude_m, p.bump_max_amplitude_m)

    # -- the hypothesis' wheel model --------------------------------------------------------

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

    def projected(self, par: list[float]) -> list[float]:
        """The parameters ``par`` brought into the hypothesis' admissible set."""
        kind = self._kind
        if kind == _NOMINAL:
            return par
        lo, hi = self._bounds
        if kind != _BUMP_LEFT and kind != _BUMP_RIGHT:
            return [min(max(par[0], lo), hi)]
        a, b = par
        amp = math.hypot(a, b)
        if amp < 1e-12:
            return [lo, 0.0]
        if amp < lo or amp > hi:
            k = (lo if amp < lo else hi) / amp
            return [a * k, b * k]
        return par

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

    # -- prediction: integrated in floats per interval, one covariance step per flush --------

    def begin(self, x: list[float] | None = None) -> None:
        """Take the state (``x``: ``self.x`` as floats) the next step starts from."""
        self._x0: list[float] = self.x.tolist() if x is None else x

    def step(self, intervals: list[_Interval]) -> tuple[list[float], list[float]]:
        """Integrate ``intervals`` from the state taken by :meth:`begin`
        (:func:`controller.kernels.bank_step`, compiled where the package was built so).

        Returns the entries of the covariance step's ``F`` and ``Q`` that are not those of the
        identity and zero (:data:`_STEP_ENTRIES`, padded to :data:`_N`), and the new mean.
        """
        return bank_step(
            self._kind,
            self.n_par,
            self.r0,
            self.b,
            self._noise,
            self._walk_per_m,
            self._x0,
            intervals,
        )


_PAD = [0.0] * _N

_PARAMS_OF = {
    Hypothesis.NOMINAL: 0,
    Hypothesis.FLAT_LEFT: 1,
    Hypothesis.FLAT_RIGHT: 1,
    Hypothesis.BUMP_LEFT: 2,
    Hypothesis.BUMP_RIGHT: 2,
    Hypothesis.SLIP: 1,
}


class FaultBank:
    """The bank of hypothesis filters and their probabilities (see the module docstring).

    Computation: the bank queues the odometry intervals; at a flush each filter integrates them
    in floats (:meth:`_Filter.step`).  The covariance steps, the fix updates and the mixing
    treat the filters' covariances as one stack of 5x5 matrices (each zero-padded: the padding
    adds exact zeros, so every filter gets the numbers of its own matrices), each filter's ``P``
    being a view of its block of the stack.
    """

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
        self._dims = [3 + f.n_par for f in self.filters]
        rest = (1.0 - p.prior_nominal) / (n - 1)
        self.prior = np.array([p.prior_nominal] + [rest] * (n - 1))
        self._R = np.diag([p.fix_pos_std_m**2, p.fix_pos_std_m**2, p.fix_heading_std_rad**2])
        self._eye = np.array(np.broadcast_to(np.eye(_N), (n, _N, _N)))
        self._FQ0 = np.zeros((n, 2 * _N * _N))  # F = I, Q = 0, raveled side by side
        self._FQ0[:, : _N * _N] = np.eye(_N).ravel()
        # each filter's prior parameter covariance, padded (IMM mixing relaxes toward it)
        self._prior_cov = np.zeros((n, _N, _N))
        for i, f in enumerate(self.filters):
            var = f.initial_params()[1]
            self._prior_cov[i, 3 : 3 + len(var), 3 : 3 + len(var)] = np.diag(var)
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
        self._intervals: list[_Interval] = []
        self._stack: np.ndarray | None = None
        self._stack_views: list[np.ndarray] = []
        self.prob = self.prior.copy()
        self._c = self.prior.copy()
        self._last: tuple[float, float] | None = None
        self._travel_m = 0.0

    # -- the stack of covariances ----------------------------------------------------------

    def _covariances(self) -> np.ndarray:
        """The filters' covariances as a zero-padded stack (each ``P`` a view of its block)."""
        stack = self._stack
        if stack is not None and all(
            f.P is v and v.base is stack
            for f, v in zip(self.filters, self._stack_views, strict=True)
        ):
            return stack  # every P is still the view set by _set_covariances
        stack = np.zeros((len(self.filters), _N, _N))
        for i, (f, n) in enumerate(zip(self.filters, self._dims, strict=True)):
            stack[i, :n, :n] = f.P
        return stack

    def _set_covariances(self, stack: np.ndarray) -> None:
        """Make ``stack`` (zero-padded) the filters' covariances."""
        self._stack = stack
        self._stack_views = views = [stack[i, :n, :n] for i, n in enumerate(self._dims)]
        for f, v in zip(self.filters, views, strict=True):
            f.P = v

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
        th0_l, th0_r = last
        dth_l, dth_r = th_l - th0_l, th_r - th0_r
        # a jump beyond physics (a drive rebooted, its position reset): re-take the baseline
        r0 = self.r0
        if abs(dth_l) * r0 > 0.5 or abs(dth_r) * r0 > 0.5:
            return False
        intervals = self._intervals
        intervals.append((th0_l, dth_l, th0_r, dth_r, r0 * dth_l, r0 * dth_r))
        self._travel_m += 0.5 * r0 * (abs(dth_l) + abs(dth_r))
        if len(intervals) >= self.params.max_pending_intervals:
            self._flush()
        return True

    def _flush(self) -> None:
        """Apply the queued intervals: filterpy's ``predict`` for every filter, as one stack.

        ``x = f(x)``, ``P = F P F' + Q`` (priors saved), then, if finite, ``P`` symmetrised and
        the parameters projected; otherwise the filter keeps its state.
        """
        intervals = self._intervals
        if not intervals:
            return
        self._intervals = []
        filters = self.filters
        m = len(filters)
        steps = [f.step(intervals) for f in filters]
        FQ = self._FQ0.copy()
        FQ[:, _STEP_ENTRIES] = [s[0] for s in steps]
        F = FQ[:, : _N * _N].reshape(m, _N, _N)
        Q = FQ[:, _N * _N :].reshape(m, _N, _N)
        P_old = self._covariances()
        P = F @ P_old @ F.transpose(0, 2, 1) + Q
        P_sym = 0.5 * (P + P.transpose(0, 2, 1))
        all_finite = bool(np.isfinite(P).all())
        ok = True
        for i, (f, n, (_, x)) in enumerate(zip(filters, self._dims, steps, strict=True)):
            f.F, f.Q, f.P_prior = F[i, :n, :n], Q[i, :n, :n], P[i, :n, :n]
            f.x_prior = np.array(x)
            finite = all_finite or math.isfinite(float(P[i, :n, :n].trace()))
            if finite and math.isfinite(sum(x)):
                x[3:] = f.projected(x[3:])
                f.x = np.array(x)
                f.begin(x)
            else:  # the filter keeps its state
                ok = False
                P_sym[i] = P_old[i]
                f.begin()
        if not ok:
            self.numerical_failures += 1
        self._set_covariances(P_sym)

    def correct(self, x_m: float, y_m: float, heading_rad: float) -> bool:
        """Fuse a pose fix into every filter and update the probabilities; False if ignored."""
        if not (math.isfinite(x_m) and math.isfinite(y_m) and math.isfinite(heading_rad)):
            self.nonfinite_count += 1
            return False
        self._flush()
        filters = self.filters
        xs = [f.x.tolist() for f in filters]
        P = self._covariances()
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self._R.tolist()
        log2pi3 = 3.0 * math.log(TWO_PI)
        ll: list[float] = []
        d2: list[float] = []
        rows: list[float] = []  # per filter: x (padded), y, S, SI (row-major)
        for x, ((p00, p01, p02), (p10, p11, p12), (p20, p21, p22)) in zip(
            xs, P[:, :3, :3].tolist(), strict=True
        ):
            y0, y1, y2 = x_m - x[0], y_m - x[1], wrap_angle(heading_rad - x[2])
            s00, s01, s02 = p00 + r00, p01 + r01, p02 + r02
            s10, s11, s12 = p10 + r10, p11 + r11, p12 + r12
            s20, s21, s22 = p20 + r20, p21 + r21, p22 + r22
            inv = inv_sym3(s00, s01, s02, s11, s12, s22)
            if inv is None:
                self.numerical_failures += 1
                return False
            ((i00, i01, i02), (i10, i11, i12), (i20, i21, i22)), det = inv
            # y' SI y, summed in numpy's order
            v0 = y0 * i00 + y1 * i10 + y2 * i20
            v1 = y0 * i01 + y1 * i11 + y2 * i21
            v2 = y0 * i02 + y1 * i12 + y2 * i22
            d = v0 * y0 + v1 * y1 + v2 * y2
            d2.append(d)
            ll.append(-0.5 * (d + math.log(det) + log2pi3))
            rows += x
            rows += _PAD[len(x) :]
            rows += (y0, y1, y2, s00, s01, s02, s10, s11, s12, s20, s21, s22)
            rows += (i00, i01, i02, i10, i11, i12, i20, i21, i22)
        if not all(map(math.isfinite, ll)):
            self.numerical_failures += 1
            return False
        if min(d2) > self.params.outlier_chi2:
            self.fixes_outlier += 1
            return False
        # Joseph-form update with H = [I3 0], for the whole stack; filterpy's update() would
        # invert S again, so the equations are applied here and each filter's y/S/SI/K filled
        # as filterpy does
        n_f = len(filters)
        xySSI = np.array(rows).reshape(n_f, _N + 21)
        Y = xySSI[:, _N : _N + 3]
        S = xySSI[:, _N + 3 : _N + 12].reshape(n_f, 3, 3)
        SI = xySSI[:, _N + 12 :].reshape(n_f, 3, 3)
        R = self._R
        K = P[:, :, :3] @ SI
        X = xySSI[:, :_N] + (K @ Y[:, :, None])[:, :, 0]
        I_KH = self._eye.copy()
        I_KH[:, :, :3] -= K
        P_new = I_KH @ P @ I_KH.transpose(0, 2, 1) + K @ R @ K.transpose(0, 2, 1)
        P_sym = 0.5 * (P_new + P_new.transpose(0, 2, 1))
        all_finite = bool(np.isfinite(X).all() and np.isfinite(P_new).all())
        X_rows = X.tolist()
        updated = []
        for i, (f, n) in enumerate(zip(filters, self._dims, strict=True)):
            if not all_finite and not (
                np.isfinite(X[i, :n]).all() and np.isfinite(P_new[i, :n, :n]).all()
            ):
                self.numerical_failures += 1
                P_sym[i] = P[i]  # the filter keeps its state
                continue
            x = X_rows[i][:n]
            x[2] = wrap_angle(x[2])
            x[3:] = f.projected(x[3:])
            xs[i] = x
            f.y, f.S, f.SI, f.K = Y[i], S[i], SI[i], K[i, :n]
            updated.append(i)
        self.fixes_used += 1
        self.last_log_likelihoods = lla = np.array(ll)
        travel, self._travel_m = self._travel_m, 0.0
        if travel >= self.params.min_travel_m:
            # model probabilities: predicted (c, from the last mixing step) times likelihood
            logp = np.log(np.maximum(self._c, 1e-300)) + lla
            logp -= max(logp.tolist())
            post = np.exp(logp)
            self.prob = post / post.sum()
            eps = 1.0 - math.exp(-self.params.switch_rate_per_m * travel)
            P_sym, mixed = self._mix(eps, xs, P_sym)
            updated = sorted({*updated, *mixed})
        for i in updated:
            x = xs[i]
            f = filters[i]
            f.x = np.array(x)
            f.begin(x)
        self._set_covariances(P_sym)
        return True

    def _mix(
        self, eps: float, xs: list[list[float]], Ps: np.ndarray
    ) -> tuple[np.ndarray, list[int]]:
        """IMM mixing of the pose block: unlikely filters restart from the mixture of the likely.

        Transition ``pi_ij = (1 - eps) delta_ij + eps prior_j``; each filter's pose mean and
        covariance become the mixture over ``mu_i|j = pi_ij mu_i / c_j``; its own parameters
        (and their cross-covariance with the pose) are kept.

        ``xs``: the filters' states as floats (the mixed ones are replaced), ``Ps``: their
        covariances as a padded stack.  Returns the new stack and the filters mixed.
        """
        prob, prior = self.prob, self.prior
        c = (1.0 - eps) * prob + eps * prior
        self._c = c
        if eps <= 0.0:
            return Ps, []
        # W[i, j] = mu_i|j = pi_ij mu_i / c_j
        n_f = len(xs)
        W = eps * (prob[:, None] * prior[None, :])  # np.outer
        W.flat[:: n_f + 1] += (1.0 - eps) * prob
        W /= c[None, :]
        keep = W.diagonal()
        mixed = [j for j, k in enumerate(keep.tolist()) if not k > 1.0 - 1e-9]
        if not mixed:
            return Ps, []
        Wt = W.T  # Wt[j, i] = mu_i|j
        poses = np.array([x[:3] for x in xs])
        covs = np.ascontiguousarray(Ps[:, :3, :3])
        d = poses[None, :, :] - poses[:, None, :]  # d[j, i] = pose_i - pose_j
        d[..., 2] = (d[..., 2] + math.pi) % TWO_PI - math.pi
        mean_d = np.einsum("ji,jik->jk", Wt, d)
        e = d - mean_d[:, None, :]
        pcs = np.einsum("ji,ikl->jkl", Wt, covs) + np.einsum("ji,jik,jil->jkl", Wt, e, e)
        # new covariances for the whole stack; the filters not mixed keep theirs below
        P = Ps.copy()
        P[:, :3, :3] = 0.5 * (pcs + pcs.transpose(0, 2, 1))
        # an unlikely filter's parameters relax toward their prior uncertainty, so that it
        # can learn its fault quickly when the fault appears
        k3 = keep[:, None, None]
        P[:, 3:, 3:] = k3 * P[:, 3:, 3:] + (1.0 - k3) * self._prior_cov[:, 3:, 3:]
        sk = np.sqrt(k3)
        P[:, :3, 3:] *= sk
        P[:, 3:, :3] *= sk
        for j in range(n_f):
            if j not in mixed:
                P[j] = Ps[j]
        dims = self._dims
        for n in (4, 5):  # the filters with parameters, by size
            group = [j for j in mixed if dims[j] == n]
            if not group:
                continue
            try:
                np.linalg.cholesky(P[group, :n, :n])
            except np.linalg.LinAlgError:
                for j in group:
                    try:
                        np.linalg.cholesky(P[j, :n, :n])
                    except np.linalg.LinAlgError:
                        P[j, :3, 3:] = 0.0
                        P[j, 3:, :3] = 0.0
        new_poses = (poses + mean_d).tolist()
        for j in mixed:
            x = new_poses[j] + xs[j][3:]
            x[2] = wrap_angle(x[2])
            xs[j] = x
        return P, mixed

    # -- outputs ---------------------------------------------------------------------------

    def diagnosis(self) -> Diagnosis:
        """The bank's verdict: the likeliest hypothesis, every probability, the effective radii."""
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
