"""The drive's velocity loop (ODrive 0.6's velocity controller, with a derivative term *ext*).

``tau = Kp e + Ki int(e) - Kd d/dt(filtered measurement) + ff`` with conditional-integration
anti-windup against the torque limits the drive gives it (the current and the voltage limit).
Compiled with the other inner loops of the bench (:mod:`dbc.runtime.compiled`): it runs at
1 kHz per drive (:meth:`firmware_sim.drive.DriveNode.control`).
"""

from __future__ import annotations

import math


class VelocityPid:
    """The drive's velocity loop: wheel rev/s in, motor N*m out, at a fixed rate.

    Gains follow ODrive's units with wheel revolutions: ``kp`` N*m/(rev/s),
    ``ki`` N*m/rev, ``kd`` N*m/(rev/s^2).  The derivative acts on the
    measurement (no kick on setpoint steps) through a first-order low-pass of
    cut-off ``cutoff_hz`` (0 = the raw difference).  Anti-windup by conditional
    integration: while the output sits on a limit the integrator only moves away
    from it; the integrator itself never leaves the torque range.
    """

    __slots__ = ("_alpha", "_d_filt", "_dt_s", "_prev_meas", "integrator", "kd", "ki", "kp")

    def __init__(self, dt_s: float) -> None:
        self._dt_s = dt_s
        self.kp = 0.0
        self.ki = 0.0
        self.kd = 0.0
        self._alpha = 1.0
        self.integrator = 0.0
        self._d_filt = 0.0
        self._prev_meas: float | None = None

    def set_gains(self, kp: float, ki: float) -> None:
        """Set ``kp`` (N*m per rev/s) and ``ki`` (N*m per rev)."""
        self.kp = kp
        self.ki = ki

    def set_derivative(self, kd: float, cutoff_hz: float) -> None:
        """Set ``kd`` (N*m per rev/s^2) and its filter's cut-off in Hz (0: no filter)."""
        self.kd = kd
        if cutoff_hz <= 0.0:
            self._alpha = 1.0
        else:
            self._alpha = 1.0 - math.exp(-math.tau * cutoff_hz * self._dt_s)

    def reset(self) -> None:
        """Clear the integrator, the derivative filter and the previous measurement."""
        self.integrator = 0.0
        self._d_filt = 0.0
        self._prev_meas = None

    def update(self, sp: float, meas: float, ff: float, lo: float, hi: float) -> float:
        """One tick: torque command within ``[lo, hi]`` for setpoint ``sp`` and ``meas``."""
        err = sp - meas
        prev = self._prev_meas
        self._prev_meas = meas
        out = self.kp * err + self.integrator + ff
        if self.kd:
            if prev is not None:
                raw = (meas - prev) / self._dt_s
                self._d_filt += self._alpha * (raw - self._d_filt)
            out -= self.kd * self._d_filt
        step = self.ki * self._dt_s * err
        if out > hi:
            out = hi
            if step < 0.0:
                self.integrator += step
        elif out < lo:
            out = lo
            if step > 0.0:
                self.integrator += step
        else:
            self.integrator += step
        if self.integrator > hi and self.integrator > 0.0:
            self.integrator = max(hi, 0.0)
        elif self.integrator < lo and self.integrator < 0.0:
            self.integrator = min(lo, 0.0)
        return out
