"""Does the chair obey, do what the host commanded?  The host's plausibility check, the
defence that also works with stock drives.

Any node on the bus can send a drive a setpoint.  Authentication (``dbc.secoc``) stops that
where the drives check MACs; a stock ODrive cannot.  :class:`ObedienceMonitor` checks, every
tick, the effect instead of the frames:

* **each wheel**: its measured speed (the drive's encoder estimate) must lie within the span
  ``[min, max]`` of the speeds the host commanded that wheel over the last
  ``obey_window_s``, widened by ``obey_margin_revps``.  The host's own commands pass its limiter
  (acceleration, jerk), so a drive's velocity loop that follows them stays inside that span;
  a wheel driven by somebody else's setpoints, a drive that does not follow (stuck, torque
  lost) or one that decodes the host's frames with another scale leaves it;
* **the chair**: its speed and yaw rate from the measured wheel speeds must stay within the
  host's own limits (``limits.v_max_mps``, ``v_reverse_max_mps``, ``omega_max_radps``) plus a
  margin.

A divergence that lasts ``obey_time_s`` is reported once; the loop answers with a
coordinated, latched stop (Estop to both drives, reason ``DISOBEYED``).  After the stop it
goes on watching (:meth:`moving`): a wheel that turns again is stopped again.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Collection

from controller.config import GeometryParams, LimitParams, SafetyParams
from controller.link import DriveLink
from dbc.codec import DRIVES, Node


class ObedienceMonitor:
    """Compares measured wheel and chair motion with what the host commanded and allows."""

    def __init__(
        self,
        params: SafetyParams,
        limits: LimitParams,
        geometry: GeometryParams,
        period_ns: int,
    ) -> None:
        self.p = params
        n = max(1, round(params.obey_window_s * 1e9 / period_ns))
        self._hist: dict[Node, deque[float]] = {node: deque(maxlen=n) for node in DRIVES}
        self._pi_r = math.pi * geometry.wheel_radius_m
        self._b = geometry.half_track_m
        self._v_hi = limits.v_max_mps + params.twist_margin_mps
        self._v_lo = -(limits.v_reverse_max_mps + params.twist_margin_mps)
        self._w_hi = limits.omega_max_radps + params.twist_margin_radps
        self._hold_ns = round(params.obey_time_s * 1e9)
        self._since_ns: int | None = None
        self._moving_since_ns: int | None = None
        self.detail = ""
        #: Largest distance of a wheel's speed outside its commanded span seen while checking
        #: (rev/s; the margin is ``obey_margin_revps``): how close a run came to a trip.
        self.worst_revps = 0.0
        #: Largest measured chair speed and yaw-rate magnitude seen while checking.
        self.peak_v_mps = 0.0
        self.peak_omega_radps = 0.0

    def commanded(self, left_revps: float, right_revps: float) -> None:
        """Record the setpoints sent in this tick."""
        self._hist[Node.LEFT].append(left_revps)
        self._hist[Node.RIGHT].append(right_revps)

    def reset(self) -> None:
        """Restart the divergence timer: a divergence must last ``obey_time_s`` again."""
        self._since_ns = None

    def _divergence(self, link: DriveLink) -> str:
        m = self.p.obey_margin_revps
        meas: dict[Node, float] = {}
        for node in DRIVES:
            v = link.drives[node].vel_revps
            h = self._hist[node]
            if not math.isfinite(v) or not h:
                return ""  # no feedback or no command yet: the staleness checks' business
            meas[node] = v
            lo, hi = min(h), max(h)
            dev = max(v - hi, lo - v)
            if dev > self.worst_revps:
                self.worst_revps = dev
            if dev > m:
                return (
                    f"wheel {node.name} turns at {v:.3f} rev/s, outside what the host "
                    f"commanded over {self.p.obey_window_s:g} s [{lo:.3f}, {hi:.3f}] "
                    f"+- {m:g} rev/s"
                )
        left, right = meas[Node.LEFT], meas[Node.RIGHT]
        v_mps = self._pi_r * (left + right)
        w_radps = self._pi_r * (right - left) / self._b
        self.peak_v_mps = max(self.peak_v_mps, abs(v_mps))
        self.peak_omega_radps = max(self.peak_omega_radps, abs(w_radps))
        if not self._v_lo <= v_mps <= self._v_hi:
            return f"chair speed {v_mps:.2f} m/s outside [{self._v_lo:.2f}, {self._v_hi:.2f}]"
        if abs(w_radps) > self._w_hi:
            return f"yaw rate {w_radps:.2f} rad/s beyond +-{self._w_hi:.2f}"
        return ""

    def check(self, link: DriveLink, t_ns: int) -> bool:
        """True once a divergence has lasted ``obey_time_s`` (:attr:`detail` says which)."""
        why = self._divergence(link)
        if not why:
            self._since_ns = None
            return False
        if self._since_ns is None:
            self._since_ns = t_ns
        if t_ns - self._since_ns >= self._hold_ns:
            self.detail = f"{why} for {(t_ns - self._since_ns) / 1e6:.0f} ms"
            return True
        return False

    def moving(self, link: DriveLink, t_ns: int, fresh: Collection[Node] | None = None) -> bool:
        """After a latched stop: True once a wheel has turned faster than the margin for
        ``obey_time_s`` (someone else is driving it).

        ``fresh``: the drives whose feedback is current; a silent drive's last speed says
        nothing about its wheel now (None: every drive's).
        """
        m = self.p.obey_margin_revps
        turning = any(
            math.isfinite(d.vel_revps) and abs(d.vel_revps) > m
            for n, d in link.drives.items()
            if fresh is None or n in fresh
        )
        if not turning:
            self._moving_since_ns = None
            return False
        if self._moving_since_ns is None:
            self._moving_since_ns = t_ns
        return t_ns - self._moving_since_ns >= self._hold_ns
