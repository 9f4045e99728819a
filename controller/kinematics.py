"""Differential-drive kinematics between body twist and wheel speeds.

The paper's wheel equation (Eq. wheelscmds) prints ``Omega_r`` twice; its second
line is the *left* wheel::

    Omega_R = (v + b * omega) / r_R        Omega_L = (v - b * omega) / r_L

with ``b`` half the wheel separation.  Speeds are in rad/s here; the wire uses
wheel revolutions per second (:func:`radps_to_revps`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, slots=True)
class WheelSpeeds:
    left_radps: float
    right_radps: float


def inverse(
    v_mps: float, omega_radps: float, half_track_m: float, r_left_m: float, r_right_m: float
) -> WheelSpeeds:
    """Body twist -> wheel angular speeds (rad/s)."""
    return WheelSpeeds(
        (v_mps - half_track_m * omega_radps) / r_left_m,
        (v_mps + half_track_m * omega_radps) / r_right_m,
    )


def forward(
    left_radps: float, right_radps: float, half_track_m: float, r_left_m: float, r_right_m: float
) -> tuple[float, float]:
    """Wheel angular speeds (rad/s) -> body twist (v m/s, omega rad/s)."""
    vl, vr = left_radps * r_left_m, right_radps * r_right_m
    return 0.5 * (vr + vl), (vr - vl) / (2.0 * half_track_m)


def radps_to_revps(w: float) -> float:
    return w / TWO_PI


def revps_to_radps(n: float) -> float:
    return n * TWO_PI
