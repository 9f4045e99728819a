"""PURSUIT: a pure-pursuit law on the reference point, with speed feedback along the path.

An example of a controller of one's own (docs/own-controller.md).  The chair steers toward
the reference point ``ref`` (the planner's sample at this time), as pure pursuit steers
toward a look-ahead point, and closes the along-track error with a proportional term::

    e_x, e_y, e_phi : the reference in the chair's frame (ahead, left, heading error)
    d      = max(hypot(e_x, e_y), lookahead_min_m)
    v      = v_d cos(e_phi) + k_x e_x
    omega  = omega_d + 2 v_d e_y / d^2 + k_phi sin(e_phi)

The pursuit term is the curvature ``2 e_y / d^2`` of the arc through the reference point,
times the reference speed; the floor ``lookahead_min_m`` keeps it bounded as the chair closes
on the point.  Stability within the chair's limits: near the path, at speed ``v_d``, the
lateral error obeys ``y'' + (k_phi) y' + (2 v_d^2 / d^2) y = 0``, stable for every positive
gain, with natural frequency ``sqrt(2) v_d / d``: the declared bounds keep that below the
drives' 21 rad/s (``d >= 0.1 m`` at 1.5 m/s gives 21 rad/s) and ``k_phi`` below 12 1/s, the
loop-rate ceiling of scenarios/tuning/space.toml.  Far from the path the command is bounded
(|omega| <= |omega_d| + 2 v_d / d + k_phi), and the node's limiter keeps it in the envelope.
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


class PurePursuit:
    name: ClassVar[str] = "pursuit"
    drive_gains: DriveGains | None = None  # the drives keep their own velocity loops

    @dataclass(frozen=True)
    class Params:
        k_x: float = param(2.0, unit="1/s", lo=0.0, hi=12.0, doc="along-track error gain")
        k_phi: float = param(3.0, unit="1/s", lo=0.0, hi=12.0, doc="heading error gain")
        lookahead_min_m: float = param(
            0.3, unit="m", lo=0.1, hi=5.0, doc="floor of the distance to the pursued point"
        )

    def __init__(
        self,
        params: Params,
        geometry: GeometryParams,
        trajectory: Trajectory,
        *,
        limits: LimitParams,
    ) -> None:
        self.p = params
        self._e = (0.0, 0.0, 0.0)

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        self._e = (0.0, 0.0, 0.0)

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        if not (math.isfinite(est.x_m) and math.isfinite(est.heading_rad)):
            return TwistCommand(math.nan, math.nan)  # the node brakes on a non-finite command
        c, s = math.cos(est.heading_rad), math.sin(est.heading_rad)
        dx, dy = ref.x_m - est.x_m, ref.y_m - est.y_m
        ex, ey = c * dx + s * dy, -s * dx + c * dy
        ephi = wrap_angle(ref.heading_rad - est.heading_rad)
        self._e = (ex, ey, ephi)
        p = self.p
        d = max(math.hypot(ex, ey), p.lookahead_min_m)
        v = ref.v_mps * math.cos(ephi) + p.k_x * ex
        w = ref.omega_radps + 2.0 * ref.v_mps * ey / (d * d) + p.k_phi * math.sin(ephi)
        return TwistCommand(v, w)

    def internals(self) -> Mapping[str, float]:
        return {"e_x_m": self._e[0], "e_y_m": self._e[1], "e_phi_rad": self._e[2]}
