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

#: The project's one 2*pi (rad per revolution), for the controller and the tools.
TWO_PI = math.tau


@dataclass(frozen=True, slots=True)
class WheelSpeeds:
    """Angular speeds of the left and right wheel, in rad/s."""

    left_radps: float
    right_radps: float


def inverse(
    v_mps: float, omega_radps: float, half_track_m: float, r_left_m: float, r_right_m: float
) -> WheelSpeeds:
    """Body twist -> wheel angular speeds (rad/s)."""
    left_mps, right_mps = rim_speeds(v_mps, omega_radps, half_track_m)
    return WheelSpeeds(left_mps / r_left_m, right_mps / r_right_m)


def rim_speeds(v_mps: float, omega_radps: float, half_track_m: float) -> tuple[float, float]:
    """Body twist -> the left and right wheels' rim speeds (m/s)."""
    return v_mps - half_track_m * omega_radps, v_mps + half_track_m * omega_radps


def twist_from_rim(left_mps: float, right_mps: float, half_track_m: float) -> tuple[float, float]:
    """The wheels' rim speeds (m/s) -> body twist (v m/s, omega rad/s)."""
    return 0.5 * (left_mps + right_mps), (right_mps - left_mps) / (2.0 * half_track_m)


def forward(
    left_radps: float, right_radps: float, half_track_m: float, r_left_m: float, r_right_m: float
) -> tuple[float, float]:
    """Wheel angular speeds (rad/s) -> body twist (v m/s, omega rad/s)."""
    return twist_from_rim(left_radps * r_left_m, right_radps * r_right_m, half_track_m)


def radps_to_revps(w: float) -> float:
    """Convert an angular speed from rad/s to revolutions per second."""
    return w / TWO_PI


def revps_to_radps(n: float) -> float:
    """Convert an angular speed from revolutions per second to rad/s."""
    return n * TWO_PI
