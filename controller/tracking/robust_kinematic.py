"""ROBUST-KINEMATIC: a kinematic two-surface sliding mode with a plain PID inner loop.

This was the project's ROBUST before the paper's (``robust.py``, Solea et al. 2007 on the
dynamic model) replaced it; it stays available as ``--controller robust-kinematic``.  Its
longitudinal channel is ANTIFRAGILE's acceleration law with other gains.

Errors are the paper's (Eq. errorvector: actual minus desired, in the desired frame) and
their derivatives Eq. derrorvector, evaluated with the *measured* twist ``(v, omega)``::

    x_e' = -v_d + v cos(phi_e) + omega_d y_e
    y_e' =  v sin(phi_e) - omega_d x_e
    phi_e' = omega - omega_d

Two separate surfaces, as the paper's "Parametrization" gives for ROBUST: one for the
along-path error ``x_e`` and one for the heading error ``phi_e``::

    s1 = x_e' + lambda_x x_e                      (Solea & Nunes' longitudinal surface)
    s2 = phi_e + atan(g k_y y_e)                  (heading surface)

On ``s2 = 0`` the chair holds the heading ``-atan(k_y y_e)`` relative to the path, so
``y_e' = v sin(phi_e) ~ -v k_y y_e``: the heading surface steers the lateral error out
(a surface on ``phi_e`` alone would leave ``y_e`` to drift, ``y_e' = -omega_d x_e``).
``g = min(1, |v_d| / shaping_speed)`` fades the shaping out when the reference is (nearly)
at rest -- start, pause, end -- where a lateral error cannot be steered out anyway and
turning on the spot over a few centimetres of estimate noise would only disturb the rider.
Both surfaces are reached with the paper's reaching law (Eq. controllawmanifold)
``s' = -Q s - P sat(s / Phi)``: a proportional term plus a switching term whose sign
function is replaced by a saturation with boundary layer ``Phi`` against chattering.
Solving ``s' = ...`` for the inputs gives equivalent control plus switching term:

    v_c'   = [ -Q1 s1 - P1 sat(s1/Phi1) - lambda_x x_e' + a_d + v phi_e' sin(phi_e)
               - omega_d y_e' - alpha_d y_e ] / cos(phi_e)                      (Eq. controllawacc)
    omega_c = omega_d - k_y (g y_e' + g' y_e) / (1 + (g k_y y_e)^2) - Q2 s2 - P2 sat(s2/Phi2)

``v_c`` is the integral of ``v_c'`` (the paper's law gives the acceleration), with the
integrator held inside the speed and acceleration bounds (anti-windup).  Where
``cos(phi_e) < cos_min`` (chair more than ~70 degrees off the path heading, e.g. a 90 degree
start) the division is replaced by a gain that fades to zero at 90 degrees, so the heading
surface turns the chair first instead of ``x_e`` being chased sideways.

The inner loop is the drives' velocity PID.  ``drive_gains`` pushes a plain PID (no
singular-perturbation design: all three terms chosen together for the chair's wheel
inertia) when arming; see ``docs/controllers.md``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from controller.config import GeometryParams
from controller.tracking.common import PlainPid, inv_cos, path_errors, sat, stop_radius
from controller.tracking.parking import RouteEndLatch
from controller.types import ReferenceSample, StateEstimate, Trajectory, TwistCommand
from dbc.runtime.params import param, section


class RobustKinematicSMC:
    """Two-surface sliding-mode tracking law; see the module doc."""

    name: ClassVar[str] = "robust-kinematic"

    @dataclass(frozen=True)
    class Params:
        lambda_x: float = param(
            2.5, unit="1/s", lo=0.01, hi=50.0, doc="x_e decay rate on the surface s1 = 0"
        )
        reach_x: float = param(
            3.0, unit="1/s", lo=0.0, hi=100.0, doc="Q1: proportional reaching rate of s1"
        )
        switch_x: float = param(0.2, unit="m/s^2", lo=0.0, hi=10.0, doc="P1: switching gain of s1")
        boundary_x: float = param(
            0.05, unit="m/s", lo=1e-4, hi=1.0, doc="Phi1: boundary layer of s1"
        )
        k_y: float = param(
            2.5, unit="1/m", lo=0.0, hi=100.0, doc="lateral shaping of the heading surface s2"
        )
        shaping_speed_mps: float = param(
            0.1,
            unit="m/s",
            lo=1e-3,
            hi=2.0,
            doc="below this reference speed the lateral shaping fades out (no turning at rest)",
        )
        reach_phi: float = param(
            3.0, unit="1/s", lo=0.0, hi=100.0, doc="Q2: proportional reaching rate of s2"
        )
        switch_phi: float = param(
            0.15, unit="rad/s", lo=0.0, hi=10.0, doc="P2: switching gain of s2"
        )
        boundary_phi: float = param(
            0.05, unit="rad", lo=1e-4, hi=1.0, doc="Phi2: boundary layer of s2"
        )
        cos_min: float = param(
            0.35,
            unit="1",
            lo=0.05,
            hi=1.0,
            doc="below this cos(phi_e) the x_e control fades out instead of dividing",
        )
        v_min_mps: float = param(
            -0.4, unit="m/s", lo=-3.0, hi=0.0, doc="lowest speed command (reverse)"
        )
        v_max_mps: float = param(1.45, unit="m/s", lo=0.1, hi=3.0, doc="highest speed command")
        accel_max_mps2: float = param(
            0.95, unit="m/s^2", lo=0.05, hi=10.0, doc="upper bound of v_c' (anti-windup)"
        )
        decel_max_mps2: float = param(
            1.4, unit="m/s^2", lo=0.05, hi=10.0, doc="lower bound of v_c', magnitude"
        )
        omega_max_radps: float = param(1.9, unit="rad/s", lo=0.1, hi=10.0, doc="|omega_c| bound")
        stop_radius_m: float = stop_radius()
        inner_loop: PlainPid = section(PlainPid, "the drives' velocity PID pushed when arming")

    def __init__(self, params: Params, geometry: GeometryParams, trajectory: Trajectory) -> None:
        self.p = params
        self.drive_gains = params.inner_loop.drive_gains()
        self._reset()

    def _reset(self) -> None:
        self._v_c = 0.0
        self._park = RouteEndLatch()
        self._e = (0.0, 0.0, 0.0)
        self._s = (0.0, 0.0)
        self._vdot = 0.0

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        self._reset()
        v = estimate.v_mps
        if math.isfinite(v):
            self._v_c = min(max(v, self.p.v_min_mps), self.p.v_max_mps)

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        p = self.p
        xe, ye, pe = path_errors(ref, est)
        self._e = (xe, ye, pe)
        if self._park.check(ref.done, math.hypot(xe, ye), p.stop_radius_m):
            self._v_c = 0.0
            return TwistCommand(0.0, 0.0)
        v, w = est.v_mps, est.omega_radps
        vd, wd, ad = ref.v_mps, ref.omega_radps, ref.a_mps2
        h = dt_s if dt_s > 0.0 else 0.0
        if not math.isfinite(xe + ye + pe + v + w + vd + wd + ad + ref.alpha_radps2 + h):
            # degrade, never raise: ramp the speed down, no turn
            self._v_c = max(0.0, self._v_c - p.decel_max_mps2 * (h if math.isfinite(h) else 0.0))
            return TwistCommand(self._v_c, 0.0)
        cp, sp = math.cos(pe), math.sin(pe)
        xe_d = -vd + v * cp + wd * ye  # Eq. derrorvector with the measured twist
        ye_d = v * sp - wd * xe
        pe_d = w - wd

        # s1: along-path surface, acceleration from s1' = -Q1 s1 - P1 sat(s1/Phi1)
        s1 = xe_d + p.lambda_x * xe
        num = (
            -p.reach_x * s1
            - p.switch_x * sat(s1 / p.boundary_x)
            - p.lambda_x * xe_d
            + ad
            + v * pe_d * sp
            - wd * ye_d
            - ref.alpha_radps2 * ye
        )
        inv = inv_cos(cp, p.cos_min)
        vdot = min(max(num * inv, -p.decel_max_mps2), p.accel_max_mps2)
        self._vdot = vdot
        self._v_c = min(max(self._v_c + vdot * h, p.v_min_mps), p.v_max_mps)

        # s2: heading surface with lateral shaping, faded in with the reference speed
        vs = p.shaping_speed_mps
        if abs(vd) >= vs:
            g, g_d = 1.0, 0.0
        else:
            g, g_d = abs(vd) / vs, (ad if vd >= 0.0 else -ad) / vs
        ky_ye = p.k_y * g * ye
        s2 = pe + math.atan(ky_ye)
        omega = (
            wd
            - p.k_y * (g * ye_d + g_d * ye) / (1.0 + ky_ye * ky_ye)
            - p.reach_phi * s2
            - p.switch_phi * sat(s2 / p.boundary_phi)
        )
        omega = min(max(omega, -p.omega_max_radps), p.omega_max_radps)
        self._s = (s1, s2)
        return TwistCommand(self._v_c, omega)

    def internals(self) -> Mapping[str, float]:
        return {
            "e_x_m": self._e[0],
            "e_y_m": self._e[1],
            "e_phi_rad": self._e[2],
            "parked": float(self._park.parked),
            "surface.s1_mps": self._s[0],
            "surface.s2_rad": self._s[1],
            "surface.v_c_mps": self._v_c,
            "surface.vdot_c_mps2": self._vdot,
        }
