"""ROBUST: the paper's sliding-mode controller after Solea et al. (2007), on the dynamic model.

The paper (Eq. robustctrl, "Parametrization": "weighted gain control law for equivalent
control; reaching mode with separated x_e and phi_e surfaces; simple PID") builds ROBUST on
the chair's *dynamic* model with the two generalized inputs of Solea et al.::

    v'     = alpha u1,   alpha = 1 / (r m)        u1 = tau_r + tau_l   (wheel torques, N*m)
    omega' = beta  u2,   beta  = b / (r I)        u2 = tau_r - tau_l

``m`` and ``I`` are the believed chair's translational and yaw inertia as the paper's
Eq. (inertia) gives them for the wheel speeds, wheels included:
``m = m_body + 2 I_w / r^2``, ``I = I_body + 2 b^2 I_w / r^2`` (controller.toml ``[body]``).
The model's state is the law's own commanded twist ``(v_c, omega_c)``, which the drives'
plain PID follows (velocity-controlled drives: ``Set_Input_Vel``).

Errors: the paper's Eq. (errorvector) from the estimated pose; their rates Eq. (derrorvector)
with the *commanded* twist (the surfaces are evaluated on the model the torques act on, not on
the odometry's rates, which would close a fast loop around the drives' own)::

    x_e'c = -v_d + v_c cos(phi_e) + omega_d y_e     y_e'c = v_c sin(phi_e) - omega_d x_e
    phi_e'c = omega_c - omega_d

Two *separate* surfaces, one for ``x_e`` and one for ``phi_e``, the second carrying a bounded
lateral term (our reading, docs/controllers.md "ROBUST")::

    s1 = x_e'c + k1 x_e
    s2 = phi_e'c + k2 phi_e + v_d L(y_e),     L(y) = k0 Y tanh(y / Y)

On ``s2 = 0`` the heading the surface asks for is ``-v_d L(y_e) / k2``, at most
``k0 v_d Y / k2``: ``Y = phi_max k2 / (k0 v_top)`` keeps it below ``phi_max < pi/2`` at every
speed up to the chair's top speed ``v_top`` (``limits.v_max_mps``), so the chair is never asked
to point across its path, where ``y_e'`` would reverse sign.  ``k0`` follows from the lateral
loop's damping at the top speed, ``k0 = (k2 / (2 zeta v_top))^2`` (small errors on ``s2 = 0``:
``y_e'' + k2 y_e' + k0 v_d^2 y_e = 0``, damping ``k2 / (2 v_d sqrt(k0)) >= zeta``).

Both surfaces contain a velocity, so the torques enter ``s'``::

    s1' = alpha cos(phi_e) u1 + D1,   D1 = -a_d - v_c sin(phi_e) phi_e'c + alpha_d y_e
                                           + omega_d y_e'c + k1 x_e'c
    s2' = beta u2 + D2,               D2 = -alpha_d + k2 phi_e'c + a_d L(y_e) + v_d L'(y_e) y_e'c

The control is equivalent control (the paper's Eq. robustctrl) plus the reaching law of its
sliding modes (Eq. controllawmanifold, sgn replaced by a saturation with boundary layer
``Phi``, as the paper allows)::

    u1 = (-D1 - Q1 s1 - P1 sat(s1/Phi1)) / (alpha cos(phi_e))
    u2 = (-D2 - Q2 s2 - P2 sat(s2/Phi2)) / beta

so that ``s' = -Q s - P sat(s/Phi)`` when the model is right.  What the drives do not realise
(a flat tire's slower wheel, slip) reaches ``s2'`` as ``k2 (omega - omega_c)``: the switching
gain ``P2`` is sized to exceed it, the boundary layer ``Phi2`` to the surface's noise, so the
switching acts (docs/controllers.md gives the sizes and the envelope relations the constructor
checks).  ``v_c' = alpha u1`` and ``omega_c' = beta u2`` are integrated inside the chair's
limits (``LimitParams``: speed, turn rate and their accelerations; anti-windup).  Speed yields
to steering: beyond ``phi_max`` the speed is capped by ``cos(phi_e) / cos(phi_max)`` of the top
speed, and the ``1/cos(phi_e)`` of ``u1`` fades to zero at 90 degrees (nothing is divided by
zero).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from controller.config import BodyParams, GeometryParams, LimitParams
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

log = logging.getLogger(__name__)

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

#: Names of :meth:`RobustSMC.activity`'s counts, in the order of its ``_counts`` list.
ACTIVITY_KEYS = (
    "ticks",
    "outside_boundary1",
    "outside_boundary2",
    "beyond_heading_max",
    "speed_yield",
    "accel_clip",
    "turn_accel_clip",
)

#: The drives' velocity loops close at about 21-25 rad/s (docs/controllers.md, the plain
#: PID): a rate of the outer law above a third of that is not realised by them.
RATE_MAX_PER_S = 8.0


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
            2.0,
            unit="1/s",
            lo=0.01,
            hi=RATE_MAX_PER_S,
            doc="k1: x_e decays at k1 on s1 = 0 (at most a third of the drive loop's bandwidth)",
        )
        k2_per_s: float = param(
            3.0,
            unit="1/s",
            lo=0.01,
            hi=RATE_MAX_PER_S,
            doc="k2: phi_e decay rate on s2 = 0 (at most a third of the drive loop's bandwidth)",
        )
        lateral_damping: float = param(
            0.8,
            unit="1",
            lo=0.3,
            hi=5.0,
            doc="zeta: damping of y_e on s2 = 0 at the chair's top speed; k0 = (k2 / (2 zeta "
            "v_top))^2",
        )
        heading_max_rad: float = param(
            0.6,
            unit="rad",
            lo=0.05,
            hi=1.4,
            doc="phi_max: the largest heading error s2 = 0 asks for (< pi/2); beyond it the "
            "speed yields",
        )
        q1_per_s: float = param(
            3.0, unit="1/s", lo=0.0, hi=RATE_MAX_PER_S, doc="Q1: reaching rate of s1"
        )
        p1_mps2: float = param(0.3, unit="m/s^2", lo=0.0, hi=10.0, doc="P1: switching gain of s1")
        boundary1_mps: float = param(
            0.03, unit="m/s", lo=1e-4, hi=1.0, doc="Phi1: boundary layer of s1"
        )
        q2_per_s: float = param(
            4.0, unit="1/s", lo=0.0, hi=RATE_MAX_PER_S, doc="Q2: reaching rate of s2"
        )
        p2_radps2: float = param(
            1.0, unit="rad/s^2", lo=0.0, hi=20.0, doc="P2: switching gain of s2"
        )
        boundary2_radps: float = param(
            0.06, unit="rad/s", lo=1e-4, hi=1.0, doc="Phi2: boundary layer of s2"
        )
        speed_floor: float = param(
            0.2,
            unit="1",
            lo=0.0,
            hi=1.0,
            doc="the yielding speed cap never falls below this share of the top speed",
        )
        stop_radius_m: float = stop_radius()
        inner_loop: PlainPid = section(PlainPid, "the drives' velocity PID pushed when arming")

    def __init__(
        self,
        params: Params,
        geometry: GeometryParams,
        trajectory: Trajectory,
        *,
        body: BodyParams,
        limits: LimitParams,
    ) -> None:
        self.p = p = params
        self.body = body
        #: The chair's limits: the bounds of v_c, omega_c and of their rates.
        self.limits = lim = limits
        src = "controller/gains.toml [robust]"
        a_lin = min(lim.accel_max_mps2, lim.decel_max_mps2)
        # The sizing relations (docs/controllers.md "ROBUST"): not errors, since the envelope
        # bounds every command whatever the gains, but a sign that they were not sized for
        # this chair's limits.
        if p.q1_per_s * p.boundary1_mps + p.p1_mps2 > a_lin:
            log.warning(
                "%s: q1_per_s * boundary1_mps + p1_mps2 = %g m/s^2 exceeds the chair's "
                "acceleration limit %g m/s^2 (limits): the reaching law saturates inside its "
                "own boundary layer",
                src,
                p.q1_per_s * p.boundary1_mps + p.p1_mps2,
                a_lin,
            )
        if p.q2_per_s * p.boundary2_radps + p.p2_radps2 > lim.alpha_max_radps2:
            log.warning(
                "%s: q2_per_s * boundary2_radps + p2_radps2 = %g rad/s^2 exceeds the chair's "
                "turn-acceleration limit alpha_max_radps2 = %g rad/s^2: the reaching law "
                "saturates inside its own boundary layer",
                src,
                p.q2_per_s * p.boundary2_radps + p.p2_radps2,
                lim.alpha_max_radps2,
            )
        m, inertia = effective_inertias(self.body, geometry)
        r = geometry.wheel_radius_m
        #: the paper's alpha = 1/(r m) and beta = b/(r I), of the believed chair
        self.alpha = 1.0 / (r * m)
        self.beta = geometry.half_track_m / (r * inertia)
        v_top = lim.v_max_mps
        #: k0 (1/m^2) from the lateral damping at the top speed, and the bound Y (m) that keeps
        #: the heading s2 = 0 asks for within heading_max_rad
        self.k0_per_m2 = (p.k2_per_s / (2.0 * p.lateral_damping * v_top)) ** 2
        self.lateral_bound_m = p.heading_max_rad * p.k2_per_s / (self.k0_per_m2 * v_top)
        self._cos_max = math.cos(p.heading_max_rad)
        #: the fastest rim speed (m/s) and the half track: the model's twist is saturated at
        #: the wheels as the node's limiter saturates it (keeping the curvature), so that the
        #: law's state is what the drives are sent
        self._rim_max = lim.wheel_max_radps * r
        self._half_track = geometry.half_track_m
        self.drive_gains = p.inner_loop.drive_gains()
        self._counts = [0] * len(ACTIVITY_KEYS)
        self._reset()

    def _reset(self) -> None:
        self._v_c = 0.0
        self._w_c = 0.0
        self._park = RouteEndLatch()
        self._last: tuple[float, ...] = (0.0,) * len(INTERNAL_KEYS)

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        """Start the commanded twist at the estimate's (within limits); clear state and counts."""
        self._reset()
        self._counts = [0] * len(ACTIVITY_KEYS)
        lim = self.limits
        if math.isfinite(estimate.v_mps):
            self._v_c = min(max(estimate.v_mps, -lim.v_reverse_max_mps), lim.v_max_mps)
        if math.isfinite(estimate.omega_radps):
            w = estimate.omega_radps
            self._w_c = min(max(w, -lim.omega_max_radps), lim.omega_max_radps)

    def inv_cos(self, c: float) -> float:
        """``1/cos(phi_e)`` up to ``heading_max_rad``, fading to 0 at 90 degrees beyond it."""
        return inv_cos(c, self._cos_max)

    def lateral_term(self, ye: float) -> tuple[float, float]:
        """The lateral term ``L(y_e) = k0 Y tanh(y_e / Y)`` (rad/m: ``v_d L`` is a turn rate) and
        its slope ``dL/dy_e = k0 (1 - tanh^2)``."""
        yb = self.lateral_bound_m
        th = math.tanh(ye / yb)
        return self.k0_per_m2 * yb * th, self.k0_per_m2 * (1.0 - th * th)

    def speed_cap(self, c: float) -> float:
        """The forward speed limit where the heading error's cosine is ``c``: the top speed
        up to ``heading_max_rad``, then yielding with ``c / cos(phi_max)`` to its floor."""
        y = min(1.0, max(self.p.speed_floor, c / self._cos_max))
        return self.limits.v_max_mps * y

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        """The sliding-mode twist for this tick: the believed model under the surfaces' torques."""
        p, lim = self.p, self.limits
        h = dt_s if (dt_s > 0.0 and math.isfinite(dt_s)) else 0.0
        c, s = math.cos(ref.heading_rad), math.sin(ref.heading_rad)
        dx, dy = est.x_m - ref.x_m, est.y_m - ref.y_m
        xe, ye = c * dx + s * dy, -s * dx + c * dy
        pe = (
            wrap_angle(est.heading_rad - ref.heading_rad) if math.isfinite(est.heading_rad) else 0.0
        )
        vd, wd, ad, al = ref.v_mps, ref.omega_radps, ref.a_mps2, ref.alpha_radps2
        if self._park.check(ref.done, math.hypot(xe, ye), p.stop_radius_m):
            self._v_c = self._w_c = 0.0
            self._last = (xe, ye, pe, 1.0, *self._last[4:10], 0.0, 0.0)
            return TwistCommand(0.0, 0.0)
        if not (est.valid and math.isfinite(xe + ye + pe + vd + wd + ad + al)):
            # degrade, never raise: ramp both to zero within the envelope
            self._v_c = (
                max(0.0, self._v_c - lim.decel_max_mps2 * h)
                if self._v_c >= 0.0
                else min(0.0, self._v_c + lim.decel_max_mps2 * h)
            )
            dw = lim.alpha_max_radps2 * h
            self._w_c = 0.0 if abs(self._w_c) <= dw else self._w_c - math.copysign(dw, self._w_c)
            return TwistCommand(self._v_c, self._w_c)
        n = self._counts
        n[0] += 1
        v, w = self._v_c, self._w_c  # the model's state: the commanded twist
        cp, sp = math.cos(pe), math.sin(pe)
        xe_d = -vd + v * cp + wd * ye  # Eq. derrorvector with the commanded twist
        ye_d = v * sp - wd * xe
        pe_d = w - wd

        # x_e surface: s1' = alpha cos(phi_e) u1 + D1
        s1 = xe_d + p.k1_per_s * xe
        d1 = -ad - v * sp * pe_d + al * ye + wd * ye_d + p.k1_per_s * xe_d
        inv = self.inv_cos(cp) / self.alpha
        u_eq1 = -d1 * inv
        z1 = s1 / p.boundary1_mps
        u1 = u_eq1 - (p.q1_per_s * s1 + p.p1_mps2 * sat(z1)) * inv

        # phi_e surface with the bounded lateral term: s2' = beta u2 + D2
        lat, dlat = self.lateral_term(ye)
        s2 = pe_d + p.k2_per_s * pe + vd * lat
        d2 = -al + p.k2_per_s * pe_d + ad * lat + vd * dlat * ye_d
        u_eq2 = -d2 / self.beta
        z2 = s2 / p.boundary2_radps
        u2 = u_eq2 - (p.q2_per_s * s2 + p.p2_radps2 * sat(z2)) / self.beta

        # the believed model turns the torques into the drives' set-point twist
        acc = self.alpha * u1
        speeding_up = (v >= 0.0) == (acc >= 0.0)
        a_max = lim.accel_max_mps2 if speeding_up else lim.decel_max_mps2
        if acc > a_max or acc < -a_max:
            acc = a_max if acc > 0.0 else -a_max
            n[5] += 1
        v_cap = self.speed_cap(cp)
        v_new = v + acc * h
        if v_new > v_cap:
            # speed yields to steering (never faster than braking at the limit)
            v_new = max(v_cap, v - lim.decel_max_mps2 * h)
            if cp < self._cos_max:
                n[4] += 1
        self._v_c = min(max(v_new, -lim.v_reverse_max_mps), lim.v_max_mps)
        wdot = self.beta * u2
        if wdot > lim.alpha_max_radps2 or wdot < -lim.alpha_max_radps2:
            wdot = lim.alpha_max_radps2 if wdot > 0.0 else -lim.alpha_max_radps2
            n[6] += 1
        self._w_c = min(max(w + wdot * h, -lim.omega_max_radps), lim.omega_max_radps)
        rim = abs(self._v_c) + self._half_track * abs(self._w_c)
        if rim > self._rim_max:
            k = self._rim_max / rim
            self._v_c *= k
            self._w_c *= k
        if z1 > 1.0 or z1 < -1.0:
            n[1] += 1
        if z2 > 1.0 or z2 < -1.0:
            n[2] += 1
        if cp < self._cos_max:
            n[3] += 1
        self._last = (xe, ye, pe, 0.0, s1, s2, u1, u2, u_eq1, u_eq2, self._v_c, self._w_c)
        return TwistCommand(self._v_c, self._w_c)

    def internals(self) -> Mapping[str, float]:
        """The last step's errors, surfaces, torques and twist, by :data:`INTERNAL_KEYS`."""
        return dict(zip(INTERNAL_KEYS, self._last, strict=True))

    def activity(self) -> Mapping[str, int]:
        """Counts since the last reset: steps that ran the law (``ticks``), outside each
        boundary layer, beyond ``heading_max_rad``, with the yielding speed cap acting, with
        the acceleration or turn acceleration clipped to the chair's limits."""
        return dict(zip(ACTIVITY_KEYS, self._counts, strict=True))
