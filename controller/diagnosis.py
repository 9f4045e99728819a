"""Fault diagnosis: a bank of Kalman filters, one per fault hypothesis (multiple-model estimation).

This module owns what the controller believes about the chair's wheels: which fault is most
likely (the paper's "Faults and uncertainty injection system": one filter per fault, each
encapsulating the chair's kinematic model with that fault's parameters, all fed the same
inputs) and the effective rolling radii that follow from it.

Every filter is an extended Kalman filter over the pose ``[x, y, phi]`` of the axle midpoint
plus the parameters of its hypothesis, with filterpy's :class:`~filterpy.kalman.ExtendedKalmanFilter`
equations (``tests/unit/controller/test_diagnosis.py`` holds every step to them):

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

The arithmetic is plain floats on each filter's own states (:mod:`controller.kernels`,
compiled where the package was built so), every sum in index order: the same numbers
compiled or from source and on every machine, where numpy's stacked products would take
their order and fused multiply-adds from the BLAS kernel the CPU selects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller import kernels
from controller.kernels import bank_fix, bank_flush, imm_mix, posterior, project, step_matrices
from controller.kinematics import TWO_PI
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

#: One odometry interval: previous wheel angles and their increments (rad), and the nominal
#: ground travel ``r0 dtheta`` of each wheel (m): ``(th_l, dth_l, th_r, dth_r, ds_l, ds_r)``.
_Interval = tuple[float, float, float, float, float, float]


def _square(values: list[float], n: int) -> np.ndarray:
    return np.array(values).reshape(n, n)


class _Filter:
    """One hypothesis: its wheel model, its parameters' bounds, and its state.

    The bank keeps the state in floats (:attr:`xl`, the mean; :attr:`Pl`, the covariance row
    by row) and computes on them (:mod:`controller.kernels`).  The filterpy names read it as
    arrays, built when first read after a change: ``x``, ``P`` (assign, or change in place
    before the bank's next call, to change the filter), and ``x_prior``, ``P_prior``, ``F``,
    ``Q`` of the last covariance step and ``y``, ``S``, ``SI``, ``K`` of the last fix update,
    as filterpy's ``predict`` and ``update`` leave them.
    """

    def __init__(self, hyp: Hypothesis, n_par: int, r0: float, p: DiagnosisParams) -> None:
        self.hyp = hyp
        self.n_par = n_par
        self.n = 3 + n_par
        self.r0 = r0
        self.cfg = p
        self._kind = int(hyp)
        walk = self.walk(1.0)
        self._walk_per_m = walk[0] if walk else 0.0
        if hyp in (Hypothesis.FLAT_LEFT, Hypothesis.FLAT_RIGHT):
            self._bounds = (p.flat_min_radius_m, r0 - p.flat_min_deflection_m)
        elif hyp == Hypothesis.SLIP:
            self._bounds = (p.slip_min_ratio, p.slip_max_ratio)
        else:
            self._bounds = (p.bump_min_amplitude_m, p.bump_max_amplitude_m)
        self.xl: list[float] = [0.0] * self.n
        self.Pl: list[float] = [0.0] * (self.n * self.n)
        # the last covariance step (F's and Q's entries, P', x') and fix update (y + S + SI,
        # K), in floats
        self.step_record: tuple[list[float], list[float], list[float]] | None = None
        self.update_record: tuple[list[float], list[float]] | None = None
        self._arrays: dict[str, np.ndarray] = {}

    # -- the state as arrays ----------------------------------------------------------------

    def changed(self, step: bool = False, update: bool = False) -> None:
        """The bank changed the state (and, if said, the step or update records)."""
        a = self._arrays
        if not a:
            return
        a.pop("x", None)
        a.pop("P", None)
        if step:
            for k in ("F", "Q", "P_prior", "x_prior"):
                a.pop(k, None)
        if update:
            for k in ("y", "S", "SI", "K"):
                a.pop(k, None)

    def take_arrays(self) -> None:
        """Take ``x`` and ``P`` back from their arrays if they were read (and so may have been
        changed in place or replaced)."""
        a = self._arrays
        if "x" in a:
            self.xl = [float(v) for v in np.ravel(a["x"])]
        if "P" in a:
            self.Pl = [float(v) for v in np.ravel(a["P"])]

    def _array(self, name: str) -> np.ndarray:
        a = self._arrays.get(name)
        if a is None:
            a = self._arrays[name] = self._build(name)
        return a

    def _build(self, name: str) -> np.ndarray:
        n = self.n
        if name == "x":
            return np.array(self.xl)
        if name == "P":
            return _square(self.Pl, n)
        if name in ("F", "Q", "P_prior", "x_prior"):
            if self.step_record is None:  # no step yet: filterpy's initial values
                return np.eye(n) if name == "F" else np.zeros(n if name == "x_prior" else (n, n))
            entries, P1, x1 = self.step_record
            if name == "x_prior":
                return np.array(x1)
            if name == "P_prior":
                return _square(P1, n)
            F, Q = step_matrices(n, entries)
            return _square(F if name == "F" else Q, n)
        if self.update_record is None:  # no update yet
            return np.zeros({"y": (3,), "K": (n, 3)}.get(name, (3, 3)))
        ysi, K = self.update_record
        if name == "y":
            return np.array(ysi[:3])
        if name == "K":
            return np.array(K).reshape(n, 3)
        return np.array(ysi[3:12] if name == "S" else ysi[12:]).reshape(3, 3)

    @property
    def x(self) -> np.ndarray:
        return self._array("x")

    @x.setter
    def x(self, value: np.ndarray) -> None:
        self._arrays["x"] = np.asarray(value, dtype=float)

    @property
    def P(self) -> np.ndarray:
        return self._array("P")

    @P.setter
    def P(self, value: np.ndarray) -> None:
        self._arrays["P"] = np.asarray(value, dtype=float)

    @property
    def x_prior(self) -> np.ndarray:
        return self._array("x_prior")

    @property
    def P_prior(self) -> np.ndarray:
        return self._array("P_prior")

    @property
    def F(self) -> np.ndarray:
        return self._array("F")

    @property
    def Q(self) -> np.ndarray:
        return self._array("Q")

    @property
    def y(self) -> np.ndarray:
        return self._array("y")

    @property
    def S(self) -> np.ndarray:
        return self._array("S")

    @property
    def SI(self) -> np.ndarray:
        return self._array("SI")

    @property
    def K(self) -> np.ndarray:
        return self._array("K")

    # -- the hypothesis' wheel model --------------------------------------------------------

    def radii(self) -> tuple[float, float]:
        """Mean effective rolling radii under this hypothesis (bump: nominal on average)."""
        r0, h = self.r0, self.hyp
        if h == Hypothesis.FLAT_LEFT:
            return self.xl[3], r0
        if h == Hypothesis.FLAT_RIGHT:
            return r0, self.xl[3]
        if h == Hypothesis.SLIP:
            r = r0 * (1.0 - self.xl[3])
            return r, r
        return r0, r0

    def projected(self, par: list[float]) -> list[float]:
        """The parameters ``par`` brought into the hypothesis' admissible set."""
        lo, hi = self._bounds
        return project(self._kind, lo, hi, par)

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

    Computation: the bank queues the odometry intervals; at a flush every filter integrates them
    and takes one covariance step (:func:`controller.kernels.bank_flush`); a fix updates every
    filter (:func:`~controller.kernels.bank_fix`), then the probabilities and the mixing.  All
    of it is float arithmetic on each filter's own ``n`` states (:mod:`controller.kernels`,
    compiled where the package was built so), each sum in index order: the same numbers on
    every machine.
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
        self._filters = [_Filter(h, _PARAMS_OF[h], nominal_radius_m, p) for h in Hypothesis]
        n = len(self._filters)
        self._dims = [f.n for f in self._filters]
        self._kinds = [f._kind for f in self._filters]
        self._walks = [f._walk_per_m for f in self._filters]
        self._los = [f._bounds[0] for f in self._filters]
        self._his = [f._bounds[1] for f in self._filters]
        rest = (1.0 - p.prior_nominal) / (n - 1)
        self._prior = [p.prior_nominal] + [rest] * (n - 1)
        self.prior = np.array(self._prior)
        R = [p.fix_pos_std_m**2, p.fix_pos_std_m**2, p.fix_heading_std_rad**2]
        self._R = [R[0], 0.0, 0.0, 0.0, R[1], 0.0, 0.0, 0.0, R[2]]
        # each filter's prior parameter variances (IMM mixing relaxes toward them)
        self._prior_var = [f.initial_params()[1] for f in self._filters]
        self.fixes_used = 0
        self.fixes_outlier = 0
        self.nonfinite_count = 0
        self.numerical_failures = 0
        self.last_log_likelihoods = np.zeros(n)
        self.reset(pose or Pose(0.0, 0.0, 0.0))

    @property
    def filters(self) -> list[_Filter]:
        """The hypothesis filters, in :class:`~dbc.codec.Hypothesis` order."""
        return self._filters

    def reset(self, pose: Pose) -> None:
        """Restart every filter at ``pose`` (e.g. the first fix) with the prior probabilities."""
        p = self.params
        for f in self._filters:
            par, var = f.initial_params()
            n = f.n
            f.xl = [pose.x_m, pose.y_m, wrap_angle(pose.heading_rad), *par]
            diag = [p.initial_pos_std_m**2, p.initial_pos_std_m**2, p.initial_heading_std_rad**2]
            diag += var
            P = [0.0] * (n * n)
            for i, v in enumerate(diag):
                P[i * n + i] = v
            f.Pl = P
            f.changed()
        self._intervals: list[_Interval] = []
        self._prob = list(self._prior)
        self.prob = np.array(self._prob)
        self._c = list(self._prior)
        self._last: tuple[float, float] | None = None
        self._travel_m = 0.0

    def _take_arrays(self) -> None:
        for f in self._filters:
            if f._arrays:
                f.take_arrays()

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
        """Apply the queued intervals: filterpy's ``predict`` for every filter.

        ``x = f(x)``, ``P = F P F' + Q`` (priors saved), then, if finite, ``P`` symmetrised and
        the parameters projected; otherwise the filter keeps its state.
        """
        intervals = self._intervals
        if not intervals:
            return
        self._take_arrays()
        self._intervals = []
        filters = self._filters
        xs = [f.xl for f in filters]
        Ps = [f.Pl for f in filters]
        records, ok = bank_flush(
            self._kinds,
            self.r0,
            self.half_track_m,
            self.params.wheel_noise_m2_per_m,
            self._walks,
            self._los,
            self._his,
            xs,
            Ps,
            intervals,
        )
        for f, x, P, rec in zip(filters, xs, Ps, records, strict=True):
            f.xl, f.Pl, f.step_record = x, P, rec
            f.changed(step=True)
        if not ok:
            self.numerical_failures += 1

    def correct(self, x_m: float, y_m: float, heading_rad: float) -> bool:
        """Fuse a pose fix into every filter and update the probabilities; False if ignored."""
        if not (math.isfinite(x_m) and math.isfinite(y_m) and math.isfinite(heading_rad)):
            self.nonfinite_count += 1
            return False
        self._flush()
        self._take_arrays()
        filters = self._filters
        xs = [f.xl for f in filters]
        Ps = [f.Pl for f in filters]
        # Joseph-form updates with H = [I3 0]; filterpy's update() would invert S again, so
        # the equations are applied here and each filter's y/S/SI/K recorded as filterpy does
        status, ll, inns, Ks, failed = bank_fix(
            self._kinds,
            self._los,
            self._his,
            xs,
            Ps,
            [x_m, y_m, heading_rad],
            self._R,
            self.params.outlier_chi2,
        )
        if status == 3:
            self.fixes_outlier += 1
            return False
        if status:  # a singular S, or a likelihood not finite
            self.numerical_failures += 1
            return False
        self.numerical_failures += failed  # those filters keep their state
        for f, ysi, K in zip(filters, inns, Ks, strict=True):
            if K:
                f.update_record = (ysi, K)
        self.fixes_used += 1
        self.last_log_likelihoods = np.array(ll)
        travel, self._travel_m = self._travel_m, 0.0
        if travel >= self.params.min_travel_m:
            # model probabilities: predicted (c, from the last mixing step) times likelihood
            self._prob = posterior(self._c, ll)
            self.prob = np.array(self._prob)
            eps = 1.0 - math.exp(-self.params.switch_rate_per_m * travel)
            self._c, _ = imm_mix(self._prob, self._prior, eps, xs, Ps, self._dims, self._prior_var)
        for f, x, P in zip(filters, xs, Ps, strict=True):
            f.xl, f.Pl = x, P
            f.changed(update=True)
        return True

    # -- outputs ---------------------------------------------------------------------------

    def diagnosis(self) -> Diagnosis:
        """The bank's verdict: the likeliest hypothesis, every probability, the effective radii."""
        prob = self._prob
        i = prob.index(max(prob))
        rl, rr = self.radii()
        return Diagnosis(Hypothesis(i), prob[i], tuple(prob), rl, rr)

    def radii(self) -> tuple[float, float]:
        """Effective rolling radii (left, right) for odometry (see the module docstring)."""
        self._take_arrays()
        prob = self._prob
        i = prob.index(max(prob))
        if prob[i] >= self.params.radius_feed_probability:
            return self._filters[i].radii()
        rl = rr = 0.0
        for w, f in zip(prob, self._filters, strict=True):
            a, b = f.radii()
            rl += w * a
            rr += w * b
        return rl, rr

    def parameters(self) -> dict[str, list[float]]:
        """Each hypothesis' parameter estimates (for logs)."""
        self._take_arrays()
        return {HYPOTHESIS_NAMES[f.hyp]: f.xl[3:] for f in self._filters}
