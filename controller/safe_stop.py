"""The host's safe-stop policy: how the chair is stopped for each stop reason, and what the
host does once it has stopped (controller/node.py runs it in SAFE_STOP, DONE and FAULT).

SAFE_STOP ramps both wheels together (``CommandLimiter.stop_step``: v and omega shrink by
the same factor, the fastest rim decelerating at ``safe_stop_decel_mps2``), the same law
the drives' own watchdog stop follows.  When one drive is lost (its feedback stale: a node
that falls silent does so both ways) it will stop by its own watchdog, from the last
command it received: the host then makes the other drive do the same (hold the command
both last shared until the lost drive's watchdog expires, then the same ramp), so that the
chair keeps its arc.  When a wheel's feedback is implausible (stuck or jumping encoder)
its speed loop cannot be trusted to ramp, and when a drive has dropped out of closed loop
(rebooted, idled) its holding brake already stops that wheel: in both cases both drives
are idled so that their brakes stop the wheels alike.  When the drives disobey, each is
sent Estop (their own coordinated ramp) and the host's ramp starts from the measured
motion.  After the stop, a wheel that turns again is sent Estop again (at most every
100 ms): somebody else is driving it.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable

from controller.config import ControllerConfig
from controller.kinematics import radps_to_revps
from controller.limits import CommandLimiter, LimitedCommand
from controller.link import DriveLink
from controller.obedience import ObedienceMonitor
from controller.safety import SafetyMonitor, StopReason
from dbc.codec import DRIVES, AxisState, Estop, Node, SetAxisState

log = logging.getLogger(__name__)

#: Stop reasons after which a drive's speed loop is blind (its feedback is wrong): brake both.
BRAKE_REASONS = frozenset({StopReason.ENCODER_STUCK, StopReason.ENCODER_JUMP})
#: After a latched stop, a wheel that turns again is sent Estop again at most this often.
RE_ESTOP_NS = 100_000_000


class SafeStopPolicy:
    """Stops the chair for a stop reason and watches it once stopped.

    The node calls :meth:`sent` with every command it sends, :meth:`begin` when it enters
    SAFE_STOP, :meth:`ramp` at each SAFE_STOP tick (it sends the command returned) and
    :meth:`after_stop` at each DONE or FAULT tick.  ``stop_ref`` rounds a peak wheel speed
    (rev/s) up to the authenticated setpoint's coordinated-stop reference.
    """

    def __init__(
        self,
        config: ControllerConfig,
        link: DriveLink,
        limiter: CommandLimiter,
        safety: SafetyMonitor,
        obedience: ObedienceMonitor,
        stop_ref: Callable[[float], float],
    ) -> None:
        self.cfg = config
        self.link = link
        self.limiter = limiter
        self.safety = safety
        self.obedience = obedience
        self._stop_ref = stop_ref
        self.period_ns = round(config.loop.period_s * 1e9)
        self.dt_s = self.period_ns * 1e-9
        #: Deceleration of the ramp (m/s^2): the chair's, stretched to a lost drive's own.
        self.decel_mps2 = config.limits.safe_stop_decel_mps2
        #: Commands sent in the last ticks (tick time, command), to mirror a lost drive.
        self.recent: deque[tuple[int, LimitedCommand]] = deque(maxlen=64)
        #: The ramp holds this command until this time first (a lost drive's watchdog
        #: expiry), or None.
        self.hold: tuple[LimitedCommand, int] | None = None
        #: Whether both drives were idled to brake (the ramp then holds nothing).
        self.braking = False
        #: Ticks at rest since the stop began (SAFE_STOP) or in DONE/FAULT.
        self.stopped_ticks = 0
        #: Estops sent because a wheel turned after the latched stop.
        self.re_estops = 0
        self._last_re_estop_ns: int | None = None

    def sent(self, t_ns: int, cmd: LimitedCommand) -> None:
        """Remember ``cmd``, sent at tick ``t_ns`` (a lost drive's stop mirrors it)."""
        self.recent.append((t_ns, cmd))

    def begin(self, reason: StopReason, t_ns: int) -> None:
        """Start the stop for ``reason`` at tick ``t_ns``: Estop and ramp from the measured
        motion (DISOBEYED), brake (a blind speed loop), or mirror a lost drive."""
        self.stopped_ticks = 0
        if reason == StopReason.DISOBEYED:
            # The drives may be following someone else's setpoints: each ramps its wheel from
            # where it is (Estop: the coordinated ramp), and the host's own ramp starts from
            # the measured motion, so that it idles the drives when they are done.
            for n in DRIVES:
                self.link.send(Estop(), n)
            g = self.cfg.geometry
            vl = self.link.drives[Node.LEFT].vel_revps
            vr = self.link.drives[Node.RIGHT].vel_revps
            if math.isfinite(vl) and math.isfinite(vr):
                pr = math.pi * g.wheel_radius_m
                self.limiter.reset(pr * (vl + vr), pr * (vr - vl) / g.half_track_m)
        elif reason in BRAKE_REASONS:
            self.brake(f"{reason.name}: the drive's speed loop cannot be trusted to ramp")
        elif reason == StopReason.ENCODER_STALE:
            self._mirror_lost_drive(t_ns)

    def ramp(self, t_ns: int) -> tuple[LimitedCommand, bool]:
        """One SAFE_STOP tick: the command to send, and whether the chair has been at rest
        for two ticks (the node then sends it, idles the drives and latches FAULT)."""
        if not self.braking and any(
            d.axis_state is not None and d.axis_state != AxisState.CLOSED_LOOP_CONTROL
            for d in self.link.drives.values()
        ):
            # A drive dropped out of closed loop (rebooted, idled): its brake holds its
            # wheel.  Brake the other wheel too rather than ramp it against a braked one.
            self.brake("drive left closed loop during the stop")
        hold = self.hold
        if hold is not None and t_ns < hold[1] and not self.braking:
            return hold[0], False
        self.hold = None
        cmd = self.limiter.stop_step(self.dt_s, self.decel_mps2)
        if cmd.v_mps == 0.0 and cmd.omega_radps == 0.0:
            self.stopped_ticks += 1
            return cmd, self.stopped_ticks >= 2
        return cmd, False

    def after_stop(self, t_ns: int, *, latched: bool) -> None:
        """One DONE or FAULT tick; after a ``latched`` stop (FAULT), a wheel that turns is
        sent Estop again (somebody else is driving it)."""
        self.stopped_ticks += 1
        if not latched or not self.obedience.moving(self.link, t_ns, self.fresh_feedback(t_ns)):
            return
        last = self._last_re_estop_ns
        if last is None or t_ns - last >= RE_ESTOP_NS:
            self._last_re_estop_ns = t_ns
            self.re_estops += 1
            if self.re_estops <= 3 or self.re_estops % 100 == 0:
                log.error("a wheel turns after the latched stop: Estop again (%d)", self.re_estops)
            for n in DRIVES:
                self.link.send(Estop(), n)

    def idle_drives(self) -> None:
        """Send both drives to IDLE (their holding brakes engage)."""
        for n in DRIVES:
            self.link.send(SetAxisState(AxisState.IDLE), n)

    def brake(self, why: str) -> None:
        """Idle both drives now: their holding brakes stop both wheels alike."""
        log.warning("braking both wheels: %s", why)
        self.braking = True
        self.idle_drives()

    def fresh_feedback(self, t_ns: int) -> frozenset[Node]:
        """The drives whose last encoder estimate is not stale (the staleness check's bound)."""
        limit = self.cfg.safety.encoder_stale_periods * self.period_ns
        fresh = []
        for n in DRIVES:
            since = self.safety.feedback_since_ns(n)
            if since is not None and t_ns - since <= limit:
                fresh.append(n)
        return frozenset(fresh)

    def _mirror_lost_drive(self, t_ns: int) -> None:
        """Plan the stop of the healthy drive to coincide with the lost drive's own stop.

        The lost drive last heard the host about when the host last heard it (a node that
        falls silent does so both ways); it holds the command of that tick until its
        watchdog expires, then ramps.  The healthy drive is given the same command and the
        same moment to start the same ramp.
        """
        timeout_ns = self.cfg.drives.watchdog_timeout_ms * 1_000_000
        culprit = self.safety.culprit
        since = self.safety.feedback_since_ns(culprit) if culprit is not None else None
        recent = self.recent
        if not timeout_ns or since is None or not recent:
            return
        shared = next((c for t, c in reversed(recent) if t <= since), recent[0][1])
        until = since + timeout_ns
        if until <= t_ns:
            return
        log.warning(
            "drive %s lost: holding v=%.3f m/s omega=%.3f rad/s until its watchdog expires "
            "at %.3f s, then the same ramp",
            culprit.name if culprit is not None else "?",
            shared.v_mps,
            shared.omega_radps,
            until * 1e-9,
        )
        self.limiter.reset(shared.v_mps, shared.omega_radps)
        self.hold = (shared, until)
        # The lost drive ramps in max(Stop_Ref_Vel, |own|) / Stop_Decel, Stop_Ref_Vel being the
        # peak wheel speed rounded up to the frame's 0.01 rev/s: stretch the healthy wheel's
        # ramp by the same factor so that both reach zero together.
        peak_revps = radps_to_revps(max(abs(shared.left_radps), abs(shared.right_radps)))
        if self.cfg.drives.require_auth and peak_revps > 0.0:
            ref = self._stop_ref(peak_revps)
            self.decel_mps2 = self.cfg.limits.safe_stop_decel_mps2 * peak_revps / ref
