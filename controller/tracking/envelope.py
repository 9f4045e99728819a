"""ANTIFRAGILE's machinery around its manifolds: the command envelope, the fallbacks, steering priority.

``antifragile.py`` holds the paper's variable-structure law (manifolds, sign, regimes); around
it runs this machinery (docs/antifragile.md §A4, §A6):

* the errors and their rates (Eqs. errorvector, derrorvector) with the estimated twist;
* the division of ``s1'`` by ``cos(phi_e)`` blended into speed matching below a margin;
* the fallback turn rate ``omega_d - k phi_e`` where the law's ``omega`` denominator is small;
* steering priority over the acceleration it would have to compensate;
* the envelope: the chair's limits (``LimitParams``, the one envelope every law and the
  node's limiter share) on jerk, acceleration, speed, turn rate and turn acceleration,
  ``a_c`` integrated to ``v_c`` without wind-up, wheel saturation keeping the curvature;
* braking to rest at the route's end or on an unusable input, and the inner loop's design.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from controller.config import GeometryParams, LimitParams, MotorParams
from controller.inner_loop import InnerLoopDesign, InnerLoopParams, design
from controller.kinematics import TWO_PI as _TWO_PI
from controller.types import DriveGains, ReferenceSample, StateEstimate, TwistCommand
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import param, section

_PI = math.pi

#: The first names of the law's internals (its ``_last`` tuple begins with these).
ENVELOPE_KEYS = (
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
)


def smoothstep(x: float) -> tuple[float, float]:
    """C1 step 0 -> 1 on [0, 1] (``3x^2 - 2x^3``) and its derivative."""
    if x <= 0.0:
        return 0.0, 0.0
    if x >= 1.0:
        return 1.0, 0.0
    return x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x)


def errors_and_rates(
    ref: ReferenceSample, est: StateEstimate
) -> tuple[float, float, float, float, float, float, float, float]:
    """``(x_e, y_e, phi_e, cos phi_e, sin phi_e, x_e', y_e', phi_e')``: the paper's errors
    (Eq. errorvector) and their rates (Eq. derrorvector) with the estimated twist."""
    hd = ref.heading_rad
    v = est.v_mps
    vd, wd = ref.v_mps, ref.omega_radps
    cd, sd = math.cos(hd), math.sin(hd)
    dx, dy = est.x_m - ref.x_m, est.y_m - ref.y_m
    xe = cd * dx + sd * dy
    ye = -sd * dx + cd * dy
    pe = math.fmod(est.heading_rad - hd + _PI, _TWO_PI)
    pe = pe - _PI if pe > 0.0 else pe + _PI
    c, s = math.cos(pe), math.sin(pe)
    return xe, ye, pe, c, s, -vd + v * c + wd * ye, v * s - wd * xe, est.omega_radps - wd


@dataclass(frozen=True)
class EnvelopeParams:
    """The gains of ANTIFRAGILE's machinery around its manifolds (``Antifragile.Params`` adds
    the manifolds and schedules)."""

    # --- rules where the law is singular (docs/antifragile.md §4)
    cos_off: float = param(
        0.5,
        unit="1",
        lo=0.0,
        hi=1.0,
        doc="below this cos(phi_e) (60 deg) a_c is the fallback alone",
    )
    cos_full: float = param(
        0.866,
        unit="1",
        lo=0.0,
        hi=1.0,
        lo_open=True,
        doc="above this cos(phi_e) (30 deg) a_c is the law alone",
    )
    authority_off_mps: float = param(
        0.04,
        unit="m/s",
        lo=0.0,
        hi=5.0,
        doc="below this omega denominator D (|D| in antifragile), omega_c is the fallback alone",
    )
    authority_full_mps: float = param(
        0.08,
        unit="m/s",
        lo=0.0,
        hi=5.0,
        lo_open=True,
        doc="above this omega denominator D (|D| in antifragile), omega_c is the law alone",
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
        doc="a_c is cut so that compensating it in omega_c needs no more than this "
        "(at most the chair's turn-rate limit)",
    )
    # --- the drives' velocity loops, pushed when arming
    inner_loop: InnerLoopParams = section(
        InnerLoopParams, "singular-perturbation PID of the drives"
    )


class CommandEnvelope:
    """ANTIFRAGILE's machinery around its manifolds (docs/antifragile.md §A4, §A6).

    A subclass declares ``name`` and ``internal_keys`` (the names of its ``_last`` tuple,
    beginning with :data:`ENVELOPE_KEYS`) and calls :meth:`_setup` from its constructor.
    """

    name: ClassVar[str]
    internal_keys: ClassVar[tuple[str, ...]]
    p: Any
    limits: LimitParams
    vc: float
    ac: float
    wc: float
    half_track_m: float
    rim_max_mps: float

    def _setup(
        self,
        p: Any,
        geometry: GeometryParams,
        motor: MotorParams,
        limits: LimitParams,
    ) -> None:
        """Check the rules across the shared gains, design the inner loop, start at rest."""
        src = f"controller/gains.toml [{self.name}]"
        if p.cos_full <= p.cos_off:
            raise ConfigError(f"{src}: cos_full must exceed cos_off")
        if p.authority_full_mps <= p.authority_off_mps:
            raise ConfigError(f"{src}: authority_full_mps must exceed authority_off_mps")
        self.p = p
        self.motor = motor
        #: The chair's limits: the envelope of a_c, v_c, omega_c and the wheels.
        self.limits = limits
        self.half_track_m = geometry.half_track_m
        self.rim_max_mps = geometry.wheel_radius_m * limits.wheel_max_radps
        self._wp = min(p.omega_priority_radps, limits.omega_max_radps)
        self.inner: InnerLoopDesign = design(self.motor, p.inner_loop)
        #: Velocity-loop gains the node pushes to both drives when arming.
        self.drive_gains: DriveGains = self.inner.drive_gains
        self._c0, self._icband = p.cos_off, 1.0 / (p.cos_full - p.cos_off)
        self._d0 = p.authority_off_mps
        self._idband = 1.0 / (p.authority_full_mps - p.authority_off_mps)
        self.vc = self.ac = self.wc = 0.0
        self._last: tuple[float, ...] = (0.0,) * len(self.internal_keys)

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        """Start from the chair's estimated motion (at rest when tracking starts)."""
        lim = self.limits
        v = estimate.v_mps if math.isfinite(estimate.v_mps) else 0.0
        w = estimate.omega_radps if math.isfinite(estimate.omega_radps) else 0.0
        self.vc = min(max(v, -lim.v_reverse_max_mps), lim.v_max_mps)
        self.ac = 0.0
        self.wc = min(max(w, -lim.omega_max_radps), lim.omega_max_radps)
        self._last = (0.0,) * len(self.internal_keys)

    def internals(self) -> Mapping[str, float]:
        """The last step's values, named by ``internal_keys``."""
        return dict(zip(self.internal_keys, self._last, strict=True))

    def _unusable(
        self, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand | None:
        """The command when the law must not run this tick, else None.

        A bad period holds the command.  At the route's end (the reference rests for good)
        or on an unusable input, ``v_c`` and ``omega_c`` ramp to zero within the envelope
        and stay there.
        """
        if not (dt_s > 0.0 and math.isfinite(dt_s)):
            return TwistCommand(self.vc, self.wc)
        # one isfinite: a NaN or an infinity anywhere makes the sum non-finite
        total = est.x_m + est.y_m + est.heading_rad + est.v_mps + est.omega_radps + ref.x_m
        total = total + ref.y_m + ref.heading_rad + ref.v_mps + ref.omega_radps + ref.a_mps2
        if ref.done or not est.valid or not math.isfinite(total + ref.alpha_radps2):
            a, v_b, w_b = self._ramp_to_zero(dt_s)
            tail = (0.0,) * (len(self.internal_keys) - len(ENVELOPE_KEYS))
            self._last = (*self._last[:11], a, v_b, w_b, 1.0 if ref.done else 2.0, *tail)
            return TwistCommand(v_b, w_b)
        return None

    def _accel(self, n1: float, vd: float, v: float, c: float) -> tuple[float, float]:
        """``(a_c, gate)``: ``n1 / cos(phi_e)`` blended (C1) into speed matching
        ``k (v_d cos phi_e - v)`` below the ``cos(phi_e)`` margin."""
        a_fb = self.p.fallback_rate_per_s * (vd * c - v)
        gate_a, _ = smoothstep((c - self._c0) * self._icband)
        return (a_fb if gate_a == 0.0 else gate_a * n1 / c + (1.0 - gate_a) * a_fb), gate_a

    def _omega(
        self, gate_w: float, D: float, u2: float, g2: float, wd: float, pe: float
    ) -> tuple[float, float]:
        """``(kw, w0)``: the turn rate's gain on ``u2 - b2 a - g2`` and the turn rate without
        the acceleration term, blended by ``gate_w`` into the fallback ``omega_d - k phi_e``."""
        kw = gate_w / D if gate_w > 0.0 else 0.0
        return kw, wd + kw * (u2 - g2) + (1.0 - gate_w) * (-self.p.fallback_rate_per_s * pe)

    def _priority(self, a_raw: float, w0: float, wa: float) -> float:
        """Steering has priority: ``a_c`` cut so that compensating it (``wa``, the turn rate
        it needs) keeps ``|omega_c|`` within ``omega_priority`` (at most the turn-rate limit)."""
        wp = self._wp
        wt = w0 + wa
        if wt > wp or wt < -wp:
            if -wp < w0 < wp:
                a_raw *= ((wp if wa > 0.0 else -wp) - w0) / wa
            elif w0 * wa > 0.0:
                a_raw = 0.0
        return a_raw

    def _shape(self, a_raw: float, w0: float, kwb2: float, dt: float) -> tuple[float, float]:
        """``(a_c, v_c)`` after the envelope; ``omega_c = w0 - kwb2 a_c`` is ``self.wc``."""
        a = self._shape_accel(a_raw, dt)
        self._shape_omega(w0 - kwb2 * a, dt)
        return a, self._wheel_limit(self.wc)

    def _shape_accel(self, a: float, dt: float) -> float:
        """Jerk, acceleration and speed limits on ``a_c``; integrates ``v_c`` (no wind-up)."""
        lim = self.limits
        a0, v0 = self.ac, self.vc
        da = lim.jerk_max_mps3 * dt
        a = min(max(a, a0 - da), a0 + da)
        speeding_up = (v0 >= 0.0 and a > 0.0) or (v0 <= 0.0 and a < 0.0)
        a_max = lim.accel_max_mps2 if speeding_up else lim.decel_max_mps2
        a = min(max(a, -a_max), a_max)
        v = v0 + a * dt
        if v > lim.v_max_mps or v < -lim.v_reverse_max_mps:
            v = min(max(v, -lim.v_reverse_max_mps), lim.v_max_mps)
            a = (v - v0) / dt
        self.vc, self.ac = v, a
        return a

    def _shape_omega(self, w: float, dt: float) -> float:
        lim = self.limits
        dw = lim.alpha_max_radps2 * dt
        w = min(max(w, self.wc - dw), self.wc + dw)
        w = min(max(w, -lim.omega_max_radps), lim.omega_max_radps)
        self.wc = w
        return w

    def _wheel_limit(self, w: float) -> float:
        """Scale ``v_c`` and ``omega_c`` together if a wheel would exceed its limit."""
        v = self.vc
        rim = abs(v) + self.half_track_m * abs(w)
        if rim > self.rim_max_mps:
            k = self.rim_max_mps / rim
            self.vc, self.wc = v * k, w * k
        return self.vc

    def _ramp_to_zero(self, dt: float) -> tuple[float, float, float]:
        """One step of ``v_c``, ``omega_c`` towards zero within the envelope, then zero.

        Returns ``(a_c, v_c, omega_c)``.
        """
        lim = self.limits
        v0, a0 = self.vc, self.ac
        a = -v0 / dt
        a = min(max(a, a0 - lim.jerk_max_mps3 * dt), a0 + lim.jerk_max_mps3 * dt)
        a = min(max(a, -lim.decel_max_mps2), lim.decel_max_mps2)
        v = v0 + a * dt
        if v * v0 <= 0.0 or abs(v) < 1e-4:  # reached or crossed zero
            v, a = 0.0, 0.0
        dw = lim.alpha_max_radps2 * dt
        w = 0.0 if abs(self.wc) <= dw else self.wc - math.copysign(dw, self.wc)
        self.vc, self.ac, self.wc = v, a, w
        return a, v, w
