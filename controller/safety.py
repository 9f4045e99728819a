"""Safety monitors of the controller: is the feedback fresh, plausible and the drives healthy?

:class:`SafetyMonitor` is called once per tick after the link has collected the
frames of that tick.  It returns the first reason to stop (:class:`StopReason`)
or ``StopReason.NONE``.  It measures staleness in the loop's own clock, so it
works the same in lock-step and in real time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controller.config import SafetyParams
from controller.kinematics import TWO_PI
from controller.link import DriveLink
from dbc.codec import DRIVES, AxisState, Node
from dbc.codec import StopReason as StopReason  # the wire's enum, re-exported

HEARTBEAT_PERIOD_NS = 100_000_000  # ODrive's heartbeat period, from the DBC's cycle time


_NONE = StopReason.NONE
_CLOSED_LOOP = AxisState.CLOSED_LOOP_CONTROL


@dataclass(slots=True)
class _WheelWatch:
    last_heartbeat_ns: int | None = None
    last_encoder_ns: int | None = None
    last_vel_revps: float | None = None
    last_pos_rev: float | None = None
    pos_frozen_since_ns: int | None = None


class SafetyMonitor:
    """Checks once per tick that the drives are healthy and their feedback fresh and plausible."""

    def __init__(
        self, params: SafetyParams, period_ns: int, heartbeat_period_ns: int = HEARTBEAT_PERIOD_NS
    ) -> None:
        self.p = params
        self.period_ns = period_ns
        self.heartbeat_period_ns = heartbeat_period_ns
        self.w: dict[Node, _WheelWatch] = {n: _WheelWatch() for n in DRIVES}
        self.detail = ""
        #: The drive the last reason to stop was about (``None``: none yet).
        self.culprit: Node | None = None
        #: The oldest the newest encoder estimate of a drive was at any check since the
        #: timers started (arming) and before the first reason to stop: the margin to
        #: ``encoder_stale_periods`` a fault-free run had (loop-clock ns; ``None``: none).
        self.encoder_age_max_ns: int | None = None
        self._measuring = False
        # the limits in the loop's clock (ns), as the checks compare them
        self._heartbeat_limit_ns = params.heartbeat_missed_max * heartbeat_period_ns
        self._stale_limit_ns = params.encoder_stale_periods * period_ns
        self._stuck_ns = params.stuck_encoder_s * 1e9

    def reset_timers(self, t_ns: int) -> None:
        """Start the freshness clocks at ``t_ns`` (a drive that never talked is judged from here)."""
        for w in self.w.values():
            w.last_heartbeat_ns = w.last_heartbeat_ns or t_ns
            w.last_encoder_ns = w.last_encoder_ns or t_ns
        self._measuring = True

    def stop_measuring(self) -> None:
        """End the fault-free staleness measurement (the chair is no longer armed)."""
        self._measuring = False

    def observe(self, link: DriveLink, t_ns: int) -> None:
        """Consume the link's fresh flags for this tick."""
        for node, d in link.drives.items():
            w = self.w[node]
            if d.heartbeat_fresh:
                d.heartbeat_fresh = False
                w.last_heartbeat_ns = t_ns

    def check(
        self, link: DriveLink, t_ns: int, *, tracking: bool, commanded_radps: dict[Node, float]
    ) -> StopReason:
        """First reason to stop in this tick, or NONE.  Consumes encoder fresh flags.

        The drive concerned is left in :attr:`culprit`.
        """
        for node in DRIVES:
            reason = self._check_drive(node, link, t_ns, tracking, commanded_radps)
            if reason is not _NONE:
                self.culprit = node
                self._measuring = False
                return reason
        if self._measuring:
            age: int | None = None
            for w in self.w.values():
                last = w.last_encoder_ns
                if last is not None and (age is None or t_ns - last > age):
                    age = t_ns - last
            if age is not None and (
                self.encoder_age_max_ns is None or age > self.encoder_age_max_ns
            ):
                self.encoder_age_max_ns = age
        return _NONE

    def feedback_since_ns(self, node: Node) -> int | None:
        """Time of the last fresh encoder estimate from ``node`` (the loop's clock)."""
        return self.w[node].last_encoder_ns

    def _check_drive(
        self,
        node: Node,
        link: DriveLink,
        t_ns: int,
        tracking: bool,
        commanded_radps: dict[Node, float],
    ) -> StopReason:
        p = self.p
        d = link.drives[node]
        w = self.w[node]
        last_hb = w.last_heartbeat_ns
        if last_hb is not None and t_ns - last_hb > self._heartbeat_limit_ns:
            self.detail = (
                f"drive {node.name} lost: no heartbeat for {(t_ns - last_hb) / 1e6:.0f} ms"
            )
            return StopReason.DRIVE_LOST
        if tracking and (d.axis_state != _CLOSED_LOOP or d.axis_error):
            self.detail = f"drive {node.name} state {d.axis_state!r} error {d.axis_error:#x}"
            return StopReason.DRIVE_ERROR
        if d.encoder_fresh:
            d.encoder_fresh = False
            pos, vel = d.pos_rev, d.vel_revps
            if not (math.isfinite(pos) and math.isfinite(vel)):
                self.detail = f"drive {node.name} encoder non-finite"
                return StopReason.NON_FINITE
            last_vel, last_ns = w.last_vel_revps, w.last_encoder_ns
            if last_vel is not None and last_ns is not None and t_ns > last_ns:
                dt = (t_ns - last_ns) * 1e-9
                acc = abs(vel - last_vel) * TWO_PI / dt
                if acc > p.max_wheel_accel_radps2:
                    self.detail = f"drive {node.name} wheel speed jump {acc:.0f} rad/s^2"
                    return StopReason.ENCODER_JUMP
            if w.last_pos_rev is not None and pos == w.last_pos_rev:
                if w.pos_frozen_since_ns is None:
                    w.pos_frozen_since_ns = last_ns
            else:
                w.pos_frozen_since_ns = None
            w.last_vel_revps, w.last_pos_rev, w.last_encoder_ns = vel, pos, t_ns
        last_enc = w.last_encoder_ns
        if last_enc is not None and t_ns - last_enc > self._stale_limit_ns:
            self.detail = f"drive {node.name} encoder stale for {(t_ns - last_enc) / 1e6:.0f} ms"
            return StopReason.ENCODER_STALE
        frozen = w.pos_frozen_since_ns
        if (
            tracking
            and frozen is not None
            and abs(commanded_radps.get(node, 0.0)) > p.stuck_command_radps
            and t_ns - frozen > self._stuck_ns
        ):
            self.detail = f"drive {node.name} encoder stuck while moving"
            return StopReason.ENCODER_STUCK
        return _NONE
