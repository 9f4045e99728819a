"""The drives' velocity loops tuned by singular perturbation (the paper's inner loop).

The paper (sections "Time scale separation" and "Redundant overcompensation") writes
the wheel's PID in fast time ``tau = t / epsilon``, ``epsilon = L / R``::

    de1/dtau = e2
    de2/dtau = -k1 e1 - k2 e2 - k3 e3 - d          e1 = e, e2 = de/dtau, e3 = int e dt
    de3/dtau = epsilon e1

with ``k1 = Kp``, ``k2 = Kp Kd``, ``k3 = Kp K^i`` and ``Ki = epsilon K^i``: the PD part is
fast (its matrix ``[[0, 1], [-k1, -k2]]`` must be Hurwitz) and the integral is slow.

For the drive we actually have (docs/physics.md: a motor-torque command ``tau*``, a
voltage-mode current loop that cancels the back-EMF so the torque follows ``tau*``
with the electrical lag ``epsilon``, gear ``N``, efficiency ``eta``) and a wheel
that accelerates the inertia ``J``::

    J w_dot = eta N tau - load,    epsilon tau_dot = tau* - tau,
    tau* = P e + D e_dot + I int e      (e = w_ref - w, derivative on the measurement)

the closed loop is *exactly* the paper's system, with the dimensionless gains

    k1 = epsilon eta N P / J,    k2 = 1 + eta N D / J,    k3 = epsilon eta N I / J,

and ``d = -epsilon load / J``.  The ``1`` in ``k2`` is the motor's own electrical
damping in fast time: a drive without derivative action already has ``k2 = 1``; a
derivative can only add to it, so ``k2 >= 1`` is the realizability condition.
:func:`design` inverts this map: from the paper's normalized gains and the motor the
controller believes (:class:`~controller.config.MotorParams`) to the drive's gains in
its own units (motor N*m per *wheel* rev/s, rev, rev/s^2), checked against the wire's
signal ranges.  Derivation and numbers: docs/antifragile.md.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

from controller.config import MotorParams
from controller.kinematics import TWO_PI
from controller.types import DriveGains
from dbc.codec import Codec, Node, SetVelDerivativeGain, SetVelGains
from dbc.errors import EncodeError
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import param

#: The slowest fast pole must be at least this many times faster than the integral
#: pole for the reduced (slow) model to describe the loop (time-scale separation).
MIN_SEPARATION = 5.0


@dataclass(frozen=True)
class InnerLoopParams:
    """The paper's normalized inner-loop gains (dimensionless in fast time)."""

    k1: float = param(
        0.17,
        unit="1",
        lo=0.0,
        hi=10.0,
        lo_open=True,
        doc="fast-time proportional gain k1 = Kp = epsilon eta N P / J",
    )
    k2: float = param(
        1.1,
        unit="1",
        lo=1.0,
        hi=20.0,
        doc="fast-time damping k2 = Kp Kd = 1 + eta N D / J (1 = the motor's own, no derivative)",
    )
    ki_hat_per_s: float = param(
        6.0,
        unit="1/s",
        lo=0.0,
        hi=200.0,
        doc="slow integral rate K^i = k3 / k1 = I / P; Ki = epsilon K^i",
    )
    derivative_cutoff_hz: float = param(
        200.0, unit="Hz", lo=1.0, hi=500.0, doc="the drive's derivative low-pass cut-off"
    )


@dataclass(frozen=True)
class InnerLoopDesign:
    """Everything :func:`design` computed, for logs, docs and tests."""

    epsilon_s: float  # L / R
    torque_gain: float  # eta N, wheel N*m per motor N*m
    inertia_kgm2: float  # J at the wheel shaft
    k1: float
    k2: float
    k3_per_s: float
    kp: float  # paper's Kp = k1
    kd: float  # paper's Kd = k2 / k1 (fast-time units)
    ki: float  # paper's Ki = epsilon K^i (dimensionless)
    ki_hat_per_s: float
    p_nm_per_radps: float  # motor N*m per wheel rad/s
    i_nm_per_rad: float  # motor N*m per wheel rad
    d_nm_per_radps2: float  # motor N*m per wheel rad/s^2
    fast_poles_per_s: tuple[complex, complex]  # PD (boundary-layer) poles in slow time
    slow_pole_per_s: float  # reduced model's integral pole, -K^i
    closed_loop_poles_per_s: tuple[complex, complex, complex]  # exact third-order loop
    drive_gains: DriveGains

    @property
    def separation(self) -> float:
        """Slowest fast pole over the integral pole (inf without integral action)."""
        slow = abs(self.slow_pole_per_s)
        fast = min(-p.real for p in self.fast_poles_per_s)
        return math.inf if slow == 0.0 else fast / slow


def fast_poles(k1: float, k2: float, epsilon_s: float) -> tuple[complex, complex]:
    """Roots of ``epsilon^2 s^2 + epsilon k2 s + k1`` (the PD part, in slow time)."""
    root = cmath.sqrt(k2 * k2 - 4.0 * k1)
    return ((-k2 + root) / (2.0 * epsilon_s), (-k2 - root) / (2.0 * epsilon_s))


def closed_loop_poles(
    k1: float, k2: float, k3: float, epsilon_s: float
) -> tuple[complex, complex, complex]:
    """Roots of ``epsilon^2 s^3 + epsilon k2 s^2 + k1 s + k3``, the whole loop in slow time."""
    import numpy as np  # configure time only

    roots = np.roots([epsilon_s * epsilon_s, epsilon_s * k2, k1, k3])
    ordered = sorted((complex(r) for r in roots), key=lambda z: (-z.real, z.imag))
    return (ordered[0], ordered[1], ordered[2])


def design(
    motor: MotorParams, gains: InnerLoopParams, *, codec: Codec | None = None
) -> InnerLoopDesign:
    """Drive velocity-loop gains from the paper's normalized gains and the believed motor.

    Raises :class:`~dbc.errors.ConfigError` (naming the gain and the bound) when the PD
    part is not Hurwitz, needs a negative derivative, the whole loop is not Hurwitz, the
    time scales do not separate, or a gain does not fit its CAN signal.
    """
    eps = motor.epsilon_s
    g = motor.torque_gain
    j = motor.reflected_inertia_kgm2
    k1, k2, ki_hat = gains.k1, gains.k2, gains.ki_hat_per_s
    where = "antifragile.inner_loop"
    if not (k1 > 0.0 and k2 > 0.0):  # paper Eq. (hurwitz): trace < 0 and det > 0
        raise ConfigError(
            f"{where}: the PD part [[0, 1], [-k1, -k2]] is not Hurwitz (k1={k1}, k2={k2})"
        )
    if k2 < 1.0:
        raise ConfigError(
            f"{where}: k2 = {k2} < 1 needs a negative derivative gain; the motor's electrical "
            "damping alone gives k2 = 1"
        )
    k3 = k1 * ki_hat
    if k2 * k1 <= eps * k3:  # Routh-Hurwitz of eps^2 s^3 + eps k2 s^2 + k1 s + k3
        raise ConfigError(f"{where}: the closed loop is unstable (k2 k1 = {k2 * k1} <= eps k3)")
    fp = fast_poles(k1, k2, eps)
    slowest_fast = min(-p.real for p in fp)
    if ki_hat > 0.0 and slowest_fast < MIN_SEPARATION * ki_hat:
        raise ConfigError(
            f"{where}: ki_hat_per_s = {ki_hat} 1/s is too close to the fast poles "
            f"({slowest_fast:.1f} 1/s); it must be at most 1/{MIN_SEPARATION:g} of them"
        )
    p_rad = k1 * j / (eps * g)
    d_rad = (k2 - 1.0) * j / g
    i_rad = p_rad * ki_hat
    drive = DriveGains(
        vel_gain=TWO_PI * p_rad,
        vel_integrator_gain=TWO_PI * i_rad,
        vel_derivative_gain=TWO_PI * d_rad,
        derivative_cutoff_hz=gains.derivative_cutoff_hz,
    )
    _check_wire(drive, codec or Codec.default(), where)
    return InnerLoopDesign(
        epsilon_s=eps,
        torque_gain=g,
        inertia_kgm2=j,
        k1=k1,
        k2=k2,
        k3_per_s=k3,
        kp=k1,
        kd=k2 / k1,
        ki=eps * ki_hat,
        ki_hat_per_s=ki_hat,
        p_nm_per_radps=p_rad,
        i_nm_per_rad=i_rad,
        d_nm_per_radps2=d_rad,
        fast_poles_per_s=fp,
        slow_pole_per_s=-ki_hat,
        closed_loop_poles_per_s=closed_loop_poles(k1, k2, k3, eps),
        drive_gains=drive,
    )


def _check_wire(gains: DriveGains, codec: Codec, where: str) -> None:
    """The gains must fit their CAN signals, or arming would fail at tick time."""
    try:
        codec.encode(SetVelGains(gains.vel_gain, gains.vel_integrator_gain), Node.LEFT)
        codec.encode(
            SetVelDerivativeGain(gains.vel_derivative_gain, gains.derivative_cutoff_hz), Node.LEFT
        )
    except EncodeError as err:
        raise ConfigError(f"{where}: the computed drive gains do not fit the wire: {err}") from err
