"""Chair physics: the paper's reduced dynamic model with a DC motor on each wheel.

This module owns the continuous state of the chair and its integration in fixed
steps; it knows nothing about CAN or drive firmware.  The equations
(docs/physics.md has the derivation and the parameter table):

* wheel dynamics in wheel-speed coordinates (paper Eq. controldynamics, inertia,
  velocity), generalised to a per-wheel contact radius ``rho_i``::

      Mbar(rho) * d/dt [w_R, w_L] = [tau_R, tau_L] - tau_rr - h(w)

      Mbar = [[I_w + rho_R^2 k_p,  rho_R rho_L k_m],
              [rho_R rho_L k_m,    I_w + rho_L^2 k_p]]
      k_p = (m b^2 + I) / (4 b^2),   k_m = (m b^2 - I) / (4 b^2)
      h_R =  (rho_R / 2) m d phi_dot (v / b - phi_dot)
      h_L = -(rho_L / 2) m d phi_dot (v / b + phi_dot)

  which for ``rho_R = rho_L = r`` is exactly the paper's ``Vbar`` with the
  ``m_c d phi_dot`` term;
* each wheel driven by a brushed DC motor through a gearbox (paper Eq. dcmotor)::

      L di/dt = u - K N w - R i,        tau = g * eta * N * K * i

* smooth rolling resistance ``tau_rr = (c_rr m g / 2) rho tanh(w / eps)`` and,
  while the drive is not in closed loop, a holding brake
  ``T_b tanh(w / eps_b)``;
* kinematics of the axle midpoint P0 (paper Eq. controlmodel)::

      v = (rho_R w_R + rho_L w_L) / 2,   phi_dot = (rho_R w_R - rho_L w_L) / (2 b)
      x_dot = v cos(phi),                y_dot = v sin(phi)

Fault seams (set by :mod:`firmware_sim.faults`, nominal values here): each
:class:`Wheel` has a mutable ``radius_m`` (a flat tyre shrinks it), an additive
``radius_offset_m`` (an eccentric shaft or a bump), a ``torque_gain`` (a weak
motor), ``motor_open`` (an open winding: no current, no torque) and a
longitudinal ``slip_ratio`` (ground speed = ``rho * w``, with
``rho = (radius_m + radius_offset_m) * (1 - slip_ratio)``).

The inner loop is plain scalar float arithmetic on purpose: numpy would cost more
per 1 ms step than the whole RK4 step does.
"""

from __future__ import annotations

import math

from firmware_sim.config import GRAVITY_MPS2, ChairParams, DriveParams, MotorParams


def wrap_angle(a: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    a = math.fmod(a + math.pi, math.tau)
    if a <= 0.0:
        a += math.tau
    return a - math.pi


class Wheel:
    """One drive wheel: its state, the drive's inputs to it, and the fault seams.

    State: ``omega_radps`` (wheel speed, + = forward), ``current_a`` (armature
    current), ``angle_rad`` (wheel angle, unwrapped).  Inputs, written by the
    drive every control tick: ``voltage_v`` (armature voltage, held for the tick),
    ``powered`` (inverter on; off forces the current to zero) and
    ``brake_engaged``.  Fault seams: ``radius_m``, ``radius_offset_m``,
    ``torque_gain``, ``motor_open``, ``slip_ratio`` (see the module docstring).
    """

    __slots__ = (
        "angle_rad",
        "brake_engaged",
        "current_a",
        "motor_open",
        "omega_radps",
        "powered",
        "radius_m",
        "radius_offset_m",
        "slip_ratio",
        "torque_gain",
        "voltage_v",
    )

    def __init__(self, radius_m: float) -> None:
        self.radius_m = radius_m
        self.radius_offset_m = 0.0
        self.torque_gain = 1.0
        self.slip_ratio = 0.0
        self.motor_open = False
        self.omega_radps = 0.0
        self.current_a = 0.0
        self.angle_rad = 0.0
        self.voltage_v = 0.0
        self.powered = False
        self.brake_engaged = True

    @property
    def rolling_radius_m(self) -> float:
        """Effective rolling radius: nominal radius plus the additive offset."""
        return self.radius_m + self.radius_offset_m

    @property
    def contact_radius_m(self) -> float:
        """Ground distance per wheel radian: rolling radius reduced by slip."""
        return (self.radius_m + self.radius_offset_m) * (1.0 - self.slip_ratio)


class Plant:
    """The chair's rigid-body dynamics, both motors and the pose of P0.

    ``step(dt_s)`` advances everything by one fixed step with the wheels'
    ``voltage_v`` held (zero-order hold, as a PWM drive applies it).  The wheel
    and current states are integrated with classic RK4; the wheel angles and the
    heading, being integrals of the wheel speeds, use the same RK4 quadrature;
    x and y follow the exact circular arc for the RK4-averaged ``v`` and
    ``phi_dot`` over the step.
    """

    __slots__ = (
        "_b",
        "_brake_nm",
        "_frr_half_n",
        "_inv_2b",
        "_inv_b",
        "_inv_brake_eps",
        "_inv_l",
        "_inv_rr_eps",
        "_iw",
        "_ke",
        "_km",
        "_kp",
        "_kt",
        "_md_half",
        "_res",
        "chair",
        "heading_rad",
        "left",
        "motor",
        "omega_radps",
        "right",
        "v_mps",
        "x_m",
        "y_m",
    )

    def __init__(
        self,
        chair: ChairParams,
        motor: MotorParams,
        drive: DriveParams,
        *,
        x_m: float = 0.0,
        y_m: float = 0.0,
        heading_rad: float = 0.0,
    ) -> None:
        self.chair = chair
        self.motor = motor
        self.left = Wheel(chair.wheel_radius_m)
        self.right = Wheel(chair.wheel_radius_m)
        self.x_m = float(x_m)
        self.y_m = float(y_m)
        #: Unwrapped heading (continuous); :attr:`heading_wrapped_rad` for (-pi, pi].
        self.heading_rad = float(heading_rad)
        self.v_mps = 0.0
        self.omega_radps = 0.0
        b = chair.half_track_m
        m, yaw = chair.mass_kg, chair.yaw_inertia_kgm2
        self._b = b
        self._inv_b = 1.0 / b
        self._inv_2b = 0.5 / b
        self._kp = (m * b * b + yaw) / (4.0 * b * b)
        self._km = (m * b * b - yaw) / (4.0 * b * b)
        self._iw = chair.wheel_inertia_kgm2
        self._md_half = 0.5 * m * chair.com_offset_m
        self._frr_half_n = 0.5 * chair.rolling_resistance_coeff * m * GRAVITY_MPS2
        self._inv_rr_eps = 1.0 / chair.rolling_speed_eps_radps
        self._kt = motor.gear_efficiency * motor.gear_ratio * motor.torque_constant_nm_per_a
        self._ke = motor.torque_constant_nm_per_a * motor.gear_ratio
        self._res = motor.resistance_ohm
        self._inv_l = 1.0 / motor.inductance_h
        self._brake_nm = drive.brake_torque_nm
        self._inv_brake_eps = 1.0 / drive.brake_speed_eps_radps

    # ------------------------------------------------------------------ queries

    @property
    def heading_wrapped_rad(self) -> float:
        """The chair's heading wrapped to (-pi, pi], in rad."""
        return wrap_angle(self.heading_rad)

    def mass_matrix(self) -> tuple[float, float, float]:
        """(M11, M12, M22) of Mbar for the current contact radii (right = index 1)."""
        rr, rl = self.right.contact_radius_m, self.left.contact_radius_m
        return (
            self._iw + rr * rr * self._kp,
            rr * rl * self._km,
            self._iw + rl * rl * self._kp,
        )

    def kinetic_energy_j(self) -> float:
        """1/2 w^T Mbar w: translation, yaw and wheel spin of the whole chair."""
        m11, m12, m22 = self.mass_matrix()
        wr, wl = self.right.omega_radps, self.left.omega_radps
        return 0.5 * (m11 * wr * wr + 2.0 * m12 * wr * wl + m22 * wl * wl)

    def body_twist(self) -> tuple[float, float]:
        """(v m/s, phi_dot rad/s) of P0 from the current wheel speeds."""
        rr, rl = self.right.contact_radius_m, self.left.contact_radius_m
        wr, wl = self.right.omega_radps, self.left.omega_radps
        return 0.5 * (rr * wr + rl * wl), (rr * wr - rl * wl) * self._inv_2b

    # --------------------------------------------------------------- integration

    def step(self, dt_s: float) -> None:
        """Advance the chair by ``dt_s`` with the wheels' voltages held."""
        R = self.right
        L = self.left
        rho_r = (R.radius_m + R.radius_offset_m) * (1.0 - R.slip_ratio)
        rho_l = (L.radius_m + L.radius_offset_m) * (1.0 - L.slip_ratio)
        kp = self._kp
        m12 = rho_r * rho_l * self._km
        m11 = self._iw + rho_r * rho_r * kp
        m22 = self._iw + rho_l * rho_l * kp
        inv_det = 1.0 / (m11 * m22 - m12 * m12)
        a11 = m22 * inv_det
        a22 = m11 * inv_det
        a12 = -m12 * inv_det
        inv_2b = self._inv_2b
        mdr = self._md_half * rho_r
        mdl = self._md_half * rho_l
        frr_r = self._frr_half_n * rho_r
        frr_l = self._frr_half_n * rho_l
        inv_eps = self._inv_rr_eps
        inv_beps = self._inv_brake_eps
        brk_r = self._brake_nm if R.brake_engaged else 0.0
        brk_l = self._brake_nm if L.brake_engaged else 0.0
        if R.powered and not R.motor_open:
            kt_r = R.torque_gain * self._kt
            g_r = self._inv_l
            u_r = R.voltage_v
            i_r0 = R.current_a
        else:
            kt_r = g_r = u_r = i_r0 = 0.0
        if L.powered and not L.motor_open:
            kt_l = L.torque_gain * self._kt
            g_l = self._inv_l
            u_l = L.voltage_v
            i_l0 = L.current_a
        else:
            kt_l = g_l = u_l = i_l0 = 0.0
        tanh = math.tanh
        h = dt_s
        hh = 0.5 * h
        gu_r = g_r * u_r
        gu_l = g_l * u_l
        gke_r = g_r * self._ke
        gke_l = g_l * self._ke
        gres_r = g_r * self._res
        gres_l = g_l * self._res
        # Classic RK4, unrolled (a loop costs ~15 % here).  Stage 1:
        w_r0 = w_r = R.omega_radps
        w_l0 = w_l = L.omega_radps
        i_r = i_r0
        i_l = i_l0
        d = rho_r * w_r
        e = rho_l * w_l
        w = (d - e) * inv_2b
        vb = (d + e) * inv_2b
        t_r = kt_r * i_r - frr_r * tanh(w_r * inv_eps) - mdr * w * (vb - w)
        t_l = kt_l * i_l - frr_l * tanh(w_l * inv_eps) + mdl * w * (vb + w)
        if brk_r:
            t_r -= brk_r * tanh(w_r * inv_beps)
        if brk_l:
            t_l -= brk_l * tanh(w_l * inv_beps)
        dwr1 = a11 * t_r + a12 * t_l
        dwl1 = a12 * t_r + a22 * t_l
        dir1 = gu_r - gke_r * w_r - gres_r * i_r
        dil1 = gu_l - gke_l * w_l - gres_l * i_l
        # Stage 2 (half step with stage-1 rates):
        w_r2 = w_r = w_r0 + hh * dwr1
        w_l2 = w_l = w_l0 + hh * dwl1
        i_r = i_r0 + hh * dir1
        i_l = i_l0 + hh * dil1
        d = rho_r * w_r
        e = rho_l * w_l
        w = (d - e) * inv_2b
        vb = (d + e) * inv_2b
        t_r = kt_r * i_r - frr_r * tanh(w_r * inv_eps) - mdr * w * (vb - w)
        t_l = kt_l * i_l - frr_l * tanh(w_l * inv_eps) + mdl * w * (vb + w)
        if brk_r:
            t_r -= brk_r * tanh(w_r * inv_beps)
        if brk_l:
            t_l -= brk_l * tanh(w_l * inv_beps)
        dwr2 = a11 * t_r + a12 * t_l
        dwl2 = a12 * t_r + a22 * t_l
        dir2 = gu_r - gke_r * w_r - gres_r * i_r
        dil2 = gu_l - gke_l * w_l - gres_l * i_l
        # Stage 3 (half step with stage-2 rates):
        w_r3 = w_r = w_r0 + hh * dwr2
        w_l3 = w_l = w_l0 + hh * dwl2
        i_r = i_r0 + hh * dir2
        i_l = i_l0 + hh * dil2
        d = rho_r * w_r
        e = rho_l * w_l
        w = (d - e) * inv_2b
        vb = (d + e) * inv_2b
        t_r = kt_r * i_r - frr_r * tanh(w_r * inv_eps) - mdr * w * (vb - w)
        t_l = kt_l * i_l - frr_l * tanh(w_l * inv_eps) + mdl * w * (vb + w)
        if brk_r:
            t_r -= brk_r * tanh(w_r * inv_beps)
        if brk_l:
            t_l -= brk_l * tanh(w_l * inv_beps)
        dwr3 = a11 * t_r + a12 * t_l
        dwl3 = a12 * t_r + a22 * t_l
        dir3 = gu_r - gke_r * w_r - gres_r * i_r
        dil3 = gu_l - gke_l * w_l - gres_l * i_l
        # Stage 4 (full step with stage-3 rates):
        w_r = w_r0 + h * dwr3
        w_l = w_l0 + h * dwl3
        i_r = i_r0 + h * dir3
        i_l = i_l0 + h * dil3
        d = rho_r * w_r
        e = rho_l * w_l
        w = (d - e) * inv_2b
        vb = (d + e) * inv_2b
        t_r = kt_r * i_r - frr_r * tanh(w_r * inv_eps) - mdr * w * (vb - w)
        t_l = kt_l * i_l - frr_l * tanh(w_l * inv_eps) + mdl * w * (vb + w)
        if brk_r:
            t_r -= brk_r * tanh(w_r * inv_beps)
        if brk_l:
            t_l -= brk_l * tanh(w_l * inv_beps)
        dwr4 = a11 * t_r + a12 * t_l
        dwl4 = a12 * t_r + a22 * t_l
        dir4 = gu_r - gke_r * w_r - gres_r * i_r
        dil4 = gu_l - gke_l * w_l - gres_l * i_l
        h6 = h / 6.0
        R.omega_radps = w_r0 + h6 * (dwr1 + 2.0 * (dwr2 + dwr3) + dwr4)
        L.omega_radps = w_l0 + h6 * (dwl1 + 2.0 * (dwl2 + dwl3) + dwl4)
        R.current_a = i_r0 + h6 * (dir1 + 2.0 * (dir2 + dir3) + dir4)
        L.current_a = i_l0 + h6 * (dil1 + 2.0 * (dil2 + dil3) + dil4)
        # Wheel angles and heading are integrals of the wheel speeds: same quadrature.
        dth_r = h6 * (w_r0 + 2.0 * (w_r2 + w_r3) + w_r)
        dth_l = h6 * (w_l0 + 2.0 * (w_l2 + w_l3) + w_l)
        R.angle_rad += dth_r
        L.angle_rad += dth_l
        d = rho_r * dth_r
        e = rho_l * dth_l
        dphi = (d - e) * inv_2b
        ds = 0.5 * (d + e)
        # Pose: exact arc for the step's mean v and phi_dot.
        half = 0.5 * dphi
        if -0.1 < half < 0.1:
            h2 = half * half
            chord = ds * (1.0 - h2 * (1.0 / 6.0 - h2 * (1.0 / 120.0)))
        else:
            chord = ds * math.sin(half) / half
        mid = self.heading_rad + half
        self.x_m += chord * math.cos(mid)
        self.y_m += chord * math.sin(mid)
        self.heading_rad += dphi
        self.v_mps = 0.5 * (rho_r * R.omega_radps + rho_l * L.omega_radps)
        self.omega_radps = (rho_r * R.omega_radps - rho_l * L.omega_radps) * inv_2b
