"""Pieces several tracking laws share: path-frame errors, the saturation, parking, a plain PID.

Each law's module keeps what makes it that law; what two or more of them compute the same
way is here (the ANTIFRAGILE laws' envelope is ``envelope.py``, the MPCs' common parts
``mpc.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from controller.types import DriveGains, ReferenceSample, StateEstimate, wrap_angle
from dbc.runtime.params import param


def path_errors(ref: ReferenceSample, est: StateEstimate) -> tuple[float, float, float]:
    """The paper's tracking errors ``(x_e, y_e, phi_e)`` (Eq. errorvector): actual minus
    desired, in the desired frame, ``phi_e`` wrapped to (-pi, pi]."""
    c, s = math.cos(ref.heading_rad), math.sin(ref.heading_rad)
    dx, dy = est.x_m - ref.x_m, est.y_m - ref.y_m
    return c * dx + s * dy, -s * dx + c * dy, wrap_angle(est.heading_rad - ref.heading_rad)


def sat(x: float) -> float:
    """The saturation that replaces sgn (paper: "sat(.) with thresholds")."""
    return -1.0 if x < -1.0 else (1.0 if x > 1.0 else x)


def inv_cos(c: float, cos_min: float) -> float:
    """``1/cos(phi_e)`` where it is well posed, fading to 0 at 90 degrees below ``cos_min``
    (the ROBUST laws' division by ``cos(phi_e)``; nothing is divided by zero)."""
    return 1.0 / c if c >= cos_min else max(c, 0.0) / (cos_min * cos_min)


def stop_radius() -> Any:
    """The ``stop_radius_m`` gain of the laws that park at the route's end (parking.py)."""
    return param(
        0.05,
        unit="m",
        lo=0.0,
        hi=1.0,
        doc="after the route end, stop for good once the position error is below this",
    )


@dataclass(frozen=True)
class PlainPid:
    """The drives' velocity loop for both ROBUST laws, in the drive's units (docs/physics.md).

    A plain PID by pole placement on the reduced wheel model (torque source, the armature
    inductance neglected): ``J w' = eta N tau``, i.e. ``G = eta N / (2 pi J)`` wheel rev/s^2
    per motor N*m, with ``J`` the laden chair's wheel-referred inertia in the common mode
    (5.99 kg m^2, ``G = 0.765``).  With the derivative on the measurement the closed loop is
    ``(1 + G Kd) s^2 + G Kp s + G Ki``; ``zeta = 1``, ``omega_n = 25 rad/s`` and a small
    ``Kd = 0.1`` give ``Kp = 2 zeta omega_n (1 + G Kd) / G = 70`` and
    ``Ki = omega_n^2 (1 + G Kd) / G = 880`` (turning mode, ``J = 8.74``: ``omega_n = 21``,
    ``zeta = 0.85``).  All three terms are designed together: no time-scale separation of
    the integral as in ANTIFRAGILE's singular-perturbation PID.
    """

    vel_gain: float = param(
        70.0, unit="Nm/(rev/s)", lo=0.0, hi=100.0, doc="P: motor torque per wheel rev/s of error"
    )
    vel_integrator_gain: float = param(
        880.0, unit="Nm/rev", lo=0.0, hi=1000.0, doc="I: motor torque per wheel rev of error"
    )
    vel_derivative_gain: float = param(
        0.1, unit="Nm/(rev/s^2)", lo=0.0, hi=100.0, doc="D, on the measured wheel speed"
    )
    derivative_cutoff_hz: float = param(
        50.0, unit="Hz", lo=1.0, hi=500.0, doc="cut-off of the drive's derivative low-pass"
    )

    def drive_gains(self) -> DriveGains:
        """The gains the node pushes to both drives when arming."""
        return DriveGains(
            self.vel_gain,
            self.vel_integrator_gain,
            self.vel_derivative_gain,
            self.derivative_cutoff_hz,
        )
