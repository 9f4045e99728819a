"""The controller process's loop: one code path for lock-step and real time.

Per tick (docs/architecture.md):

    frames in (link) -> odometry + EKF -> safety checks -> state machine
    -> reference sample at route time -> controller.step(t, dt, ref, est)
    -> limits (the command and its wheel speeds) -> setpoint frames out -> host heartbeat
    -> telemetry

State machine (published in Host_Heartbeat every 100 ms and at once on a change, and
logged): INIT -> ARMING -> TRACKING -> DONE, and SAFE_STOP -> FAULT from ARMING/TRACKING
when a safety monitor fires or a tick fails.  There is no automatic resume: FAULT is
final, and the drives latch their own stops until Clear_Errors and re-arming
(docs/safety.md).  Nothing raises out of a tick: an exception is counted and logged,
and the chair is brought to a coordinated stop.

SAFE_STOP follows the safe-stop policy (controller/safe_stop.py): a coordinated ramp, a
lost drive's stop mirrored, both drives braked where a speed loop cannot be trusted.

Setpoints are saturated explicitly before encoding (finite, within the drives' velocity
limit): a non-finite or out-of-range value never reaches a frame.  The limiter computes the
wheel speeds once; each is turned into the wire's rev/s once (``radps_to_revps``) and
checked once before encoding.
"""

from __future__ import annotations

import contextlib
import errno
import gc
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

from controller.clock import NOT_DUE, Clock
from controller.config import CONFIG_PATH, ControllerConfig, node_map
from controller.estimation import Estimation
from controller.kinematics import forward, radps_to_revps, revps_to_radps
from controller.limits import STOP, CommandLimiter, LimitedCommand, RateLimitMeter
from controller.link import INTERFACE_DOWN_ERRNOS, DriveLink
from controller.obedience import ObedienceMonitor
from controller.odometry import arc_step
from controller.safe_stop import SafeStopPolicy
from controller.safety import SafetyMonitor, StopReason
from controller.telemetry import NullTelemetry, Telemetry
from controller.types import (
    Controller,
    Pose,
    StateEstimate,
    Trajectory,
    tracking_error,
    wrap_angle,
)
from dbc.codec import (
    DRIVES,
    AxisState,
    ClearErrors,
    Codec,
    ControlMode,
    HostDiagnosis,
    HostHeartbeat,
    HostState,
    InputMode,
    Node,
    RxSdo,
    SdoEndpoint,
    SdoOpcode,
    SetAxisState,
    SetControllerMode,
    SetInputVel,
    SetInputVelAuth,
    SetLimits,
    SetVelDerivativeGain,
    SetVelGains,
    SetWatchdog,
)
from dbc.runtime.errors import ConfigError
from dbc.secoc import Authenticator, load_key

log = logging.getLogger(__name__)

_TEST_KEY_WARNED: set[str] = set()


#: While arming, a drive that has not reported its wire-contract hash is asked again this often
#: (s), until ``auth.contract_timeout_s``: an SDO read is not acknowledged, and one lost frame
#: must not cost the arming.
CONTRACT_REASK_S = 0.5
#: While arming, a drive that reports itself idle without an error is sent the arming
#: commands again this often (s), until ``loop.arming_timeout_s``: a command is not
#: acknowledged, and one lost on the bus (or refused for a Host_Auth that came late) must not
#: cost the arming.  A drive that reports an error is not: its error is why it stays idle,
#: and the arming's timeout names it.
ARM_RESEND_S = 0.5

#: A receive's failure that names the interface down (``busio.rx_reason``'s names).
_RX_DOWN = frozenset(f"rx_os_error_{errno.errorcode[c]}" for c in INTERFACE_DOWN_ERRNOS)


@dataclass
class NodeStats:
    """What the loop measured; the summary and the benchmarks read it."""

    ticks: int = 0
    tracking_ticks: int = 0
    step_ns: list[int] = field(default_factory=list)  # controller.step() durations
    tick_ns: list[int] = field(default_factory=list)  # whole-tick durations
    deadline_misses: int = 0  # real time: late or skipped ticks; lock-step: skipped steps
    overruns: int = 0  # ticks whose computation took longer than the period (wall clock)
    exceptions: int = 0
    non_finite_commands: int = 0
    #: times the arming commands went again to a drive still idle while arming (ARM_RESEND_S)
    arm_resent: int = 0
    final_state: str = "INIT"
    stop_reason: str = "NONE"
    stop_detail: str = ""
    tracking_start_ns: int | None = None
    route_done_ns: int | None = None
    #: The oldest the drives' newest encoder estimate was at a tick while armed and before
    #: any stop (ms of the loop's clock; None: never armed), and the limit it is judged
    #: against (``encoder_stale_periods`` periods): the margin of a fault-free run.
    encoder_age_max_ms: float | None = None
    encoder_stale_limit_ms: float = 0.0
    #: Receives dropped because what arrived was no frame, by reason (dbc.runtime.busio).
    rx_invalid: dict[str, int] = field(default_factory=dict)
    #: Plausibility (controller.plausibility): the largest distance of a wheel's speed outside
    #: what the host commanded (rev/s, against obey_margin_revps) and the peak measured chair
    #: speed and yaw rate while tracking.
    obey_worst_revps: float = 0.0
    obey_peak_v_mps: float = 0.0
    obey_peak_omega_radps: float = 0.0
    #: The largest per-tick step of the estimate the law got while tracking, beyond the arc
    #: the tick's odometry moved it along (position m, heading rad): the estimator's
    #: released corrections, each at most its max_correction_step_m / _rad.
    estimate_step_max_m: float = 0.0
    estimate_step_max_rad: float = 0.0
    #: Tracking ticks whose law command was at each limit of the envelope, and ``ticks``,
    #: the commands counted (controller.limits.RateLimitMeter).
    rate_limits: dict[str, int] = field(default_factory=dict)
    #: The law's own events since tracking began (its optional ``activity()``, read once at
    #: the end of the run; empty for a law without it).
    law_activity: dict[str, int] = field(default_factory=dict)
    #: The estimator's health over the run (controller.estimation.Estimation.counters).
    estimator: dict[str, int] = field(default_factory=dict)


class ControllerNode:
    """Runs ``controller`` on ``trajectory`` against the drives on ``bus``.

    A registered law carries the chair's limits it saturates with (``limits``); they must be
    this deployment's ``[limits]``, which the node's limiter applies (ConfigError otherwise).
    """

    def __init__(
        self,
        bus: can.BusABC,
        config: ControllerConfig,
        controller: Controller,
        trajectory: Trajectory,
        clock: Clock,
        *,
        codec: Codec | None = None,
        telemetry: Telemetry | None = None,
        start_pose: Pose | None = None,
        stop_event: threading.Event | None = None,
    ) -> None:
        self.cfg = config
        # One envelope: a law saturates with the limits the limiter applies to its output.
        law_limits = getattr(controller, "limits", None)
        if law_limits is not None and law_limits != config.limits:
            raise ConfigError(
                f"controller {controller.name!r} was built with other limits than this "
                f"deployment's [limits] ({law_limits} against {config.limits}): build it "
                "with registry.create(..., limits=config.limits)"
            )
        self.controller = controller
        self.trajectory = trajectory
        self.clock = clock
        self.codec = codec or Codec.default()
        # the authenticated setpoint's Stop_Ref_Vel resolution and range and its Input_Vel
        # range (rev/s), from the contract
        self._stop_ref_lsb, _lo, self._stop_ref_max = self.codec.signal_scale(
            SetInputVelAuth, "stop_ref_revps", Node.LEFT
        )
        auth_vel_max = self.codec.signal_scale(SetInputVelAuth, "input_vel_revps", Node.LEFT)[2]
        d = config.drives
        self.auth: Authenticator | None = None
        if d.require_auth:
            if d.velocity_limit_revps > auth_vel_max:
                raise ConfigError(
                    f"drives.velocity_limit_revps = {d.velocity_limit_revps} is above "
                    f"{auth_vel_max} rev/s, the most Set_Input_Vel_Auth carries"
                )
            key_path = Path(config.auth.key_file)
            if not key_path.is_absolute():
                key_path = CONFIG_PATH.parent / key_path
            key = load_key(key_path)  # a missing or unreadable key: ConfigError naming the file
            if key.is_test and key.path not in _TEST_KEY_WARNED:
                _TEST_KEY_WARNED.add(key.path)  # once per process, not once per run
                log.warning("authentication uses the public TEST key %s: not for a chair", key.path)
            self.auth = Authenticator(key)
        self.link = DriveLink(bus, self.codec, self.auth, node_map(config))
        self.telemetry = telemetry or NullTelemetry()
        #: whether the tick's record goes anywhere (the null log keeps nothing)
        self._logging = not isinstance(self.telemetry, NullTelemetry)
        self.stop_event = stop_event or threading.Event()
        g = config.geometry
        self.period_ns = round(config.loop.period_s * 1e9)
        self.dt_s = self.period_ns * 1e-9
        self.limiter = CommandLimiter(config.limits, g.half_track_m, g.wheel_radius_m)
        #: How often the law's own command sits at a limit of the envelope (per tracking tick).
        self.rate_limits = RateLimitMeter(config.limits, self.dt_s)
        self.safety = SafetyMonitor(config.safety, self.period_ns)
        self.obedience = ObedienceMonitor(
            config.safety, config.limits, config.geometry, self.period_ns
        )
        self.contract_hash = self.codec.contract_hash
        self._contract_asked_ns: int | None = None
        self._contract_reasked_ns = 0
        self.telemetry.metadata(
            "contract",
            {"dbc_hash": f"{self.contract_hash:08x}", "dbc": str(self.codec.path)},
        )
        first = trajectory.sample(0.0)
        self.start_pose = start_pose or Pose(first.x_m, first.y_m, first.heading_rad)
        self.estimation = Estimation(
            g, self.start_pose, settings=self.cfg.estimation, codec=self.codec
        )
        self.state = HostState.INIT
        self.stop_reason = StopReason.NONE
        self.stats = NodeStats()
        self._arm_started_ns = 0
        self._arm_sent_ns = 0
        self._tracking_start_ns = 0
        self._at_rest_since_ns: int | None = None
        self._last_heartbeat_ns: int | None = None
        self._last_diagnosis_ns: int | None = None
        self._diagnosis_period_ns = (
            self.codec.cycle_time_ms(HostDiagnosis, Node.HOST) or 100
        ) * 1_000_000
        self._alive = 0
        self._wheel_cmd_radps: dict[Node, float] = {n: 0.0 for n in DRIVES}
        self._fix_seen = False
        self._rx_down_seen = 0  # receives that found the interface down, as of the last tick
        self._exception_logged = 0
        self._record: dict[str, Any] | None = None
        #: The estimate the law got at the previous tracking tick (NodeStats.estimate_step_*).
        self._prev_est: StateEstimate | None = None
        self._t_ns = 0
        self._published_state: HostState | None = None
        self._vel_limit_revps = config.drives.velocity_limit_revps
        #: How the chair is stopped in SAFE_STOP, and watched in DONE and FAULT.
        self.safe_stop = SafeStopPolicy(
            config, self.link, self.limiter, self.safety, self.obedience, self._stop_ref
        )
        self._gc_was_enabled = True
        self._over = False
        self._ended = False

    # ------------------------------------------------------------------ the loop

    def run(self) -> NodeStats:
        """Run until the clock ends the run (Bench_End, duration, stop event) or the route is done.

        The clock waits for each tick; a clock that does not (``LockstepClock(wait=False)``)
        is for :meth:`poll`.
        """
        self.begin()
        try:
            while self._step() is not False:
                pass
        finally:
            self.end()
        return self.stats

    def begin(self) -> None:
        """Start the loop's clock (and freeze the collector if configured); :meth:`run` calls it.

        A caller that drives the loop with :meth:`poll` calls ``begin`` first and
        :meth:`end` at the end.
        """
        self._gc_was_enabled = gc.isenabled()
        if self.cfg.loop.disable_gc:
            if not self.clock.lockstep:
                # the garbage collected now, so that the frozen heap holds none; in lock-step
                # nothing waits for a pause, and a full collection of a process that has run
                # experiments (a campaign's worker, a test session) cost 40-70 ms per run
                gc.collect()
            gc.freeze()
            gc.disable()
        self.clock.start()

    def poll(self) -> bool:
        """Run every tick that is due, without waiting; False once the run is over.

        For a run that has the bench and this loop in one thread: the clock must not
        wait (``LockstepClock(wait=False)``), and the bench calls this whenever it would
        wait for the controller.  Each tick is the same code as in :meth:`run`.
        """
        while (ticked := self._step()) is True:
            pass
        return ticked is None

    def end(self) -> None:
        """Undo :meth:`begin` and settle the statistics (idempotent)."""
        if self._ended:
            return
        self._ended = True
        if self.cfg.loop.disable_gc:
            gc.unfreeze()
            if self._gc_was_enabled:
                gc.enable()
        self.stats.deadline_misses += self.clock.stats.missed_ticks
        rx = dict(getattr(self.clock.stats, "rx_invalid", {}))
        self.stats.rx_invalid = rx
        self.link.counters.rejected.update(rx)  # the link's rejected frames, by reason
        age = self.safety.encoder_age_max_ns
        self.stats.encoder_age_max_ms = None if age is None else age / 1e6
        self.stats.encoder_stale_limit_ms = (
            self.cfg.safety.encoder_stale_periods * self.period_ns / 1e6
        )
        if age is not None:
            log.info(
                "worst encoder feedback age while armed: %.1f ms (stale above %.1f ms)",
                age / 1e6,
                self.stats.encoder_stale_limit_ms,
            )
        if rx:
            log.warning("dropped %d receives that were no frame: %s", sum(rx.values()), rx)
        ob = self.obedience
        self.stats.obey_worst_revps = ob.worst_revps
        self.stats.obey_peak_v_mps = ob.peak_v_mps
        self.stats.obey_peak_omega_radps = ob.peak_omega_radps
        self.stats.rate_limits = self.rate_limits.counts()
        self.stats.law_activity = self._law_activity()
        self.stats.estimator = self.estimation.counters()
        self.stats.final_state = self.state.name
        self.stats.stop_reason = self.stop_reason.name

    def _law_activity(self) -> dict[str, int]:
        """The law's ``activity()`` counts (optional in the Controller protocol), once, at
        the end: empty without one, or if it fails (logged; the run's statistics stand)."""
        activity = getattr(self.controller, "activity", None)
        if activity is None:
            return {}
        try:
            return {str(k): int(v) for k, v in activity().items()}
        except Exception as err:
            log.warning("the law's activity() failed: %s: %s", type(err).__name__, err)
            return {}

    def _step(self) -> bool | None:
        """Wait for the next tick and run it: True, then; None if the clock has no tick due
        and does not wait; False once the run is over."""
        if self._over or self.stop_event.is_set():
            self._over = True
            return False
        clock = self.clock
        t_ns = clock.wait_tick(self.link.on_frame)
        if t_ns is None:
            self._over = True
            return False
        if t_ns == NOT_DUE:
            return None
        t0 = time.perf_counter_ns()
        self._tick(t_ns)
        clock.tick_done(t_ns)
        dur = time.perf_counter_ns() - t0
        if self._record is not None:  # logged after the ack: off the critical path
            self.telemetry.log("/controller/tick", t_ns, self._record)
            self._record = None
        self.stats.tick_ns.append(dur)
        if dur > self.period_ns:
            # A tick longer than the period: a missed deadline in real time; in
            # lock-step the bench waits, so it is only a (load-dependent) overrun.
            self.stats.overruns += 1
            if not clock.lockstep:
                self.stats.deadline_misses += 1
        if self._finished(t_ns):
            self._over = True
            return False
        return True

    def _receive_down(self) -> str | None:
        """Why the bus is down, if a receive since the last tick found the interface down.

        A send names it too (:meth:`DriveLink.bus_down`), but only from the tick after the one
        that sent: a host descheduled while the interface went down (660 ms in a loaded
        one-CPU guest) finds the drives' feedback stale in its first tick after, before any
        send of its own has failed, while its receive has already been refused (ENETDOWN).
        """
        rx = getattr(self.clock.stats, "rx_invalid", None)
        if not rx:
            return None
        n = sum(v for k, v in rx.items() if k in _RX_DOWN)
        if n <= self._rx_down_seen:
            return None
        self._rx_down_seen = n
        where = getattr(self.link.bus, "channel_info", "") or "the bus"
        names = ", ".join(sorted(k.removeprefix("rx_os_error_") for k in rx if k in _RX_DOWN))
        return f"cannot receive on {where}: the interface is down ({names})"

    def _finished(self, t_ns: int) -> bool:
        """Real-time runs end on their own once the chair is idle; lock-step waits for Bench_End."""
        if self.clock.lockstep:
            return False
        return (
            self.state in (HostState.DONE, HostState.FAULT)
            and self.safe_stop.stopped_ticks * self.period_ns > 1e9
        )

    def _set_state(self, state: HostState) -> None:
        """Change state (logged; the next heartbeat, sent in this tick, publishes it)."""
        if state != self.state:
            log.info(
                "state %s -> %s at %.3f s (%s)",
                self.state.name,
                state.name,
                self._t_ns * 1e-9,
                self.stop_reason.name,
            )
            self.state = state
            if state not in (HostState.ARMING, HostState.TRACKING):
                self.safety.stop_measuring()

    def _tick(self, t_ns: int) -> None:
        self.stats.ticks += 1
        self._t_ns = t_ns
        try:
            self._tick_body(t_ns)
        except Exception as err:  # the loop must survive anything; stop the chair instead
            self.stats.exceptions += 1
            if self._exception_logged < 5:
                self._exception_logged += 1
                log.exception("tick at %d ns failed: %s", t_ns, err)
            self._enter_safe_stop(StopReason.TICK_EXCEPTION, f"{type(err).__name__}: {err}")
            with contextlib.suppress(Exception):
                self._send_setpoints(
                    self.limiter.stop_step(self.dt_s, self.cfg.limits.safe_stop_decel_mps2)
                )
        self._host_heartbeat(t_ns)
        self._publish_diagnosis(t_ns)

    def _tick_body(self, t_ns: int) -> None:
        link, est = self.link, self.estimation
        down = link.bus_down() or self._receive_down()
        if down is not None and self.state in (
            HostState.INIT,
            HostState.ARMING,
            HostState.TRACKING,
        ):
            # before the feedback checks: with the host's own interface down, a drive that
            # looks lost or stale is the consequence, not the cause
            self.safety.detail = down
            log.error("the bus is down: %s; braking (the drives stop by their watchdog)", down)
            self._enter_safe_stop(StopReason.BUS_DOWN)
        self.safety.observe(link, t_ns)
        est.update(link, t_ns)
        for fix in link.take_pose_fixes():
            self._fix_seen = True
            est.fuse_fix(fix, initialise=self.state in (HostState.INIT, HostState.ARMING))
        tracking = self.state == HostState.TRACKING
        reason = self.safety.check(
            link, t_ns, tracking=tracking, commanded_radps=self._wheel_cmd_radps
        )
        if reason != StopReason.NONE and self.state in (HostState.ARMING, HostState.TRACKING):
            self._enter_safe_stop(reason)

        state = self.state
        if state == HostState.INIT:
            # Arm only once both drives are on the bus (a real chair's drives, or a bench
            # that is still starting, may come up after the host), and (check_contract) they
            # have reported the same wire-contract hash as the host's.
            if all(d.heartbeats > 0 and d.encoder_msgs > 0 for d in link.drives.values()):
                if not self.cfg.auth.check_contract:
                    self._arm(t_ns)
                else:
                    self._confirm_contract(t_ns)
        elif state == HostState.ARMING:
            self._send_setpoints(STOP)
            fix_ok = (
                self._fix_seen
                or (t_ns - self._arm_started_ns) >= self.cfg.loop.wait_for_fix_s * 1e9
            )
            if link.both_armed() and self._heartbeats_since_arm() and fix_ok:
                self._start_tracking(t_ns)
            elif t_ns - self._arm_started_ns > self.cfg.loop.arming_timeout_s * 1e9:
                self._enter_safe_stop(StopReason.ARMING_TIMEOUT, self._arming_missing(fix_ok))
            elif t_ns - self._arm_sent_ns >= ARM_RESEND_S * 1e9:
                self._arm_sent_ns = t_ns
                for n in DRIVES:
                    d = link.drives[n]
                    if d.axis_state == AxisState.IDLE and d.axis_error == 0:
                        self.stats.arm_resent += 1
                        log.info("drive %s still idle while arming: arming commands again", n.name)
                        self._send_arm(n)
        elif state == HostState.TRACKING:
            if self.obedience.check(link, t_ns):
                self.safety.detail = self.obedience.detail
                self._enter_safe_stop(StopReason.DISOBEYED)
                self._send_setpoints(
                    self.limiter.stop_step(self.dt_s, self.cfg.limits.safe_stop_decel_mps2)
                )
                return
            self._track(t_ns)
        elif state == HostState.SAFE_STOP:
            cmd, stopped = self.safe_stop.ramp(t_ns)
            self._send_setpoints(cmd)
            if stopped:
                self.safe_stop.idle_drives()
                self._set_state(HostState.FAULT)
        else:  # DONE / FAULT: drives idle, only the heartbeat goes out
            self.safe_stop.after_stop(t_ns, latched=state == HostState.FAULT)

    # ------------------------------------------------------------ state actions

    def _confirm_contract(self, t_ns: int) -> None:
        """Ask both drives for their wire-contract hash (and freshness reference); arm once
        both answered with the host's hash, refuse for good on a mismatch."""
        link = self.link
        if self._contract_asked_ns is None:
            self._contract_asked_ns = self._contract_reasked_ns = t_ns
            for n in DRIVES:
                self._ask_contract(n)
            return
        hashes = {n: link.drives[n].sdo.get(SdoEndpoint.CONTRACT_HASH) for n in DRIVES}
        for n, h in hashes.items():
            if h is not None and h != self.contract_hash:
                self.stop_reason = StopReason.CONTRACT_MISMATCH
                self.safety.detail = (
                    f"wire contract mismatch: host {self.contract_hash:08x} ({self.codec.path}), "
                    f"drive {n.name} {h:08x}; refusing to arm"
                )
                self.stats.stop_detail = self.safety.detail
                log.error("%s", self.safety.detail)
                self._set_state(HostState.FAULT)
                return
        if all(h is not None for h in hashes.values()):
            if self.auth is not None:
                for n in DRIVES:  # a restarted host continues above the drive's reference
                    ref = link.drives[n].sdo.get(SdoEndpoint.FRESHNESS)
                    if ref is not None:
                        self.auth.resync(int(n), ref)
            self._arm(t_ns)
        elif t_ns - self._contract_asked_ns > self.cfg.auth.contract_timeout_s * 1e9:
            missing = ", ".join(n.name for n, h in hashes.items() if h is None)
            self.stop_reason = StopReason.ARMING_TIMEOUT
            self.safety.detail = (
                f"drive {missing} did not report its wire-contract hash (RxSdo endpoint "
                f"0x{int(SdoEndpoint.CONTRACT_HASH):04X}) within {self.cfg.auth.contract_timeout_s:g} s "
                "(a stock ODrive has none: set auth.check_contract = false)"
            )
            self.stats.stop_detail = self.safety.detail
            log.error("%s", self.safety.detail)
            self._set_state(HostState.FAULT)
        elif t_ns - self._contract_reasked_ns >= CONTRACT_REASK_S * 1e9:
            # an SDO read has no acknowledgement: a request or its answer lost on the bus (a
            # drive still booting, a burst of errors) is asked again, not waited for
            self._contract_reasked_ns = t_ns
            for n, h in hashes.items():
                if h is None:
                    self._ask_contract(n)

    def _ask_contract(self, n: Node) -> None:
        self.link.send(RxSdo(SdoOpcode.READ, SdoEndpoint.FRESHNESS), n)
        self.link.send(RxSdo(SdoOpcode.READ, SdoEndpoint.CONTRACT_HASH), n)

    def _arm(self, t_ns: int) -> None:
        for n in DRIVES:
            self._send_arm(n)
        self._arm_started_ns = self._arm_sent_ns = t_ns
        self._arm_heartbeats = {n: self.link.drives[n].heartbeats for n in DRIVES}
        self.safety.reset_timers(t_ns)
        self._set_state(HostState.ARMING)

    def _arming_missing(self, fix_ok: bool) -> str:
        """What the arming still waited for when it timed out, drive by drive."""
        parts = []
        for n in DRIVES:
            d = self.link.drives[n]
            state = "no heartbeat" if d.axis_state is None else d.axis_state.name
            if d.axis_state != AxisState.CLOSED_LOOP_CONTROL or d.axis_error:
                parts.append(f"drive {n.name} {state}, axis error 0x{d.axis_error:x}")
            elif d.heartbeats <= self._arm_heartbeats[n]:
                parts.append(f"drive {n.name}: no heartbeat since the arming")
        if not fix_ok:
            parts.append("no pose fix")
        waited = "; ".join(parts) or "nothing (the timeout came first)"
        return (
            f"not armed within loop.arming_timeout_s = {self.cfg.loop.arming_timeout_s:g} s: "
            f"{waited} (arming commands sent again {self.stats.arm_resent} times)"
        )

    def _send_arm(self, n: Node) -> None:
        """The arming commands to drive ``n``: a zero setpoint, the configuration, closed loop."""
        d = self.cfg.drives
        gains = self.controller.drive_gains
        send = self.link.send
        send(SetInputVelAuth(0.0, 0.0) if d.require_auth else SetInputVel(0.0, 0.0), n)
        send(SetControllerMode(ControlMode.VELOCITY_CONTROL, InputMode.PASSTHROUGH), n)
        send(SetLimits(d.velocity_limit_revps, d.current_limit_a), n)
        if gains is not None:
            send(SetVelGains(gains.vel_gain, gains.vel_integrator_gain), n)
            send(SetVelDerivativeGain(gains.vel_derivative_gain, gains.derivative_cutoff_hz), n)
        elif d.push_gains:
            send(SetVelGains(d.vel_gain, d.vel_integrator_gain), n)
            send(SetVelDerivativeGain(d.vel_derivative_gain, d.derivative_cutoff_hz), n)
        send(
            SetWatchdog(
                d.watchdog_timeout_ms,
                d.stop_decel_revps2,
                d.require_auth,
                d.host_timeout_ms,
                d.require_neutral_start,
            ),
            n,
        )
        if self.cfg.auth.check_contract:
            send(RxSdo(SdoOpcode.WRITE, SdoEndpoint.CONTRACT_HASH, self.contract_hash), n)
        send(ClearErrors(False), n)
        send(SetAxisState(AxisState.CLOSED_LOOP_CONTROL), n)

    def _heartbeats_since_arm(self) -> bool:
        return all(self.link.drives[n].heartbeats > self._arm_heartbeats[n] for n in DRIVES)

    def _start_tracking(self, t_ns: int) -> None:
        self._tracking_start_ns = t_ns
        self.stats.tracking_start_ns = t_ns
        self.limiter.reset()
        self.rate_limits.reset()
        self._prev_est = est = self.estimation.estimate()
        self.controller.reset(est, 0.0)
        self._set_state(HostState.TRACKING)
        log.info("tracking started at %.3f s", t_ns * 1e-9)

    def _track(self, t_ns: int) -> None:
        tau = (t_ns - self._tracking_start_ns) * 1e-9
        ref = self.trajectory.sample(tau)
        est = self.estimation.estimate()
        self._measure_estimate_step(est)
        off = math.hypot(est.x_m - ref.x_m, est.y_m - ref.y_m)
        if est.valid and off > self.cfg.safety.max_path_error_m:  # NaN compares False
            self._enter_safe_stop(
                StopReason.OFF_PATH,
                f"estimated position {off:.2f} m from the reference "
                f"(safety.max_path_error_m = {self.cfg.safety.max_path_error_m} m)",
            )
            self._send_setpoints(
                self.limiter.stop_step(self.dt_s, self.cfg.limits.safe_stop_decel_mps2)
            )
            return
        t0 = time.perf_counter_ns()
        raw = self.controller.step(tau, self.dt_s, ref, est)
        self.stats.step_ns.append(time.perf_counter_ns() - t0)
        self.stats.tracking_ticks += 1
        if not (math.isfinite(raw.v_mps) and math.isfinite(raw.omega_radps)):
            self.stats.non_finite_commands += 1
            self._enter_safe_stop(
                StopReason.NON_FINITE, f"controller returned v={raw.v_mps} omega={raw.omega_radps}"
            )
            return
        self.rate_limits.observe(raw.v_mps, raw.omega_radps)
        cmd = self.limiter.apply(raw, self.dt_s)
        wl, wr = self._send_setpoints(cmd)
        if ref.done:
            # The route has ended: finish once the chair has been at rest for end_settle_s
            # (within tolerances: a tracking law on noisy estimates dithers at mm/s), or at
            # the latest end_timeout_s after the end of the reference.
            lp = self.cfg.loop
            at_rest = (
                abs(cmd.v_mps) < lp.end_speed_tol_mps
                and abs(cmd.omega_radps) < lp.end_omega_tol_radps
                and abs(est.v_mps) < lp.end_speed_tol_mps
            )
            if not at_rest:
                self._at_rest_since_ns = None
            elif self._at_rest_since_ns is None:
                self._at_rest_since_ns = t_ns
            settled = (
                self._at_rest_since_ns is not None
                and t_ns - self._at_rest_since_ns >= lp.end_settle_s * 1e9
            )
            if settled or tau - self.trajectory.duration_s > lp.end_timeout_s:
                self.stats.route_done_ns = t_ns
                self.stop_reason = StopReason.ROUTE_DONE
                self._send_setpoints(STOP)
                self.safe_stop.idle_drives()
                self._set_state(HostState.DONE)
        if not self._logging:  # nobody reads the tick's record (a run without a log)
            return
        err = tracking_error(est.x_m, est.y_m, est.heading_rad, ref)
        rec: dict[str, Any] = {
            "route_time_s": tau,
            "ref": {
                "x": ref.x_m,
                "y": ref.y_m,
                "heading": ref.heading_rad,
                "v": ref.v_mps,
                "omega": ref.omega_radps,
                "a": ref.a_mps2,
                "alpha": ref.alpha_radps2,
                "curvature": ref.curvature_1pm,
            },
            "est": {
                "x": est.x_m,
                "y": est.y_m,
                "heading": est.heading_rad,
                "v": est.v_mps,
                "omega": est.omega_radps,
            },
            "err": {"x_e": err.x_e_m, "y_e": err.y_e_m, "phi_e": err.phi_e_rad},
            "cmd_raw": {"v": raw.v_mps, "omega": raw.omega_radps},
            "cmd": {
                "v": cmd.v_mps,
                "omega": cmd.omega_radps,
                "wheel_left_radps": wl,
                "wheel_right_radps": wr,
            },
            "step_us": self.stats.step_ns[-1] / 1000.0,
            "internals": dict(self.controller.internals()),
            "diagnosis": self.estimation.diagnosis_record(),
        }
        self._record = rec

    def _measure_estimate_step(self, est: StateEstimate) -> None:
        """Keep the largest step of the estimate since the previous tick beyond the arc that
        the tick's odometry travel moves the previous estimate along (NodeStats)."""
        prev, self._prev_est = self._prev_est, est
        if prev is None or not (prev.valid and est.valid):
            return
        dl, dr = self.estimation.tick_travel_m
        x, y, h, _, _ = arc_step(
            prev.x_m, prev.y_m, prev.heading_rad, dl, dr, self.cfg.geometry.half_track_m
        )
        step_m = math.hypot(est.x_m - x, est.y_m - y)
        step_rad = abs(wrap_angle(est.heading_rad - h))
        s = self.stats
        if step_m > s.estimate_step_max_m:  # NaN compares False
            s.estimate_step_max_m = step_m
        if step_rad > s.estimate_step_max_rad:
            s.estimate_step_max_rad = step_rad

    def _send_setpoints(self, cmd: LimitedCommand) -> tuple[float, float]:
        """Send both wheels' setpoints; returns the wheel speeds sent (rad/s).

        Saturation is explicit here: a non-finite wheel speed becomes 0 (counted), any other
        is clamped to the drives' velocity limit, so the encoder never sees a value it must
        refuse.  E2E frames carry the peak wheel speed as the coordinated-stop reference.
        """
        left, right = radps_to_revps(cmd.left_radps), radps_to_revps(cmd.right_radps)
        lim = self._vel_limit_revps
        if not (math.isfinite(left + right) and -lim <= left <= lim and -lim <= right <= lim):
            # the one guard before encoding (rarely taken); what is sent is recorded as sent
            cmd = self._saturated(left, right)
            left, right = radps_to_revps(cmd.left_radps), radps_to_revps(cmd.right_radps)
        self.safe_stop.sent(self._t_ns, cmd)
        self._wheel_cmd_radps[Node.LEFT] = cmd.left_radps
        self._wheel_cmd_radps[Node.RIGHT] = cmd.right_radps
        self.obedience.commanded(left, right)
        if self.cfg.drives.require_auth:
            ref = self._stop_ref(max(abs(left), abs(right)))
            self.link.send(SetInputVelAuth(left, ref), Node.LEFT)
            self.link.send(SetInputVelAuth(right, ref), Node.RIGHT)
        else:
            self.link.send(SetInputVel(left, 0.0), Node.LEFT)
            self.link.send(SetInputVel(right, 0.0), Node.RIGHT)
        return cmd.left_radps, cmd.right_radps

    def _saturated(self, left_revps: float, right_revps: float) -> LimitedCommand:
        """The command actually sent for wheel speeds that are not finite (each counted, sent
        as 0) or beyond the drives' velocity limit (clamped)."""
        lim = self._vel_limit_revps
        wheels = []
        for r in (left_revps, right_revps):
            if not math.isfinite(r):
                self.stats.non_finite_commands += 1
                r = 0.0
            wheels.append(revps_to_radps(min(max(r, -lim), lim)))
        g = self.cfg.geometry
        v, w = forward(wheels[0], wheels[1], g.half_track_m, g.wheel_radius_m, g.wheel_radius_m)
        return LimitedCommand(v, w, wheels[0], wheels[1])

    def _stop_ref(self, peak_revps: float) -> float:
        """The coordinated-stop reference for ``peak_revps``: rounded up to the frame's LSB."""
        lsb = self._stop_ref_lsb
        return min(self._stop_ref_max, math.ceil(peak_revps / lsb - 1e-9) * lsb)

    def _enter_safe_stop(self, reason: StopReason, detail: str | None = None) -> None:
        """Stop for ``reason``; ``detail`` (default: the safety monitor's) is kept as the
        cause: later checks overwrite the monitor's detail, not this."""
        if self.state in (HostState.SAFE_STOP, HostState.FAULT, HostState.DONE):
            return
        cause = self.safety.detail if detail is None else detail
        log.warning("safe stop: %s (%s)", reason.name, cause)
        self.stop_reason = reason
        self.stats.stop_detail = cause
        self._set_state(HostState.SAFE_STOP)
        self.safe_stop.begin(reason, self._t_ns)

    def _publish_diagnosis(self, t_ns: int) -> None:
        """Host_Diagnosis (the fault bank's verdict and radii) on its DBC cycle."""
        last = self._last_diagnosis_ns
        if last is not None and t_ns - last < self._diagnosis_period_ns:
            return
        self._last_diagnosis_ns = t_ns
        self.link.send(self.estimation.diagnosis_frame(), Node.HOST)

    def _host_heartbeat(self, t_ns: int) -> None:
        """Host_Heartbeat on its period, and at once when the state changed."""
        period = int(self.cfg.loop.host_heartbeat_period_s * 1e9)
        if (
            self._last_heartbeat_ns is not None
            and t_ns - self._last_heartbeat_ns < period
            and self.state == self._published_state
        ):
            return
        self._last_heartbeat_ns = t_ns
        self._published_state = self.state
        self._alive = (self._alive + 1) & 0xFF
        route_s = (
            max(0.0, (t_ns - self._tracking_start_ns) * 1e-9)
            if self.state != HostState.INIT and self._tracking_start_ns
            else 0.0
        )
        self.link.send(
            HostHeartbeat(self.state, self._alive, min(route_s, 4294967.0), int(self.stop_reason)),
            Node.HOST,
        )
