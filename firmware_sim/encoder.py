"""The drive's motor encoder: a finite-resolution quadrature count and ODrive's PLL.

The encoder sits on the motor shaft, so one wheel revolution is ``cpr * N``
counts.  Every control tick the drive samples the count and runs the
position/velocity PLL of ODrive's ``Encoder::update`` (gains ``k_p = 2 bw``,
``k_i = k_p^2 / 4``: a critically damped second-order tracker, with its
snap-to-zero of velocities smaller than one integrator step).  Positions and
velocities leave this class in **wheel** revolutions (the load mapper of
ODrive 0.6 carries the gear ratio).

Fault seam: ``count_filter`` (None when healthy) maps each sampled count to the
count the drive sees (noise, a stuck or mis-scaled encoder; :mod:`firmware_sim.faults`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

_INV_TWO_PI = 1.0 / math.tau


def wrap_int32(n: int) -> int:
    """The two's-complement int32 value of ``n`` (a hardware counter wraps)."""
    return ((n + 0x8000_0000) & 0xFFFF_FFFF) - 0x8000_0000


class QuadratureEncoder:
    """Count + PLL estimate of one motor shaft, read as wheel revolutions."""

    __slots__ = (
        "_counts_per_motor_rad",
        "_dt_ki",
        "_dt_kp",
        "_dt_s",
        "_inv_counts_per_wheel_rev",
        "_offset",
        "_snap",
        "count_filter",
        "cpr",
        "pos_counts",
        "shadow_count",
        "vel_countsps",
    )

    def __init__(self, cpr: int, gear_ratio: float, bandwidth_radps: float, dt_s: float) -> None:
        self.cpr = cpr
        self._counts_per_motor_rad = cpr * _INV_TWO_PI * gear_ratio  # per *wheel* radian
        self._inv_counts_per_wheel_rev = 1.0 / (cpr * gear_ratio)
        kp = 2.0 * bandwidth_radps
        ki = 0.25 * kp * kp
        self._dt_s = dt_s
        self._dt_kp = dt_s * kp
        self._dt_ki = dt_s * ki
        self._snap = 0.5 * dt_s * ki
        self._offset = 0
        self.count_filter: Callable[[int], int] | None = None
        self.shadow_count = 0
        self.pos_counts = 0.0
        self.vel_countsps = 0.0

    def reset(self, wheel_angle_rad: float) -> None:
        """Power-on: the count restarts at zero wherever the shaft stands."""
        self._offset = math.floor(wheel_angle_rad * self._counts_per_motor_rad)
        self.shadow_count = 0
        self.pos_counts = 0.0
        self.vel_countsps = 0.0

    def update(self, wheel_angle_rad: float) -> None:
        """Sample the count at the wheel angle and advance the PLL by one tick."""
        count = math.floor(wheel_angle_rad * self._counts_per_motor_rad) - self._offset
        f = self.count_filter
        if f is not None:
            count = f(count)
        self.shadow_count = count
        pos = self.pos_counts + self._dt_s * self.vel_countsps
        delta = count - pos
        self.pos_counts = pos + self._dt_kp * delta
        vel = self.vel_countsps + self._dt_ki * delta
        if -self._snap < vel < self._snap:
            vel = 0.0
        self.vel_countsps = vel

    @property
    def pos_rev(self) -> float:
        """PLL position estimate, wheel revolutions since power-on."""
        return self.pos_counts * self._inv_counts_per_wheel_rev

    @property
    def vel_revps(self) -> float:
        """PLL velocity estimate, wheel revolutions per second."""
        return self.vel_countsps * self._inv_counts_per_wheel_rev

    @property
    def count_in_cpr(self) -> int:
        """The shadow count within one motor revolution, ``0 .. cpr - 1``."""
        return self.shadow_count % self.cpr
