"""BASELINE: Kanayama's stable tracking law (Kanayama et al., ICRA 1990).

Errors in the *robot* frame, desired minus actual::

    e_x =  cos(phi)(x_d - x) + sin(phi)(y_d - y)
    e_y = -sin(phi)(x_d - x) + cos(phi)(y_d - y)
    e_phi = wrap(phi_d - phi)

    v     = v_d cos(e_phi) + K_x e_x
    omega = omega_d + v_d (K_y e_y + K_phi sin(e_phi))

Linearised about a straight path at speed v_d, the lateral error obeys
``s^2 + v_d K_phi s + v_d^2 K_y = 0``: natural frequency ``v_d sqrt(K_y)``, damping
``K_phi / (2 sqrt(K_y))``.  The law is smooth, has no singularity and needs no
model; it is the reference point the paper's controllers are compared with.  It has no
saturation of its own: the node's limiter shapes its command with the chair's limits, the
same envelope the other laws saturate with.  Nothing in it switches, so it has no
``activity()`` (optional in the Controller protocol): its runs report no law activity.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from controller.config import GeometryParams, LimitParams
from controller.types import (
    DriveGains,
    ReferenceSample,
    StateEstimate,
    Trajectory,
    TwistCommand,
    wrap_angle,
)
from dbc.runtime.params import param


class Kanayama:
    """BASELINE: Kanayama's law on the robot-frame errors, with no saturation of its own."""

    name: ClassVar[str] = "baseline"
    #: the drives keep their own velocity-loop gains
    drive_gains: DriveGains | None = None

    @dataclass(frozen=True)
    class Params:
        k_x: float = param(2.0, unit="1/s", lo=0.0, hi=50.0, doc="longitudinal error gain")
        k_y: float = param(16.0, unit="1/m^2", lo=0.0, hi=500.0, doc="lateral error gain")
        k_phi: float = param(6.4, unit="1/m", lo=0.0, hi=100.0, doc="heading error gain")

    def __init__(
        self,
        params: Params,
        geometry: GeometryParams,
        trajectory: Trajectory,
        *,
        limits: LimitParams,
    ) -> None:
        self.p = params
        #: The chair's limits (the law itself does not saturate; the node's limiter does).
        self.limits = limits
        self._e = (0.0, 0.0, 0.0)

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        """Clear the last step's errors."""
        self._e = (0.0, 0.0, 0.0)

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        """Kanayama's twist for this tick (NaN for a non-finite estimated heading)."""
        if not math.isfinite(est.heading_rad):
            # math.cos(inf) raises; a non-finite command makes the node stop (NON_FINITE)
            self._e = (math.nan, math.nan, math.nan)
            return TwistCommand(math.nan, math.nan)
        c, s = math.cos(est.heading_rad), math.sin(est.heading_rad)
        dx, dy = ref.x_m - est.x_m, ref.y_m - est.y_m
        ex, ey = c * dx + s * dy, -s * dx + c * dy
        ephi = wrap_angle(ref.heading_rad - est.heading_rad)
        self._e = (ex, ey, ephi)
        p = self.p
        v = ref.v_mps * math.cos(ephi) + p.k_x * ex
        w = ref.omega_radps + ref.v_mps * (p.k_y * ey + p.k_phi * math.sin(ephi))
        return TwistCommand(v, w)

    def internals(self) -> Mapping[str, float]:
        """The last step's robot-frame errors ``e_x_m``, ``e_y_m`` (m) and ``e_phi_rad`` (rad)."""
        return {"e_x_m": self._e[0], "e_y_m": self._e[1], "e_phi_rad": self._e[2]}
