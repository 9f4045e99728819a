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

**Curvature regimes** (paper Eq. (curvature), lines 364-374, 780, 786; docs/antifragile.md
§A3).  The regime is the sign of the *planned path's* curvature, Eq. (curvature) of the
reference trajectory (``ReferenceSample.curvature_1pm``, the planner's quintic spline):
``k < 0``: *antifragile* regime, the law's *slow* dynamics, its base reaching gains;
otherwise (``k >= 0``, a straight counting as zero within ``curvature_deadband_1pm``):
*fragile* regime, the *rapid* dynamics, ``Q2``, ``P2`` raised by ``fragile_gain``.  The
planned curvature is noise-free, so the regime changes only where the path's curvature
changes sign.

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

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from controller.config import GeometryParams, LimitParams, MotorParams
from controller.tracking.envelope import (
    ENVELOPE_KEYS,
    CommandEnvelope,
    EnvelopeParams,
    errors_and_rates,
    smoothstep,
)
from controller.types import ReferenceSample, StateEstimate, Trajectory, TwistCommand
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import param

log = logging.getLogger(__name__)

#: Names of :meth:`Antifragile.internals`, in the order of its ``_last`` tuple.
INTERNAL_KEYS = (*ENVELOPE_KEYS, "curvature", "regime_fragile", "layer2_mps")

#: Names of :meth:`Antifragile.activity`'s counts, in the order of its ``_counts`` list.
ACTIVITY_KEYS = (
    "ticks",
    "regime_fragile",
    "outside_boundary1",
    "outside_boundary2",
    "l0_condition_fails",
    "regime_flips",
)


def switch(y: float, width: float) -> float:
    """The paper's ``sgn(y)``; a saturation ``sat(y / width)`` for ``width > 0``."""
    if width <= 0.0:
        return 1.0 if y > 0.0 else (-1.0 if y < 0.0 else 0.0)
    z = y / width
    return -1.0 if z < -1.0 else (1.0 if z > 1.0 else z)


class Antifragile(CommandEnvelope):
    """The paper's ANTIFRAGILE controller (see the module doc and docs/antifragile.md)."""

    name: ClassVar[str] = "antifragile"
    internal_keys: ClassVar[tuple[str, ...]] = INTERNAL_KEYS

    @dataclass(frozen=True)
    class Params(EnvelopeParams):
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
            0.03,
            unit="m/s",
            lo=0.0,
            hi=10.0,
            lo_open=True,
            doc="Phi2, boundary layer of s2: the surface's noise (widened where P2 / Phi2 "
            "would push the loop past loop_rate_max_per_s)",
        )
        loop_rate_max_per_s: float = param(
            12.0,
            unit="1/s",
            lo=1.0,
            hi=50.0,
            doc="the fastest the s2 loop may close through the drives: Q2 + P2 / Phi2 in "
            "either regime (45 deg of phase margin with a 21 rad/s drive loop and 20 ms of "
            "delay); Phi2 widens to keep it",
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
        curvature_deadband_1pm: float = param(
            0.01,
            unit="1/m",
            lo=0.0,
            hi=1.0,
            doc="a planned curvature within +-this (a radius over 100 m) counts as straight, "
            "i.e. as k >= 0: the fragile regime",
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
        heading_max_rad: float = param(
            0.6,
            unit="rad",
            lo=0.05,
            hi=1.4,
            doc="phi_max: the largest heading the bounded lateral term asks for; y_e enters s2 "
            "as Y tanh(y_e / Y) with l2 Y = lateral_speed_mps sin(phi_max)",
        )

    def __init__(
        self,
        params: Params,
        geometry: GeometryParams,
        trajectory: Trajectory,
        *,
        motor: MotorParams,
        limits: LimitParams,
    ) -> None:
        p = params
        src = "controller/gains.toml [antifragile]"
        if p.lateral_speed_mps <= p.lateral_speed_lo_mps:
            raise ConfigError(f"{src}: lateral_speed_mps must exceed lateral_speed_lo_mps")
        if p.lateral_speed_lo_mps < p.lambda0_mps + p.authority_full_mps:
            raise ConfigError(
                f"{src}: lateral_speed_lo_mps = {p.lateral_speed_lo_mps} m/s must be at least "
                f"lambda0_mps + authority_full_mps = {p.lambda0_mps + p.authority_full_mps:g} m/s "
                "(below it the manifold steers away from the path for y_e < 0)"
            )
        self._setup(p, geometry, motor, limits)
        self._vlat = p.lateral_speed_lo_mps
        self._ivlat = 1.0 / (p.lateral_speed_mps - p.lateral_speed_lo_mps)
        #: Y (m): the lateral term's bound, l2 Y = lateral_speed_mps sin(heading_max_rad), the
        #: fastest approach s2 = 0 asks for: at most phi_max of heading from the speed where
        #: the term is whole (docs/antifragile.md §A4)
        self.lateral_bound_m = p.lateral_speed_mps * math.sin(p.heading_max_rad) / p.lambda2_per_s
        self._ybound, self._iybound = self.lateral_bound_m, 1.0 / self.lateral_bound_m
        self._qmax = p.loop_rate_max_per_s
        self._slope_min = 0.1 * p.loop_rate_max_per_s
        if p.q2_per_s * p.fragile_gain > 0.9 * p.loop_rate_max_per_s:
            log.warning(
                "%s: q2_per_s * fragile_gain = %g 1/s leaves the boundary layer's slope less "
                "than a tenth of loop_rate_max_per_s = %g 1/s: the s2 loop closes faster than "
                "the drives allow",
                src,
                p.q2_per_s * p.fragile_gain,
                p.loop_rate_max_per_s,
            )
        self._counts = [0] * len(ACTIVITY_KEYS)
        self._fragile = False

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        """Start the envelope from the estimate; clear the activity counts and the regime."""
        super().reset(estimate, t_s)
        self._counts = [0] * len(ACTIVITY_KEYS)
        self._fragile = False

    def activity(self) -> Mapping[str, int]:
        """Counts since the last reset: steps that ran the law (``ticks``), in the fragile
        regime, outside each boundary layer, and where the paper's condition
        ``l0 < l2 |y_e| / |phi_e|`` fails while ``phi_e`` points away from the path (on
        ``s2 = 0`` the lateral error then does not shrink; docs/antifragile.md §A3), and the
        steps whose regime differs from the step before (``regime_flips``)."""
        return dict(zip(ACTIVITY_KEYS, self._counts, strict=True))

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        """The variable-structure law's twist for this tick, in the planned curvature's regime."""
        if (held := self._unusable(dt_s, ref, est)) is not None:
            return held
        p = self.p
        v = est.v_mps
        vd, wd, ad, al = ref.v_mps, ref.omega_radps, ref.a_mps2, ref.alpha_radps2
        xe, ye, pe, c, s, xe_d, ye_d, pe_d = errors_and_rates(ref, est)

        l0, l1 = p.lambda0_mps, p.lambda1_per_s
        sig = switch(ye, p.sign_width_m)
        kap, dkap = smoothstep((v - self._vlat) * self._ivlat)
        dkap *= self._ivlat
        l2k = p.lambda2_per_s * kap
        yt = math.tanh(ye * self._iybound)
        yb = self._ybound * yt
        dyb = 1.0 - yt * yt

        # curvature regime of the planned path (Eq. curvature)
        curv = ref.curvature_1pm
        fragile = not curv < -p.curvature_deadband_1pm
        boost = p.fragile_gain if fragile else 1.0

        s1 = xe_d + l1 * xe
        s2 = ye_d + l2k * yb + l0 * sig * pe
        z1 = s1 / p.boundary1_mps
        u1 = -p.q1_per_s * s1 - p.p1_mps2 * (z1 if -1.0 < z1 < 1.0 else (1.0 if z1 > 0 else -1.0))
        q2 = (p.q2_rest_per_s + (p.q2_per_s - p.q2_rest_per_s) * kap) * boost
        p2 = (p.p2_rest_mps2 + (p.p2_mps2 - p.p2_rest_mps2) * kap) * boost
        # the layer: the surface's noise, or wider where its slope P2 / Phi2 would close the
        # loop faster than loop_rate_max_per_s (docs/antifragile.md §A3)
        phi2 = p.boundary2_mps
        slope = self._qmax - q2
        if p2 > slope * phi2:
            phi2 = p2 / (slope if slope > self._slope_min else self._slope_min)
        z2 = s2 / phi2
        u2 = -q2 * s2 - p2 * (z2 if -1.0 < z2 < 1.0 else (1.0 if z2 > 0.0 else -1.0))
        n = self._counts
        n[0] += 1
        if fragile:
            n[1] += 1
        if fragile is not self._fragile and n[0] > 1:
            n[5] += 1
        self._fragile = fragile
        if z1 >= 1.0 or z1 <= -1.0:
            n[2] += 1
        if z2 >= 1.0 or z2 <= -1.0:
            n[3] += 1
        if sig * pe > 0.0 and l0 * abs(pe) >= l2k * abs(yb):
            n[4] += 1

        # s1' = cos(pe) a - v sin(pe) (omega - omega_d) + f1 = u1, solved for a
        n1 = u1 + ad - al * ye - wd * ye_d - l1 * xe_d + v * s * pe_d
        a_raw, gate_a = self._accel(n1, vd, v, c)

        # s2' = b2 a + D (omega - omega_d) + g2 = u2 (sgn(y_e)' dropped, as in the paper)
        D = v * c + l0 * sig
        b2 = s + p.lambda2_per_s * dkap * yb
        g2 = -al * xe - wd * xe_d + l2k * dyb * ye_d
        gate_w, _ = smoothstep((abs(D) - self._d0) * self._idband)
        kw, w0 = self._omega(gate_w, D, u2, g2, wd, pe)
        a_raw = self._priority(a_raw, w0, -kw * b2 * a_raw)
        a, vc = self._shape(a_raw, w0, kw * b2, dt_s)
        self._last = (
            xe, ye, pe, xe_d, ye_d, s1, s2, sig, D, gate_a, gate_w, a, vc, self.wc, 0.0,
            curv, float(fragile), phi2,
        )  # fmt: skip
        return TwistCommand(vc, self.wc)
