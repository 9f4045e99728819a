"""RESILIENT: the paper's 4-rule Takagi-Sugeno-Kang fuzzy controller (Eq. resilientctrl).

Two inputs, each with two membership functions; four rules; min t-norm; first-order
(linear) consequents that give the left and right wheel rim speeds; weighted average::

    u_i = [v_l; v_r]_i = [k_d,i d_e + k_t,i theta_e;  k_d,i d_e - k_t,i theta_e]
    w_i = min(mu_D(d_e), mu_Theta(|theta_e|))           (D in {near, far}, Theta in {small, large})
    [v_l; v_r] = sum_i w_i u_i / sum_i w_i

in SI units (``d_e`` m, ``theta_e`` rad, gains 1/s and m/(s rad), wheel speeds m/s at the rim)
and turned into the body twist ``v = (v_l + v_r)/2``, ``omega = (v_r - v_l)/(2b)``.

Inputs, as implemented:

* ``d_e`` -- the Euclidean distance from the chair to the virtual robot, **signed along the
  path**: positive when the chair is behind the reference (``x_e < 0``), negative when it is
  ahead, so the same consequents brake and, if needed, back up.  The sign is smoothed,
  ``d_e = -tanh(x_e / sign_width) hypot(x_e, y_e)``, so that a chair standing beside the
  reference (``x_e ~ 0``, e.g. started right of the path) is not commanded back and forth.
* ``theta_e`` -- the heading error wrapped to (-pi, pi]: the chair's heading minus the
  bearing of a carrot point ``lookahead`` metres ahead of the virtual robot along its
  heading.  On the path this is the paper's ``phi_e``; off the path it includes the
  line-of-sight correction ``~atan(y_e / lookahead)``, which is what brings the lateral
  error back (the law has no ``y_e`` input otherwise).  The carrot keeps the bearing
  defined when the chair catches up with a reference that pauses or ends.

Both wheels are scaled together (keeping the turn radius) to the chair's wheel speed limit,
``LimitParams.wheel_max_radps`` times the believed wheel radius: the one envelope every law
and the node's limiter share.

As in the paper, the law has no feed-forward of the reference speed or turn rate: the
chair trails the virtual robot by about ``v_d / k_d`` and its heading lags by about
``omega_d b / k_t``.  That is the price of this structure (the paper's table shows
RESILIENT far behind the others) and is kept, not tuned away.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from controller.config import GeometryParams, LimitParams
from controller.kinematics import twist_from_rim
from controller.tracking.common import path_errors, stop_radius
from controller.tracking.parking import RouteEndLatch
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

#: rule order: (distance MF, heading MF)
RULES: tuple[tuple[str, str], ...] = (
    ("near", "small"),
    ("near", "large"),
    ("far", "small"),
    ("far", "large"),
)
#: Names of :meth:`ResilientTSK.activity`'s counts, in the order of its ``_counts`` list:
#: the steps, then per rule the steps it had the largest weight in (the first of equals),
#: the steps parked at the route's end and those whose rim speeds were scaled to the limit.
ACTIVITY_KEYS: tuple[str, ...] = (
    "ticks",
    *(f"rule_{d}_{t}" for d, t in RULES),
    "parked",
    "wheel_limit",
)
_PARKED, _WHEEL_LIMIT = len(RULES) + 1, len(RULES) + 2


def ramp(x: float, lo: float, hi: float) -> float:
    """0 below ``lo``, 1 above ``hi``, linear in between (the 'far'/'large' membership)."""
    if x <= lo:
        return 0.0
    if x >= hi:
        return 1.0
    return (x - lo) / (hi - lo)


class ResilientTSK:
    """RESILIENT: the four-rule TSK fuzzy law on the signed distance and the carrot bearing."""

    name: ClassVar[str] = "resilient"
    #: the drives keep their own velocity-loop gains
    drive_gains: DriveGains | None = None

    @dataclass(frozen=True)
    class Params:
        d_near_m: float = param(
            0.05, unit="m", lo=0.0, hi=10.0, doc="|d_e| up to which d_e is fully 'near'"
        )
        d_far_m: float = param(
            0.5, unit="m", lo=0.001, hi=20.0, doc="|d_e| from which d_e is fully 'far'"
        )
        theta_small_rad: float = param(
            0.1, unit="rad", lo=0.0, hi=3.0, doc="|theta_e| up to which it is fully 'small'"
        )
        theta_large_rad: float = param(
            0.6, unit="rad", lo=0.001, hi=3.2, doc="|theta_e| from which it is fully 'large'"
        )
        k_d_near_small: float = param(2.0, unit="1/s", lo=0.0, hi=20.0, doc="rule 1 k_d")
        k_t_near_small: float = param(1.0, unit="m/(s*rad)", lo=0.0, hi=20.0, doc="rule 1 k_t")
        k_d_near_large: float = param(1.0, unit="1/s", lo=0.0, hi=20.0, doc="rule 2 k_d")
        k_t_near_large: float = param(1.4, unit="m/(s*rad)", lo=0.0, hi=20.0, doc="rule 2 k_t")
        k_d_far_small: float = param(3.0, unit="1/s", lo=0.0, hi=20.0, doc="rule 3 k_d")
        k_t_far_small: float = param(1.0, unit="m/(s*rad)", lo=0.0, hi=20.0, doc="rule 3 k_t")
        k_d_far_large: float = param(1.5, unit="1/s", lo=0.0, hi=20.0, doc="rule 4 k_d")
        k_t_far_large: float = param(1.4, unit="m/(s*rad)", lo=0.0, hi=20.0, doc="rule 4 k_t")
        lookahead_m: float = param(
            0.3,
            unit="m",
            lo=0.01,
            hi=5.0,
            doc="carrot distance ahead of the virtual robot that defines theta_e",
        )
        sign_width_m: float = param(
            0.02, unit="m", lo=1e-4, hi=1.0, doc="smoothing width of the sign of d_e"
        )
        stop_radius_m: float = stop_radius()

    def __init__(
        self,
        params: Params,
        geometry: GeometryParams,
        trajectory: Trajectory,
        *,
        limits: LimitParams,
    ) -> None:
        p = self.p = params
        #: The chair's limits; their wheel speed limit bounds both rim speeds.
        self.limits = limits
        self.rim_max_mps = self.limits.wheel_max_radps * geometry.wheel_radius_m
        if p.d_far_m <= p.d_near_m:
            raise ConfigError("resilient: d_far_m must be above d_near_m")
        if p.theta_large_rad <= p.theta_small_rad:
            raise ConfigError("resilient: theta_large_rad must be above theta_small_rad")
        self.b = geometry.half_track_m
        self.k_d = (p.k_d_near_small, p.k_d_near_large, p.k_d_far_small, p.k_d_far_large)
        self.k_t = (p.k_t_near_small, p.k_t_near_large, p.k_t_far_small, p.k_t_far_large)
        self._reset()

    def _reset(self) -> None:
        self._park = RouteEndLatch()
        self._e = (0.0, 0.0, 0.0)
        self._d = 0.0
        self._theta = 0.0
        self._w = (0.0, 0.0, 0.0, 0.0)
        self._wheels = (0.0, 0.0)
        self._counts = [0] * len(ACTIVITY_KEYS)

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        """Clear the last step's values, the route-end latch and the activity counts."""
        self._reset()

    def infer(self, d_e: float, theta_e: float) -> tuple[float, float]:
        """The fuzzy system alone: (v_left, v_right) rim speeds in m/s for the two inputs."""
        p = self.p
        mu_far = ramp(abs(d_e), p.d_near_m, p.d_far_m)
        mu_large = ramp(abs(theta_e), p.theta_small_rad, p.theta_large_rad)
        mu_near, mu_small = 1.0 - mu_far, 1.0 - mu_large
        w = (
            min(mu_near, mu_small),
            min(mu_near, mu_large),
            min(mu_far, mu_small),
            min(mu_far, mu_large),
        )
        self._w = w
        # complementary memberships: one rule always fires with weight >= 1/2
        total = w[0] + w[1] + w[2] + w[3]
        kd = (
            w[0] * self.k_d[0] + w[1] * self.k_d[1] + w[2] * self.k_d[2] + w[3] * self.k_d[3]
        ) / total
        kt = (
            w[0] * self.k_t[0] + w[1] * self.k_t[1] + w[2] * self.k_t[2] + w[3] * self.k_t[3]
        ) / total
        return kd * d_e + kt * theta_e, kd * d_e - kt * theta_e

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        """The fuzzy law's twist for this tick, within the wheel limit; zero when parked."""
        p = self.p
        n = self._counts
        n[0] += 1
        xe, ye, pe = path_errors(ref, est)
        self._e = (xe, ye, pe)
        dist = math.hypot(xe, ye)
        if self._park.check(ref.done, dist, p.stop_radius_m):
            n[_PARKED] += 1
            return TwistCommand(0.0, 0.0)
        d_e = -math.tanh(xe / p.sign_width_m) * dist
        # bearing of the carrot point, seen from the chair
        cx = ref.x_m + p.lookahead_m * math.cos(ref.heading_rad) - est.x_m
        cy = ref.y_m + p.lookahead_m * math.sin(ref.heading_rad) - est.y_m
        theta_e = wrap_angle(est.heading_rad - math.atan2(cy, cx))
        if not (math.isfinite(d_e) and math.isfinite(theta_e)):
            return TwistCommand(0.0, 0.0)
        self._d, self._theta = d_e, theta_e
        vl, vr = self.infer(d_e, theta_e)
        w = self._w
        n[1 + w.index(max(w))] += 1  # the dominant rule
        lim = self.rim_max_mps
        peak = max(abs(vl), abs(vr))
        if peak > lim:  # scale both: keeps the turn radius
            vl, vr = vl * lim / peak, vr * lim / peak
            n[_WHEEL_LIMIT] += 1
        self._wheels = (vl, vr)
        return TwistCommand(*twist_from_rim(vl, vr, self.b))

    def activity(self) -> Mapping[str, int]:
        """Counts since the last reset (:data:`ACTIVITY_KEYS`): steps, the rule that
        dominated each step, steps parked, steps at the wheel speed limit."""
        return dict(zip(ACTIVITY_KEYS, self._counts, strict=True))

    def internals(self) -> Mapping[str, float]:
        """The last step's path errors, fuzzy inputs, rule weights and rim speeds, by name."""
        w = self._w
        return {
            "e_x_m": self._e[0],
            "e_y_m": self._e[1],
            "e_phi_rad": self._e[2],
            "parked": float(self._park.parked),
            "fuzzy.d_e_m": self._d,
            "fuzzy.theta_e_rad": self._theta,
            "fuzzy.w_near_small": w[0],
            "fuzzy.w_near_large": w[1],
            "fuzzy.w_far_small": w[2],
            "fuzzy.w_far_large": w[3],
            "fuzzy.v_left_mps": self._wheels[0],
            "fuzzy.v_right_mps": self._wheels[1],
        }
