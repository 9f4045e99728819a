"""Sensor faults injected into the controller's own estimate: the paper's flat tire as it
injects it.

The paper (Sec. "Faults and uncertainty injection system", "Evaluation") injects a flat tire
as a *sensor* fault, "perceiving a continuous wheel radius decrease": the wheel does not
change, the robot's state estimate is the one a kinematic model with the shrinking radius
produces.  :class:`PerceivedEncoders` does that to the drives' encoder positions before the
odometry and the filter bank see them: each wheel's rotation since the previous sample is
scaled by ``r(t) / r0``, with ``r(t)`` the bench's flat-tire profile (exponential decay from
the nominal ``r0`` to ``to_radius_m`` with ``time_constant_s``, back to ``r0`` at once when
the fault ends).  Travel computed from the perceived positions with the believed radius
``r0`` is then travel computed with ``r(t)``.  Configured by ``[[estimation.perceived_flats]]``
(:class:`~controller.config.PerceivedFlatParams`); the link, the safety checks and the
drives keep the true readings.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from controller.config import PerceivedFlatParams


def perceived_radius_m(fault: PerceivedFlatParams, r0_m: float, t_s: float) -> float:
    """The radius the odometry perceives under ``fault`` at ``t_s`` (``r0_m`` outside it)."""
    start = fault.onset_s
    if t_s < start or (fault.duration_s > 0.0 and t_s >= start + fault.duration_s):
        return r0_m
    tau = fault.time_constant_s
    decay = 1.0 if tau <= 0.0 else 1.0 - math.exp(-(t_s - start) / tau)
    return r0_m - (r0_m - fault.to_radius_m) * decay


class PerceivedEncoders:
    """Encoder positions as a sensor fault makes the estimator perceive them (module doc)."""

    def __init__(self, faults: Sequence[PerceivedFlatParams], r0_m: float) -> None:
        self.faults = tuple(faults)
        self.r0_m = r0_m
        self._raw: tuple[float, float] | None = None
        self._out = (0.0, 0.0)

    @property
    def active(self) -> bool:
        """Whether any sensor fault is configured."""
        return bool(self.faults)

    def factors(self, t_s: float) -> tuple[float, float]:
        """(left, right) perceived/true radius ratio at ``t_s``; overlapping faults multiply."""
        k = [1.0, 1.0]
        for f in self.faults:
            ratio = perceived_radius_m(f, self.r0_m, t_s) / self.r0_m
            if f.side in ("left", "both"):
                k[0] *= ratio
            if f.side in ("right", "both"):
                k[1] *= ratio
        return k[0], k[1]

    def positions(self, left_rev: float, right_rev: float, t_s: float) -> tuple[float, float]:
        """Perceived (left, right) positions for true positions read at ``t_s``."""
        if not self.faults:
            return left_rev, right_rev
        if not (math.isfinite(left_rev) and math.isfinite(right_rev)):
            return left_rev, right_rev  # the odometry rejects (and counts) it; state kept
        if self._raw is None:  # first sample: perceived = true from here on
            self._raw = (left_rev, right_rev)
            self._out = (left_rev, right_rev)
            return self._out
        kl, kr = self.factors(t_s)
        out = (
            self._out[0] + (left_rev - self._raw[0]) * kl,
            self._out[1] + (right_rev - self._raw[1]) * kr,
        )
        self._raw, self._out = (left_rev, right_rev), out
        return out
