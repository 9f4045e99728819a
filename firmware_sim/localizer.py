"""Localization node (node 3): noisy absolute pose fixes of the axle midpoint P0.

It stands for an indoor positioning unit (UWB, lidar scan matching) that sends
``Localizer_Pose_Fix`` at a fixed rate whose period is a multiple of the bench
step.  The noise is Gaussian and independent per fix, drawn from a private
``random.Random(seed)`` so that a run is reproducible; the heading is wrapped to
(-pi, pi].

Fault seams (:mod:`firmware_sim.faults`): ``drop`` (None when healthy) decides
whether a due fix is lost, ``bias`` (x m, y m, heading rad) is added to every fix.
The noise is drawn for every due fix, lost or not, so a dropout does not shift
the noise sequence of the fixes that follow.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import Any

from dbc.codec import Node, PoseFix
from firmware_sim.config import LocalizerParams
from firmware_sim.plant import wrap_angle


class Localizer:
    """Emits a :class:`~dbc.codec.PoseFix` every ``period_ns`` starting at time zero."""

    node = Node.LOCALIZER

    def __init__(self, params: LocalizerParams, period_ns: int, *, seed: int) -> None:
        self.params = params
        self.period_ns = period_ns
        self._rng = random.Random(seed)
        self._next_ns = 0
        self.drop: Callable[[], bool] | None = None
        self.bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.dropped = 0

    def emit_due(
        self,
        now_ns: int,
        x_m: float,
        y_m: float,
        heading_rad: float,
        out: list[tuple[Any, Node | None]],
    ) -> None:
        """Append a fix of the pose (``x_m``, ``y_m``, ``heading_rad``) if one is due."""
        if now_ns < self._next_ns:
            return
        self._next_ns = now_ns + self.period_ns
        p = self.params
        gauss = self._rng.gauss
        nx = gauss(0.0, p.sigma_xy_m)
        ny = gauss(0.0, p.sigma_xy_m)
        nh = gauss(0.0, p.sigma_heading_rad)
        if self.drop is not None and self.drop():
            self.dropped += 1
            return
        bx, by, bh = self.bias
        out.append(
            (
                PoseFix(x_m + nx + bx, y_m + ny + by, wrap_angle(heading_rad + nh + bh)),
                Node.LOCALIZER,
            )
        )
