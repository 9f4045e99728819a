"""ANTIFRAGILE-SMOOTH: the paper's sliding-mode law made smooth, with the singular-perturbation PID.

This was the project's ANTIFRAGILE before the paper-faithful one (``antifragile.py``) replaced
it; it stays available as ``--controller antifragile-smooth``.  Its ``sgn(y_e)`` is
``tanh(y_e / 2 cm)`` (about 0.24 at the route's 4.8 mm y_e RMSE: a smooth term, not a
switch), a blend chi(v) pushes the coupling sign to +1 below 0.8 m/s, and it has no
curvature-regime component.

Errors in the paper's convention (controller/types.py, Eq. errorvector): actual minus
desired, in the desired frame.  With the chair's estimated ``v``, ``omega`` and the
reference's ``v_d, omega_d, a_d, alpha_d``::

    xe' = -v_d + v cos(pe) + omega_d ye            ye' = v sin(pe) - omega_d xe
    s1  = xe' + l1 xe                              s2  = ye' + l2 ye + l0 sgn(ye) pe
    s'  = -Q s - P sat(s / Phi)                    (reaching law with boundary layer Phi)

Solving ``s1'`` for the acceleration and ``s2'`` for the turn rate, as the paper's
Eqs. (controllawacc, controllawomega) do (``b2``, ``g2`` collect the known terms)::

    a_c     = [u1 + a_d - alpha_d ye - omega_d ye' - l1 xe' + v sin(pe) (omega - omega_d)] / cos(pe)
    omega_c = omega_d + [u2 - b2 a_c - g2] / D,         D = v cos(pe) + l0 sgn(ye)

``a_c`` is integrated to ``v_c`` here, inside an envelope set within the loop's limits, so
the limiter never clips and nothing winds up.  Rules for the law's hazards (every term is
derived in docs/antifragile.md):

1. ``sgn(ye)`` in ``s2`` is ``tanh(ye / w)``; its derivative enters ``s2'`` exactly.
2. Speed schedules, both C1 in the estimated speed ``v``: the coupling's sign is
   ``chi(v) tanh(ye/w) + 1 - chi(v)`` (+1 at low speed, the paper's above
   ``sign_speed_hi``); ``l2`` fades in as ``kappa(v) l2`` and ``Q2``, ``P2`` move from
   their gentle rest values to their moving ones with ``kappa``.  So ``D = l0 > 0`` at rest,
   ``D`` never changes sign at forward speed for moderate heading errors (checked at
   configure time), the manifold is stable at every speed (the paper's is not for
   ``ye < 0`` below ``v = l0``), and at rest the chair aligns its heading without spinning
   after lateral errors it cannot reduce standing still.
3. ``ye`` enters ``s2`` as ``Y tanh(ye / Y)``: the demanded approach speed is bounded.
4. The divisions by ``cos(pe)`` and ``D`` are blended (C1) into well-posed fallbacks below
   a margin: speed matching ``a = k (v_d cos pe - v)``, heading alignment
   ``omega = omega_d - k pe``.
5. Steering has priority: ``a_c`` is cut so that compensating it needs at most
   ``omega_priority`` of turn rate.
6. When the reference is done (route end), or the estimate is unusable, ``v_c`` and
   ``omega_c`` ramp to zero within the envelope and stay exactly zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from controller.config import GeometryParams, MotorParams
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

#: Names of :meth:`AntifragileSmooth.internals`, in the order of its ``_last`` tuple.
INTERNAL_KEYS = ENVELOPE_KEYS


class AntifragileSmooth(CommandEnvelope):
    """The paper's ANTIFRAGILE controller (see the module doc and docs/antifragile.md)."""

    name: ClassVar[str] = "antifragile-smooth"
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
            0.25,
            unit="m/s",
            lo=0.0,
            hi=5.0,
            lo_open=True,
            doc="l0: heading coupling l0 sgn(y_e) phi_e in s2",
        )
        # --- reaching law s' = -Q s - P sat(s / Phi) (paper Eq. controllawmanifold)
        q1_per_s: float = param(2.0, unit="1/s", lo=0.0, hi=100.0, doc="Q1, proportional rate")
        q2_per_s: float = param(
            2.0, unit="1/s", lo=0.0, hi=100.0, doc="Q2, proportional rate when moving"
        )
        q2_rest_per_s: float = param(
            0.6, unit="1/s", lo=0.0, hi=100.0, doc="Q2 at rest (in-place turns)"
        )
        p1_mps2: float = param(0.2, unit="m/s^2", lo=0.0, hi=20.0, doc="P1, constant rate")
        p2_mps2: float = param(
            0.4, unit="m/s^2", lo=0.0, hi=20.0, doc="P2, constant rate when moving"
        )
        p2_rest_mps2: float = param(
            0.1, unit="m/s^2", lo=0.0, hi=20.0, doc="P2 at rest (in-place turns)"
        )
        boundary1_mps: float = param(
            0.05, unit="m/s", lo=0.0, hi=10.0, lo_open=True, doc="Phi1, boundary layer of s1"
        )
        boundary2_mps: float = param(
            0.08, unit="m/s", lo=0.0, hi=10.0, lo_open=True, doc="Phi2, boundary layer of s2"
        )
        # --- hazard rules (docs/antifragile.md, "Hazards")
        sign_width_m: float = param(
            0.02, unit="m", lo=0.0, hi=1.0, lo_open=True, doc="w: sgn(y_e) is tanh(y_e / w)"
        )
        sign_speed_lo_mps: float = param(
            0.3,
            unit="m/s",
            lo=0.0,
            hi=5.0,
            doc="below this speed the coupling sign in s2 is +1",
        )
        sign_speed_hi_mps: float = param(
            0.8,
            unit="m/s",
            lo=0.0,
            hi=5.0,
            lo_open=True,
            doc="above this speed the coupling sign in s2 is the paper's sgn(y_e)",
        )
        lateral_speed_mps: float = param(
            0.3,
            unit="m/s",
            lo=0.0,
            hi=5.0,
            lo_open=True,
            doc="l2, Q2 and P2 move from their rest values to their full ones by this speed",
        )
        lateral_bound_m: float = param(
            0.1,
            unit="m",
            lo=0.0,
            hi=10.0,
            lo_open=True,
            doc="Y: y_e enters s2 as Y tanh(y_e / Y), bounding the demanded approach to l2 Y",
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
        self._setup(p, geometry, motor)
        _validate(p)
        # flat copies for the tick
        self._l1, self._l2, self._l0 = p.lambda1_per_s, p.lambda2_per_s, p.lambda0_mps
        self._q1, self._p1 = p.q1_per_s, p.p1_mps2
        self._q2r, self._dq2 = p.q2_rest_per_s, p.q2_per_s - p.q2_rest_per_s
        self._p2r, self._dp2 = p.p2_rest_mps2, p.p2_mps2 - p.p2_rest_mps2
        self._ib1, self._ib2 = 1.0 / p.boundary1_mps, 1.0 / p.boundary2_mps
        self._iw = 1.0 / p.sign_width_m
        self._vlo = p.sign_speed_lo_mps
        self._ivband = 1.0 / (p.sign_speed_hi_mps - p.sign_speed_lo_mps)
        self._ivlat = 1.0 / p.lateral_speed_mps
        self._ybound, self._iybound = p.lateral_bound_m, 1.0 / p.lateral_bound_m

    # ------------------------------------------------------------------ protocol

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        # rule 6: route end (the reference rests for good) or no usable input: brake, hold
        if (held := self._unusable(dt_s, ref, est)) is not None:
            return held
        v = est.v_mps
        vd, wd, ad, al = ref.v_mps, ref.omega_radps, ref.a_mps2, ref.alpha_radps2
        # errors, paper Eq. (errorvector), and their rates, Eq. (derrorvector)
        xe, ye, pe, c, s, xe_d, ye_d, pe_d = errors_and_rates(ref, est)

        # rules 1-3: smooth sign, speed schedules, bounded lateral error
        l0, l1, l2 = self._l0, self._l1, self._l2
        th = math.tanh(ye * self._iw)
        dth = (1.0 - th * th) * self._iw  # d tanh / d ye
        chi, dchi = smoothstep((v - self._vlo) * self._ivband)
        dchi *= self._ivband  # d chi / d v
        sig = chi * th + 1.0 - chi
        kap, dkap = smoothstep(v * self._ivlat)
        dkap *= self._ivlat  # d kappa / d v
        l2k = l2 * kap
        yt = math.tanh(ye * self._iybound)
        yb = self._ybound * yt  # Y tanh(ye / Y)
        dyb = 1.0 - yt * yt  # d yb / d ye

        # surfaces and reaching law
        s1 = xe_d + l1 * xe
        s2 = ye_d + l2k * yb + l0 * sig * pe
        z1 = s1 * self._ib1
        z2 = s2 * self._ib2
        u1 = -self._q1 * s1 - self._p1 * (z1 if -1.0 < z1 < 1.0 else (1.0 if z1 > 0.0 else -1.0))
        q2 = self._q2r + self._dq2 * kap  # reaching gains scheduled like l2 (rule 2)
        p2 = self._p2r + self._dp2 * kap
        u2 = -q2 * s2 - p2 * (z2 if -1.0 < z2 < 1.0 else (1.0 if z2 > 0.0 else -1.0))

        # s1' = cos(pe) a - v sin(pe) (omega - omega_d) + f1 = u1, solved for a (rule 4)
        n1 = u1 + ad - al * ye - wd * ye_d - l1 * xe_d + v * s * pe_d
        a_raw, gate_a = self._accel(n1, vd, v, c)

        # s2' = b2 a + D (omega - omega_d) + g2 = u2, solved for omega (rule 4)
        D = v * c + l0 * sig
        b2 = s + l0 * pe * dchi * (th - 1.0) + l2 * dkap * yb
        g2 = -al * xe - wd * xe_d + (l2k * dyb + l0 * pe * chi * dth) * ye_d
        gate_w, _ = smoothstep((D - self._d0) * self._idband)  # D, not |D|: see rule 2
        kw, w0 = self._omega(gate_w, D, u2, g2, wd, pe)
        # rule 5: steering has priority over the acceleration it would have to compensate
        a_raw = self._priority(a_raw, w0, -kw * b2 * a_raw)
        a, vc = self._shape(a_raw, w0, kw * b2, dt_s)
        self._last = (
            xe, ye, pe, xe_d, ye_d, s1, s2, sig, D, gate_a, gate_w, a, vc, self.wc, 0.0,
        )  # fmt: skip
        return TwistCommand(vc, self.wc)


def _validate(p: AntifragileSmooth.Params) -> None:
    """Rules across this law's parameters that per-key bounds cannot state (configure time;
    those of the shared gains: :meth:`CommandEnvelope._setup`)."""
    src = "controller/gains.toml [antifragile-smooth]"
    if p.sign_speed_hi_mps <= p.sign_speed_lo_mps:
        raise ConfigError(f"{src}: sign_speed_hi_mps must exceed sign_speed_lo_mps")
    worst_v, worst = min_authority(p)
    if worst < p.authority_full_mps:
        raise ConfigError(
            f"{src}: with lambda0_mps = {p.lambda0_mps} the omega denominator falls to "
            f"{worst:.3f} m/s at {worst_v:.2f} m/s for y_e < 0 (below authority_full_mps = "
            f"{p.authority_full_mps}); raise sign_speed_lo_mps/sign_speed_hi_mps or lower "
            "lambda0_mps"
        )


def min_authority(p: AntifragileSmooth.Params, samples: int = 600) -> tuple[float, float]:
    """Smallest ``D = v + l0 (1 - 2 chi(v))`` (``ye << 0``, ``pe = 0``) over forward speeds.

    Returns ``(v, D)`` at the minimum.  Above ``sign_speed_hi`` ``D = v - l0`` only grows.
    """
    band = p.sign_speed_hi_mps - p.sign_speed_lo_mps
    best = (0.0, math.inf)
    for i in range(samples + 1):
        v = p.sign_speed_hi_mps * i / samples
        chi, _ = smoothstep((v - p.sign_speed_lo_mps) / band)
        d = v + p.lambda0_mps * (1.0 - 2.0 * chi)
        if d < best[1]:
            best = (v, d)
    return best
