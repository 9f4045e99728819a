"""Localization node (node 3): noisy absolute pose fixes of the axle midpoint P0.

It stands for an indoor positioning unit (UWB, lidar scan matching) that sends
``Localizer_Pose_Fix`` at a fixed rate whose period is a multiple of the bench
step.  The noise is Gaussian and independent per fix, drawn from a private
``random.Random(seed)`` so that a run is reproducible; the heading is wrapped to
(-pi, pi].
"""

from __future__ import annotations

import random
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
        out.append(
            (
                PoseFix(
                    x_m + gauss(0.0, p.sigma_xy_m),
                    y_m + gauss(0.0, p.sigma_xy_m),
                    wrap_angle(heading_rad + gauss(0.0, p.sigma_heading_rad)),
                ),
                Node.LOCALIZER,
            )
        )
