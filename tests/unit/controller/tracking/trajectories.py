"""Synthetic references for the tracking laws' tests."""

from __future__ import annotations

import math

from controller.types import ReferenceSample


class Circle:
    """A virtual robot on a circle at constant speed (a Trajectory); past ``duration`` its
    pose stays where it ended."""

    def __init__(self, v: float = 0.8, radius: float = 2.0, duration: float = 30.0) -> None:
        self.v, self.r, self.duration_s = v, radius, duration

    def sample(self, t: float) -> ReferenceSample:
        w = self.v / self.r
        a = w * min(t, self.duration_s)
        return ReferenceSample(
            t,
            self.r * math.sin(a),
            self.r * (1 - math.cos(a)),
            a,
            self.v,
            w,
            curvature_1pm=1 / self.r,
        )
