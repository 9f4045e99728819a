"""ANTIFRAGILE: the paper's variable-structure law, its curvature regimes and singular-perturbation PID.

Errors in the paper's convention (Eq. errorvector) and their rates (Eq. derrorvector), with
the estimated ``v``, ``omega`` and the reference's ``v_d, omega_d, a_d, alpha_d``.  The
paper's manifolds (Eq. trackingsurfaces) and reaching law (Eq. controllawmanifold)::

    s1 = x_e' + l1 x_e                             s2 = y_e' + l2 y_e + l0 sgn(y_e) phi_e
    s' = -Q s - P sat(s / Phi)                     (sgn(s) -> sat(s/Phi), as the paper allows)

solved for the acceleration and the turn rate (Eqs. controllawacc, controllawomega)::

    a_c     = [u1 + a_d - alpha_d y_e - omega_d y_e' - l1 x_e' + v sin(pe) (omega - omega_d)] / cos(pe)
    omega_c = omega_d + [u2 - sin(pe) a_c + alpha_d x_e + omega_d x_e' - l2 y_e'] / D
    D       = v cos(pe) + l0 sgn(y_e)

**Variable structure at the scale of the error.**  ``sgn(y_e)`` is the switch itself: a
saturation ``sat(y_e / w)`` with ``w = sign_width_m`` = 1 mm, below the chair's estimate
noise, so it is +-1 wherever the lateral error is measurable (``w = 0`` is the hard sign).
Its derivative is dropped, as the paper drops it (``sgn`` is piecewise constant): ``s2``
jumps by ``2 l0 phi_e`` when ``y_e`` changes side.  There is no speed blend of the sign:
``D`` is the paper's at every speed.

**Curvature regimes** (paper lines 364, 373-374, 780, 786; the paper gives no equation,
docs/antifragile.md §2 states this reading).  The regime is the sign of the curvature,
by Eq. (curvature), of the closed-loop solution: the lateral deviation ``|y_e|`` as a
function of time, ``k = sgn(y_e) y_e'' / (1 + y_e'^2)``.  ``k < 0`` (the deviation bends
back: concave): *antifragile* regime, the law's *slow* dynamics, its base reaching gains.
``k >= 0`` (the deviation grows at a growing or constant rate): *fragile* regime, the
*rapid* dynamics, ``Q2``, ``P2`` raised by ``fragile_gain`` until the deviation bends back.

Rules the paper's law needs where it is singular (each tested; docs/antifragile.md §4):
the lateral term ``l2 y_e`` and ``Q2``, ``P2`` fade in with speed, from a speed above
``l0`` (at rest the chair cannot reduce ``y_e`` and the paper's law would spin it; below
``v = l0`` its manifold steers away from the path for ``y_e < 0``), ``y_e`` enters ``s2`` bounded as
``Y tanh(y_e / Y)``, the divisions by ``cos(pe)`` and ``D`` blend into well-posed
fallbacks below a margin of ``cos(pe)`` and ``|D|``, steering has priority over the
acceleration it would have to compensate, and at the route's end or on an unusable
input both commands ramp to zero.  The inner loop is the singular-perturbation PID of
``controller/inner_loop.py`` (pushed when arming).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from controller.config import GeometryParams, MotorParams, load_config
from controller.inner_loop import InnerLoopDesign, InnerLoopParams, design
from controller.kinematics import TWO_PI as _TWO_PI
from controller.tracking.antifragile_smooth import CommandEnvelope, smoothstep
from controller.types import DriveGains, ReferenceSample, StateEstimate, Trajectory, TwistCommand
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import param, section

_PI = math.pi

#: Names of :meth:`Antifragile.internals`, in the order of its ``_last`` tuple.
INTERNAL_KEYS = (
    "x_e_m",
    "y_e_m",
    "phi_e_rad",
    "x_e_dot_mps",
    "y_e_dot_mps",
    "s1_mps",
    "s2_mps",
    "sign",
    "authority_mps",
    "gate_accel",
    "gate_omega",
    "a_c_mps2",
    "v_c_mps",
    "omega_c_radps",
    "braking",
    "curvature",
    "regime_fragile",
)


def switch(y: float, width: float) -> float:
    """The paper's ``sgn(y)``; a saturation ``sat(y / width)`` for ``width > 0``."""
    if width <= 0.0:
        return 1.0 if y > 0.0 else (-1.0 if y < 0.0 else 0.0)
    z = y / width
    return -1.0 if z < -1.0 else (1.0 if z > 1.0 else z)


def solution_curvature(ye: float, ye_d: float, ye_dd: float) -> float:
    """Eq. (curvature) of the graph ``t -> |y_e(t)|``: ``sgn(y_e) y_e'' / (1 + y_e'^2)``.

    With ``x = t`` (``x' = 1``, ``x'' = 0``) the paper's expression is ``y'' / (1 + y'^2)``.
    Negative: the deviation bends back (antifragile regime).
    """
    sg = 1.0 if ye > 0.0 else (-1.0 if ye < 0.0 else 0.0)
    return sg * ye_dd / (1.0 + ye_d * ye_d)


class Antifragile(CommandEnvelope):
    """The paper's ANTIFRAGILE controller (see the module doc and docs/antifragile.md)."""

    name: ClassVar[str] = "antifragile"

    @dataclass(frozen=True)
    class Params:
        # --- sliding manifolds (paper Eq. trackingsurfaces)
        lambda1_per_s: float = param(
            2.0, unit="1/s", lo=0.0, hi=50.0, lo_open=True, doc="l1: x_e decays at l1 on s1 = 0"
        )
        lambda2_per_s: float = param(
            2.0, unit="1/s", lo=0.0, hi=50.0, lo_open=True, doc="l2: y_e decays at l2 on s2 = 0"
        )
        lambda0_mps: float = param(
            0.2,
            unit="m/s",
            lo=0.0,
            hi=5.0,
            lo_open=True,
            doc="l0: heading coupling l0 sgn(y_e) phi_e in s2",
        )
        sign_width_m: float = param(
            0.001,
            unit="m",
            lo=0.0,
            hi=0.01,
            doc="w: sgn(y_e) is sat(y_e / w), a switch at the error's scale (0: the hard sign)",
        )
        # --- reaching law s' = -Q s - P sat(s / Phi) (paper Eq. controllawmanifold)
        q1_per_s: float = param(2.0, unit="1/s", lo=0.0, hi=100.0, doc="Q1, proportional rate")
        p1_mps2: float = param(0.2, unit="m/s^2", lo=0.0, hi=20.0, doc="P1, constant rate")
        boundary1_mps: float = param(
            0.05, unit="m/s", lo=0.0, hi=10.0, lo_open=True, doc="Phi1, boundary layer of s1"
        )
        q2_per_s: float = param(
            2.0, unit="1/s", lo=0.0, hi=100.0, doc="Q2 when moving, antifragile regime"
        )
        p2_mps2: float = param(
            0.4, unit="m/s^2", lo=0.0, hi=20.0, doc="P2 when moving, antifragile regime"
        )
        boundary2_mps: float = param(
            0.08, unit="m/s", lo=0.0, hi=10.0, lo_open=True, doc="Phi2, boundary layer of s2"
        )
        q2_rest_per_s: float = param(
            0.6, unit="1/s", lo=0.0, hi=100.0, doc="Q2 at rest (in-place turns)"
        )
        p2_rest_mps2: float = param(
            0.1, unit="m/s^2", lo=0.0, hi=20.0, doc="P2 at rest (in-place turns)"
        )
        # --- curvature regimes (docs/antifragile.md §2)
        fragile_gain: float = param(
            2.0,
            unit="1",
            lo=1.0,
            hi=20.0,
            doc="Q2, P2 are this many times larger in the fragile regime (rapid dynamics)",
        )
        # --- rules where the paper's law is singular (docs/antifragile.md §4)
        lateral_speed_lo_mps: float = param(
            0.3,
            unit="m/s",
            lo=0.0,
            hi=5.0,
            doc="below this speed l2 is off and Q2, P2 keep their rest values (must exceed "
            "lambda0_mps + authority_full_mps: D = v - l0 crosses 0 below it for y_e < 0)",
        )
        lateral_speed_mps: float = param(
            0.6,
            unit="m/s",
            lo=0.0,
            hi=5.0,
            lo_open=True,
            doc="l2, Q2 and P2 reach their full values at this speed",
        )
        lateral_bound_m: float = param(
            0.1,
            unit="m",
            lo=0.0,
            hi=10.0,
            lo_open=True,
            doc="Y: y_e enters s2 as Y tanh(y_e / Y), bounding the demanded approach to l2 Y",
        )
        cos_off: float = param(
            0.5, unit="1", lo=0.0, hi=1.0, doc="below this cos(phi_e) a_c is the fallback alone"
        )
        cos_full: float = param(
            0.866,
            unit="1",
            lo=0.0,
            hi=1.0,
            lo_open=True,
            doc="above this cos(phi_e) a_c is the paper's law alone",
        )
        authority_off_mps: float = param(
            0.04, unit="m/s", lo=0.0, hi=5.0, doc="below this |D|, omega_c is the fallback alone"
        )
        authority_full_mps: float = param(
            0.08,
            unit="m/s",
            lo=0.0,
            hi=5.0,
            lo_open=True,
            doc="above this |D|, omega_c is the paper's law alone",
        )
        fallback_rate_per_s: float = param(
            1.5,
            unit="1/s",
            lo=0.0,
            hi=50.0,
            doc="k of the fallbacks a = k (v_d cos phi_e - v), omega = omega_d - k phi_e",
        )
        omega_priority_radps: float = param(
            1.5,
            unit="rad/s",
            lo=0.1,
            hi=10.0,
            doc="a_c is cut so that compensating it in omega_c needs no more than this",
        )
        # --- command envelope, inside the loop's limits (controller/config.py LimitParams)
        v_max_mps: float = param(1.4, unit="m/s", lo=0.1, hi=3.0, doc="forward speed")
        v_reverse_max_mps: float = param(0.3, unit="m/s", lo=0.0, hi=3.0, doc="reverse speed")
        accel_max_mps2: float = param(0.9, unit="m/s^2", lo=0.05, hi=5.0, doc="speeding up")
        decel_max_mps2: float = param(1.4, unit="m/s^2", lo=0.05, hi=5.0, doc="slowing down")
        jerk_max_mps3: float = param(15.0, unit="m/s^3", lo=0.1, hi=1e4, doc="change of a_c")
        omega_max_radps: float = param(1.8, unit="rad/s", lo=0.1, hi=10.0, doc="turn rate")
        alpha_max_radps2: float = param(5.0, unit="rad/s^2", lo=0.1, hi=1e4, doc="turn accel")
        wheel_max_radps: float = param(
            5.2, unit="rad/s", lo=0.5, hi=50.0, doc="wheel speed (v, omega scaled together)"
        )
        # --- the drives' velocity loops, pushed when arming
        inner_loop: InnerLoopParams = section(
            InnerLoopParams, "singular-perturbation PID of the drives"
        )

    def __init__(
        self,
        params: Params,
        geometry: GeometryParams,
        trajectory: Trajectory,
        *,
        motor: MotorParams | None = None,
    ) -> None:
        p = params
        src = "controller/gains.toml [antifragile]"
        if p.cos_full <= p.cos_off:
            raise ConfigError(f"{src}: cos_full must exceed cos_off")
        if p.authority_full_mps <= p.authority_off_mps:
            raise ConfigError(f"{src}: authority_full_mps must exceed authority_off_mps")
        if p.lateral_speed_mps <= p.lateral_speed_lo_mps:
            raise ConfigError(f"{src}: lateral_speed_mps must exceed lateral_speed_lo_mps")
        if p.lateral_speed_lo_mps < p.lambda0_mps + p.authority_full_mps:
            raise ConfigError(
                f"{src}: lateral_speed_lo_mps = {p.lateral_speed_lo_mps} m/s must be at least "
                f"lambda0_mps + authority_full_mps = {p.lambda0_mps + p.authority_full_mps:g} m/s "
                "(below it the manifold steers away from the path for y_e < 0)"
            )
        self.p = p
        self.half_track_m = geometry.half_track_m
        self.rim_max_mps = geometry.wheel_radius_m * p.wheel_max_radps
        self.motor = motor if motor is not None else load_config().motor
        self.inner: InnerLoopDesign = design(self.motor, p.inner_loop)
        #: Velocity-loop gains the node pushes to both drives when arming.
        self.drive_gains: DriveGains = self.inner.drive_gains
        self._vlat = p.lateral_speed_lo_mps
        self._ivlat = 1.0 / (p.lateral_speed_mps - p.lateral_speed_lo_mps)
        self._ybound, self._iybound = p.lateral_bound_m, 1.0 / p.lateral_bound_m
        self._c0, self._icband = p.cos_off, 1.0 / (p.cos_full - p.cos_off)
        self._d0 = p.authority_off_mps
        self._idband = 1.0 / (p.authority_full_mps - p.authority_off_mps)
        self.vc = self.ac = self.wc = 0.0
        self._last: tuple[float, ...] = (0.0,) * len(INTERNAL_KEYS)

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        """Start from the chair's estimated motion (at rest when tracking starts)."""
        p = self.p
        v = estimate.v_mps if math.isfinite(estimate.v_mps) else 0.0
        w = estimate.omega_radps if math.isfinite(estimate.omega_radps) else 0.0
        self.vc = min(max(v, -p.v_reverse_max_mps), p.v_max_mps)
        self.ac = 0.0
        self.wc = min(max(w, -p.omega_max_radps), p.omega_max_radps)
        self._last = (0.0,) * len(INTERNAL_KEYS)

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        p = self.p
        x, y, h = est.x_m, est.y_m, est.heading_rad
        v, w = est.v_mps, est.omega_radps
        xd, yd, hd = ref.x_m, ref.y_m, ref.heading_rad
        vd, wd, ad, al = ref.v_mps, ref.omega_radps, ref.a_mps2, ref.alpha_radps2
        if not (dt_s > 0.0 and math.isfinite(dt_s)):
            return TwistCommand(self.vc, self.wc)
        if (
            ref.done
            or not est.valid
            or not math.isfinite(x + y + h + v + w + xd + yd + hd + vd + wd + ad + al)
        ):
            a, v_b, w_b = self._ramp_to_zero(dt_s)
            self._last = (*self._last[:11], a, v_b, w_b, 1.0 if ref.done else 2.0, 0.0, 0.0)
            return TwistCommand(v_b, w_b)

        cd, sd = math.cos(hd), math.sin(hd)
        dx, dy = x - xd, y - yd
        xe = cd * dx + sd * dy
        ye = -sd * dx + cd * dy
        pe = math.fmod(h - hd + _PI, _TWO_PI)
        pe = pe - _PI if pe > 0.0 else pe + _PI
        c, s = math.cos(pe), math.sin(pe)
        xe_d = -vd + v * c + wd * ye
        ye_d = v * s - wd * xe
        pe_d = w - wd

        l0, l1 = p.lambda0_mps, p.lambda1_per_s
        sig = switch(ye, p.sign_width_m)
        kap, dkap = smoothstep((v - self._vlat) * self._ivlat)
        dkap *= self._ivlat
        l2k = p.lambda2_per_s * kap
        yt = math.tanh(ye * self._iybound)
        yb = self._ybound * yt
        dyb = 1.0 - yt * yt

        # curvature regime of the closed-loop solution (a: the last commanded acceleration)
        ye_dd = self.ac * s + v * c * pe_d - al * xe - wd * xe_d
        curv = solution_curvature(ye, ye_d, ye_dd)
        fragile = curv >= 0.0
        boost = p.fragile_gain if fragile else 1.0

        s1 = xe_d + l1 * xe
        s2 = ye_d + l2k * yb + l0 * sig * pe
        z1 = s1 / p.boundary1_mps
        z2 = s2 / p.boundary2_mps
        u1 = -p.q1_per_s * s1 - p.p1_mps2 * (z1 if -1.0 < z1 < 1.0 else (1.0 if z1 > 0 else -1.0))
        q2 = (p.q2_rest_per_s + (p.q2_per_s - p.q2_rest_per_s) * kap) * boost
        p2 = (p.p2_rest_mps2 + (p.p2_mps2 - p.p2_rest_mps2) * kap) * boost
        u2 = -q2 * s2 - p2 * (z2 if -1.0 < z2 < 1.0 else (1.0 if z2 > 0.0 else -1.0))

        # s1' = cos(pe) a - v sin(pe) (omega - omega_d) + f1 = u1, solved for a
        n1 = u1 + ad - al * ye - wd * ye_d - l1 * xe_d + v * s * pe_d
        a_fb = p.fallback_rate_per_s * (vd * c - v)
        gate_a, _ = smoothstep((c - self._c0) * self._icband)
        a_raw = a_fb if gate_a == 0.0 else gate_a * n1 / c + (1.0 - gate_a) * a_fb

        # s2' = b2 a + D (omega - omega_d) + g2 = u2 (sgn(y_e)' dropped, as in the paper)
        D = v * c + l0 * sig
        b2 = s + p.lambda2_per_s * dkap * yb
        g2 = -al * xe - wd * xe_d + l2k * dyb * ye_d
        gate_w, _ = smoothstep((abs(D) - self._d0) * self._idband)
        kw = gate_w / D if gate_w > 0.0 else 0.0
        w0 = wd + kw * (u2 - g2) + (1.0 - gate_w) * (-p.fallback_rate_per_s * pe)
        wa = -kw * b2 * a_raw
        wt = w0 + wa
        wp = p.omega_priority_radps
        if wt > wp or wt < -wp:
            if -wp < w0 < wp:
                a_raw *= ((wp if wa > 0.0 else -wp) - w0) / wa
            elif w0 * wa > 0.0:
                a_raw = 0.0
        a = self._shape_accel(a_raw, dt_s)
        self._shape_omega(w0 - kw * b2 * a, dt_s)
        vc = self._wheel_limit(self.wc)
        self._last = (
            xe, ye, pe, xe_d, ye_d, s1, s2, sig, D, gate_a, gate_w, a, vc, self.wc, 0.0,
            curv, float(fragile),
        )  # fmt: skip
        return TwistCommand(vc, self.wc)

    def internals(self) -> Mapping[str, float]:
        return dict(zip(INTERNAL_KEYS, self._last, strict=True))
