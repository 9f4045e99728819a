"""ROBUST: the paper's sliding-mode controller after Solea et al. (2007), on the dynamic model.

The paper (Eq. robustctrl, "Parametrization": "weighted gain control law for equivalent
control; reaching mode with separated x_e and phi_e surfaces; simple PID") builds ROBUST on
the chair's *dynamic* model with the two generalized inputs of Solea et al.::

    v'     = alpha u1,   alpha = 1 / (r m)        u1 = tau_r + tau_l   (wheel torques, N*m)
    omega' = beta  u2,   beta  = b / (r I)        u2 = tau_r - tau_l

``m`` and ``I`` are the believed chair's translational and yaw inertia as the paper's
Eq. (inertia) gives them for the wheel speeds, wheels included:
``m = m_body + 2 I_w / r^2``, ``I = I_body + 2 b^2 I_w / r^2`` (controller.toml ``[body]``).

Errors: the paper's Eq. (errorvector) and their rates Eq. (derrorvector), with the estimated
twist ``(v, omega)``.  Two *separate* surfaces, one for ``x_e`` and one for ``phi_e``::

    s1 = x_e' + k1 x_e
    s2 = phi_e' + k2 phi_e + k0 v_d y_e

``s2``'s last term is our reading (docs/controllers.md, "ROBUST"): a surface on ``phi_e``
alone leaves ``y_e`` uncontrolled (``y_e' = v sin phi_e - omega_d x_e``); with it, on
``s2 = 0`` the lateral error obeys ``y_e'' + k2 y_e' + k0 v_d v y_e = 0`` (small angles).
Both surfaces contain the first derivative of a velocity, so the torques enter ``s'``::

    s1' = alpha cos(phi_e) u1 + D1,   D1 = -a_d - v sin(phi_e) phi_e' + alpha_d y_e
                                           + omega_d y_e' + k1 x_e'
    s2' = beta u2 + D2,               D2 = -alpha_d + k2 phi_e' + k0 (a_d y_e + v_d y_e')

The control is equivalent control (the paper's Eq. robustctrl) plus the reaching law the
paper uses for its sliding modes (Eq. controllawmanifold, sgn replaced by a saturation
with boundary layer ``Phi``, as the paper allows)::

    u_eq1 = -D1 / (alpha cos(phi_e)),           u_eq2 = -D2 / beta
    u1 = u_eq1 - (Q1 s1 + P1 sat(s1/Phi1)) / (alpha cos(phi_e))
    u2 = u_eq2 - (Q2 s2 + P2 sat(s2/Phi2)) / beta

so that ``s' = -Q s - P sat(s/Phi)`` when the model is right.  The drives are velocity
controlled (ODrive ``Set_Input_Vel``): the torques are turned into the set-point twist by
the believed model, ``v_c' = alpha u1``, ``omega_c' = beta u2``, integrated inside the
chair's limits (``LimitParams``, the one envelope every law and the node's limiter share:
speed, turn rate and their accelerations; anti-windup), and the drives' *plain PID*
(``PlainPid``, pushed when arming) realizes it.  Where ``cos(phi_e)`` falls below ``cos_min`` the division is replaced by a
gain that fades to zero at 90 degrees (``cos(phi_e) -> 0``: the paper's law is singular
there); nothing is ever divided by zero.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from controller.config import BodyParams, GeometryParams, LimitParams, load_config
from controller.tracking.common import PlainPid, inv_cos, sat, stop_radius
from controller.tracking.parking import RouteEndLatch
from controller.types import (
    ReferenceSample,
    StateEstimate,
    Trajectory,
    TwistCommand,
    wrap_angle,
)
from dbc.runtime.params import param, section

#: Names of :meth:`RobustSMC.internals`, in the order of its ``_last`` tuple.
INTERNAL_KEYS = (
    "e_x_m",
    "e_y_m",
    "e_phi_rad",
    "parked",
    "surface.s1_mps",
    "surface.s2_radps",
    "surface.u1_nm",
    "surface.u2_nm",
    "surface.u_eq1_nm",
    "surface.u_eq2_nm",
    "surface.v_c_mps",
    "surface.omega_c_radps",
)


def effective_inertias(body: BodyParams, geometry: GeometryParams) -> tuple[float, float]:
    """``(m, I)`` of the paper's Eq. (inertia) in body coordinates, wheels included."""
    r, b = geometry.wheel_radius_m, geometry.half_track_m
    iw = body.wheel_inertia_kgm2
    return body.mass_kg + 2.0 * iw / (r * r), body.yaw_inertia_kgm2 + 2.0 * b * b * iw / (r * r)


class RobustSMC:
    """The paper's ROBUST (Solea et al. 2007); see the module doc."""

    name: ClassVar[str] = "robust"

    @dataclass(frozen=True)
    class Params:
        k1_per_s: float = param(
            2.0, unit="1/s", lo=0.01, hi=50.0, doc="k1: x_e decays at k1 on s1 = 0"
        )
        k2_per_s: float = param(
            3.0, unit="1/s", lo=0.01, hi=50.0, doc="k2: phi_e decay rate on s2 = 0"
        )
        k0_per_m2: float = param(
            4.0,
            unit="1/m^2",
            lo=0.0,
            hi=500.0,
            doc="k0: lateral term k0 v_d y_e of the phi_e surface (y_e frequency v sqrt(k0))",
        )
        q1_per_s: float = param(3.0, unit="1/s", lo=0.0, hi=100.0, doc="Q1: reaching rate of s1")
        p1_mps2: float = param(0.2, unit="m/s^2", lo=0.0, hi=10.0, doc="P1: switching gain of s1")
        boundary1_mps: float = param(
            0.05, unit="m/s", lo=1e-4, hi=1.0, doc="Phi1: boundary layer of s1"
        )
        q2_per_s: float = param(4.0, unit="1/s", lo=0.0, hi=100.0, doc="Q2: reaching rate of s2")
        p2_radps2: float = param(
            0.3, unit="rad/s^2", lo=0.0, hi=20.0, doc="P2: switching gain of s2"
        )
        boundary2_radps: float = param(
            0.05, unit="rad/s", lo=1e-4, hi=1.0, doc="Phi2: boundary layer of s2"
        )
        cos_min: float = param(
            0.35,
            unit="1",
            lo=0.05,
            hi=1.0,
            doc="below this cos(phi_e) the 1/cos(phi_e) of u_eq1 fades to 0 at 90 deg",
        )
        stop_radius_m: float = stop_radius()
        inner_loop: PlainPid = section(PlainPid, "the drives' velocity PID pushed when arming")

    def __init__(
        self,
        params: Params,
        geometry: GeometryParams,
        trajectory: Trajectory,
        *,
        body: BodyParams | None = None,
        limits: LimitParams | None = None,
    ) -> None:
        self.p = params
        if body is None or limits is None:
            cfg = load_config()
            body = body if body is not None else cfg.body
            limits = limits if limits is not None else cfg.limits
        self.body = body
        #: The chair's limits: the bounds of v_c, omega_c and of their rates.
        self.limits = limits
        m, inertia = effective_inertias(self.body, geometry)
        r = geometry.wheel_radius_m
        #: the paper's alpha = 1/(r m) and beta = b/(r I), of the believed chair
        self.alpha = 1.0 / (r * m)
        self.beta = geometry.half_track_m / (r * inertia)
        self.drive_gains = params.inner_loop.drive_gains()
        self._reset()

    def _reset(self) -> None:
        self._v_c = 0.0
        self._w_c = 0.0
        self._park = RouteEndLatch()
        self._last: tuple[float, ...] = (0.0,) * len(INTERNAL_KEYS)

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        self._reset()
        lim = self.limits
        if math.isfinite(estimate.v_mps):
            self._v_c = min(max(estimate.v_mps, -lim.v_reverse_max_mps), lim.v_max_mps)
        if math.isfinite(estimate.omega_radps):
            w = estimate.omega_radps
            self._w_c = min(max(w, -lim.omega_max_radps), lim.omega_max_radps)

    def inv_cos(self, c: float) -> float:
        """``1/cos(phi_e)`` where it is well posed, fading to 0 at 90 degrees below ``cos_min``."""
        return inv_cos(c, self.p.cos_min)

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        p, lim = self.p, self.limits
        h = dt_s if (dt_s > 0.0 and math.isfinite(dt_s)) else 0.0
        c, s = math.cos(ref.heading_rad), math.sin(ref.heading_rad)
        dx, dy = est.x_m - ref.x_m, est.y_m - ref.y_m
        xe, ye = c * dx + s * dy, -s * dx + c * dy
        pe = (
            wrap_angle(est.heading_rad - ref.heading_rad) if math.isfinite(est.heading_rad) else 0.0
        )
        v, w = est.v_mps, est.omega_radps
        vd, wd, ad, al = ref.v_mps, ref.omega_radps, ref.a_mps2, ref.alpha_radps2
        if self._park.check(ref.done, math.hypot(xe, ye), p.stop_radius_m):
            self._v_c = self._w_c = 0.0
            self._last = (xe, ye, pe, 1.0, *self._last[4:10], 0.0, 0.0)
            return TwistCommand(0.0, 0.0)
        if not (est.valid and math.isfinite(xe + ye + pe + v + w + vd + wd + ad + al)):
            # degrade, never raise: ramp both to zero within the envelope
            self._v_c = (
                max(0.0, self._v_c - lim.decel_max_mps2 * h)
                if self._v_c >= 0.0
                else min(0.0, self._v_c + lim.decel_max_mps2 * h)
            )
            dw = lim.alpha_max_radps2 * h
            self._w_c = 0.0 if abs(self._w_c) <= dw else self._w_c - math.copysign(dw, self._w_c)
            return TwistCommand(self._v_c, self._w_c)
        cp, sp = math.cos(pe), math.sin(pe)
        xe_d = -vd + v * cp + wd * ye  # Eq. derrorvector with the estimated twist
        ye_d = v * sp - wd * xe
        pe_d = w - wd

        # x_e surface: s1' = alpha cos(phi_e) u1 + D1
        s1 = xe_d + p.k1_per_s * xe
        d1 = -ad - v * sp * pe_d + al * ye + wd * ye_d + p.k1_per_s * xe_d
        inv = self.inv_cos(cp) / self.alpha
        u_eq1 = -d1 * inv
        u1 = u_eq1 - (p.q1_per_s * s1 + p.p1_mps2 * sat(s1 / p.boundary1_mps)) * inv

        # phi_e surface: s2' = beta u2 + D2
        s2 = pe_d + p.k2_per_s * pe + p.k0_per_m2 * vd * ye
        d2 = -al + p.k2_per_s * pe_d + p.k0_per_m2 * (ad * ye + vd * ye_d)
        u_eq2 = -d2 / self.beta
        u2 = u_eq2 - (p.q2_per_s * s2 + p.p2_radps2 * sat(s2 / p.boundary2_radps)) / self.beta

        # the believed model turns the torques into the drives' set-point twist
        acc = self.alpha * u1
        speeding_up = (self._v_c >= 0.0) == (acc >= 0.0)
        a_max = lim.accel_max_mps2 if speeding_up else lim.decel_max_mps2
        acc = min(max(acc, -a_max), a_max)
        self._v_c = min(max(self._v_c + acc * h, -lim.v_reverse_max_mps), lim.v_max_mps)
        wdot = min(max(self.beta * u2, -lim.alpha_max_radps2), lim.alpha_max_radps2)
        self._w_c = min(max(self._w_c + wdot * h, -lim.omega_max_radps), lim.omega_max_radps)
        self._last = (xe, ye, pe, 0.0, s1, s2, u1, u2, u_eq1, u_eq2, self._v_c, self._w_c)
        return TwistCommand(self._v_c, self._w_c)

    def internals(self) -> Mapping[str, float]:
        return dict(zip(INTERNAL_KEYS, self._last, strict=True))
