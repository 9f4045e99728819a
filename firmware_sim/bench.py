"""The bench loop: the simulated chair on a python-can bus, lock-step or real time.

:class:`Bench` owns the bench's side of the protocol in docs/architecture.md
("Lock-step protocol, precisely").  Per step ``k`` (``t = k*T``):

1. publish the frames due at ``t``: the drives' cyclic frames, the localizer's
   fix, then ``Bench_Step(t)``; after the host's ack (lock-step) or at once (real time)
   ``Bench_Truth_Pose`` and ``Bench_Truth_Twist`` (every step) and
   ``Bench_Truth_Wheels`` (on its DBC cycle), all describing time t;
2. **lock-step**: wait for ``Bench_Step_Ack(t)`` (stale acks are ignored), the
   first time as a handshake that repeats ``Bench_Step(0)`` every
   ``handshake_resend_ms`` until ``handshake_timeout_s``, afterwards at most
   ``ack_timeout_s`` per step (misses are counted; after
   ``give_up_after_missed_acks`` in a row the bench stops waiting until an ack
   comes back).  **Real time**: receive until the absolute deadline
   ``t0 + (k+1)*T`` of the monotonic clock, no ack waiting;
3. every frame received meanwhile is decoded and applied at once, i.e. at
   ``t``; RTR requests are answered at once;
4. integrate ``t -> t+T`` (:meth:`ChairSim.advance`).

At the end it sends ``Bench_End``.  Both modes share this code path; only the
wait in step 2 differs.

Faults (:mod:`firmware_sim.faults`): a :class:`~firmware_sim.faults.FaultManager`
activates the scenario's schedule at simulation time and acts on
``Bench_Fault_Command`` frames at once; every activation, clearing or refusal is
sent as a ``Bench_Fault_Event`` before the step's other frames (so a recorder logs
it at the step's time).  During :meth:`Bench.run` the bench talks through a
:class:`~firmware_sim.busfaults.FaultInjectingBus` wrapped around the caller's bus,
clocked by simulation time, where bus faults act.  The receive path never raises: frames that fail to
decode are counted by :attr:`DecodeError.reason`, frames not addressed to the
bench's nodes (including its own, echoed by udp_multicast) are counted as
ignored, and a payload that cannot be encoded or sent is counted and logged at a
limited rate.  The bench does not own the bus: the caller opens and shuts it.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import can

from dbc.codec import (
    BenchEnd,
    BenchStep,
    BenchStepAck,
    BusVoltageCurrent,
    Codec,
    EncoderEstimates,
    FaultCommand,
    FaultEvent,
    Heartbeat,
    Iq,
    Node,
    PoseFix,
    RecordAck,
    SetInputVel,
    SetInputVelAuth,
    TruthContact,
    TruthPose,
    TruthTwist,
    TruthWheels,
    TxSdo,
)
from dbc.errors import DecodeError, EncodeError
from dbc.runtime import stopping
from dbc.runtime.busio import receive_ns, recv_dropping
from dbc.runtime.errors import BusError, ConfigError
from firmware_sim.busfaults import FaultInjectingBus
from firmware_sim.config import BenchConfig, bench_node_map
from firmware_sim.faults import FaultManager
from firmware_sim.faultspec import FaultSpec, parse_schedule
from firmware_sim.sim import ChairSim

log = logging.getLogger(__name__)

#: Longest single blocking receive while a stop event may ask us to quit.
_POLL_S = 0.05
#: Real time: frames taken at most before a late step (what a 10 ms step of traffic holds, x8).
_LATE_DRAIN_MAX = 256


class BenchHandshakeError(BusError):
    """No controller acknowledged ``Bench_Step(0)`` within the handshake timeout."""


#: The setpoint frames a drive's watchdog counts.
_SETPOINTS = (SetInputVel, SetInputVelAuth)


@dataclass(slots=True)
class BenchStats:
    """What a bench run did; returned by :meth:`Bench.run`."""

    steps: int = 0
    sim_time_s: float = 0.0
    wall_s: float = 0.0
    frames_sent: int = 0
    frames_received: int = 0
    frames_rejected_by_reason: dict[str, int] = field(default_factory=dict)
    missed_acks: int = 0
    handshake_wall_s: float = 0.0
    #: Valid frames the bench's nodes do not receive (other nodes', own echoes).
    frames_ignored: int = 0
    #: Payloads that could not be encoded (e.g. a truth value outside its DBC range).
    encode_failures: int = 0
    send_failures: int = 0
    #: Real time only: steps whose deadline had passed before the bench got to wait.
    overruns: int = 0
    stopped_early: bool = False
    #: Why the run ended before its duration because the simulation itself failed, if it did.
    aborted: str | None = None
    #: Bench_Fault_Event frames produced (activations, clearings, refusals).
    fault_events: int = 0
    #: What the bus-fault wrapper did, by effect (dropped, delayed, ...).
    bus_fault_effects: dict[str, int] = field(default_factory=dict)
    #: Lock-step with a recorder window: wall time spent waiting for the recorder, and
    #: whether it stopped answering (then the bench stopped waiting).
    recorder_wait_s: float = 0.0
    recorder_lost: bool = False
    #: Wall time spent integrating the chair (physics and the drives' 1 kHz loops), of
    #: ``wall_s``: what a lock-step step costs before any frame or controller work.
    physics_s: float = 0.0
    #: Frames the kernel dropped from this part's full receive queue (filled in by the
    #: part's runner, which owns the socket), and the queue's size in bytes (0: no socket).
    rx_dropped: int = 0
    rx_buffer_bytes: int = 0
    #: Real time with ``sim --rt-priority``: the scheduling the bench asked for and got.
    realtime_notes: list[str] = field(default_factory=list)
    #: Frames each drive did not act on, by reason (authentication refusals, locked
    #: configuration, contract mismatch, ...): ``DriveNode.ignored`` by drive name.
    drive_refusals: dict[str, dict[str, int]] = field(default_factory=dict)
    #: Real time: the longest time between two setpoints a drive was given, in bench time
    #: ("bench", what its watchdog counts) and between their receive times ("wire"), in ms
    #: by drive name.  A bench that applied frames long after they arrived shows the first
    #: far above the second.
    setpoint_gap_max_ms: dict[str, dict[str, float]] = field(default_factory=dict)

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return self.sim_time_s / self.wall_s if self.wall_s > 0 else math.inf


class _Throttle:
    """At most one log line per key and interval (tick-time errors must not flood)."""

    __slots__ = ("_interval_s", "_last")

    def __init__(self, interval_s: float = 5.0) -> None:
        self._interval_s = interval_s
        self._last: dict[str, float] = {}

    def warn(self, key: str, msg: str, *args: Any) -> None:
        now = time.monotonic()
        if now - self._last.get(key, -math.inf) >= self._interval_s:
            self._last[key] = now
            log.warning(msg, *args)


class Bench:
    """The simulated chair (two drives, localizer, physics) serving a CAN bus.

    ``duration_s`` is simulated time.  ``realtime=False`` runs the lock-step
    protocol (deterministic for a given ``seed``); ``realtime=True`` clocks the
    steps by ``time.monotonic_ns`` against an absolute schedule.  Setting
    ``stop_event`` ends the run after the current step (a ``Bench_End`` is still
    sent).  ``sim`` is exposed for inspection, ``faults`` (the fault manager) for
    injection; ``faults`` schedules faults (validated :class:`FaultSpec` objects or
    raw ``[[faults]]`` tables).
    """

    def __init__(
        self,
        bus: can.BusABC,
        config: BenchConfig,
        *,
        duration_s: float,
        realtime: bool = False,
        seed: int = 0,
        codec: Codec | None = None,
        stop_event: threading.Event | None = None,
        initial_pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
        faults: Sequence[FaultSpec | Mapping[str, Any]] = (),
    ) -> None:
        if not (isinstance(duration_s, int | float) and math.isfinite(duration_s)) or (
            duration_s < 0
        ):
            raise ConfigError(f"bench duration_s = {duration_s!r} must be a finite number >= 0 (s)")
        if len(initial_pose) != 3 or not all(math.isfinite(float(v)) for v in initial_pose):
            raise ConfigError(f"bench initial_pose = {initial_pose!r} must be 3 finite numbers")
        self.bus = bus
        self.config = config
        self.codec = codec or Codec.default()
        self.realtime = realtime
        self.stop_event = stop_event
        self.sim = ChairSim(config, seed=seed, initial_pose=initial_pose, codec=self.codec)
        for drive in self.sim.drives.values():  # real time: a command's wait on the wire's clock
            drive.auth.arrival_clock = realtime
        schedule = [f for f in faults if isinstance(f, FaultSpec)]
        raw = [f for f in faults if not isinstance(f, FaultSpec)]
        if raw:
            schedule += parse_schedule(raw, source="bench faults", codec=self.codec)
        self.faults = FaultManager(self.sim, schedule, seed=seed, codec=self.codec)
        self.seed = seed
        self.stats = BenchStats()
        self._step_ns = config.step_ns
        self._n_steps = round(duration_s * 1e9 / self._step_ns)
        wheels_ms = self.codec.cycle_time_ms(TruthWheels) or config.bench.step_ms
        self._truth_wheels_period_ns = int(wheels_ms) * 1_000_000
        self._next_truth_wheels_ns = 0
        self._out: list[tuple[Any, Node | None]] = []
        #: real time: each drive's last setpoint, (bench ns, receive ns)
        self._last_setpoint: dict[Node, tuple[int, int]] = {}
        self._throttle = _Throttle()
        self._consecutive_misses = 0
        self._controller_gone = False
        self._ran = False
        self._record_ack_ns = -1
        # Frames the bench itself sends: an echoing transport hands them back.
        own: list[tuple[type, Node | None]] = [
            (cls, node)
            for cls in (Heartbeat, EncoderEstimates, Iq, BusVoltageCurrent, TxSdo)
            for node in (Node.LEFT, Node.RIGHT)
        ]
        own += [(PoseFix, Node.LOCALIZER)]
        own += [
            (cls, None)
            for cls in (BenchStep, TruthPose, TruthTwist, TruthWheels, TruthContact, BenchEnd)
        ]
        own += [(FaultEvent, None)]
        self._own_ids = frozenset(
            (self.codec.frame_id(cls, node), node is None) for cls, node in own
        )
        self._encode = self.codec.encode
        self._decode = self.codec.decode

        # A drive or the localizer configured with another node ID than the contract's
        # (drive.*_node_id, localizer.node_id): its frames go out with that ID, frames to that
        # ID reach it, and frames to its contract ID reach nobody.  Empty as the contract says.
        self._nodes = bench_node_map(config)
        #: called with the simulation time at every step boundary, before the step is
        #: integrated (a lock-step harness's hook: tools.run.branches forks a run there)
        self.on_step: Callable[[int], None] | None = None

    # ------------------------------------------------------------------- run

    def run(self) -> BenchStats:
        """Run the whole bench; returns the statistics (also in :attr:`stats`).

        Raises :class:`BenchHandshakeError` (lock-step) if no controller ever
        acknowledges ``Bench_Step(0)``.  Nothing raises after the handshake.
        """
        if self._ran:
            raise RuntimeError("Bench.run() may be called once per Bench")
        self._ran = True
        outer = self.bus
        sim = self.sim
        wrapper = FaultInjectingBus(outer, now_ns=lambda: sim.now_ns, seed=self.seed)
        self.bus = self.faults.bus = wrapper
        try:
            return self._run()
        finally:
            self.stats.bus_fault_effects = dict(wrapper.counters.effects)
            self.bus = outer
            wrapper.shutdown()

    def _run(self) -> BenchStats:
        stats = self.stats
        sim = self.sim
        wall0 = time.monotonic_ns()
        self._publish()
        if self.realtime:
            deadline_ns = wall0
        else:
            if not self._handshake():
                return self._finish(wall0)
        self._publish_truth()
        stop = self.stop_event
        step_ns = self._step_ns
        realtime = self.realtime
        window_ns = self.config.bench.recorder_window_steps * step_ns
        physics_ns = 0
        for _ in range(self._n_steps):
            if stop is not None and stop.is_set():
                stats.stopped_early = True
                break
            if realtime:
                deadline_ns += step_ns
                self._pump_until(deadline_ns)
            if self.on_step is not None:
                self.on_step(sim.now_ns)
            t0_ns = time.perf_counter_ns()
            try:
                sim.advance()
            except Exception as err:  # a diverged model or a broken fault hook ends the run cleanly
                stats.aborted = f"simulation failed at t={sim.now_ns / 1e9:.3f} s: {err!r}"
                log.error("bench: %s", stats.aborted)
                break
            physics_ns += time.perf_counter_ns() - t0_ns
            stats.steps += 1
            self._publish()
            if not realtime:
                self._await_ack(sim.now_ns)
            self._publish_truth()
            if window_ns and not realtime:
                self._await_recorder(sim.now_ns - window_ns)
        stats.physics_s = physics_ns / 1e9
        return self._finish(wall0)

    def _await_recorder(self, t_ns: int) -> None:
        """Lock-step: receive until a recorder has acknowledged ``Bench_Step(t_ns)`` or later."""
        if self._record_ack_ns >= t_ns or self.stats.recorder_lost:
            return
        stats = self.stats
        t0 = time.monotonic()
        deadline = t0 + self.config.bench.recorder_timeout_s
        stop = self.stop_event
        while self._record_ack_ns < t_ns:
            now = time.monotonic()
            if now >= deadline or (stop is not None and stop.is_set()):
                stats.recorder_lost = True
                self._throttle.warn(
                    "recorder",
                    "bench: no Bench_Record_Ack for %.1f s; no longer waiting",
                    now - t0,
                )
                break
            msg = self._recv(min(_POLL_S, deadline - now))
            if msg is not None:
                self._on_message(msg)
        stats.recorder_wait_s += time.monotonic() - t0

    def _finish(self, wall0_ns: int) -> BenchStats:
        self._send(BenchEnd(self.sim.now_ns), None)
        stopping.at("bench-end")
        stats = self.stats
        stats.drive_refusals = {
            n.name: dict(sorted(d.ignored.items())) for n, d in self.sim.drives.items()
        }
        auth = {
            n: {k: v for k, v in r.items() if k.startswith(("auth", "contract", "config_loos"))}
            for n, r in stats.drive_refusals.items()
        }
        if any(auth.values()):
            log.warning("bench: drives refused frames: %s", auth)
        stats.sim_time_s = self.sim.now_ns / 1e9
        stats.wall_s = (time.monotonic_ns() - wall0_ns) / 1e9
        return stats

    # --------------------------------------------------------------- publish

    def _publish(self) -> None:
        """Send fault events, the drive and localizer frames due now, then ``Bench_Step``."""
        sim = self.sim
        out = self._out
        self.faults.on_step(sim.now_ns)
        self._send_fault_events()
        sim.emit_due(out)
        send = self._send
        for payload, node in out:
            send(payload, node)
        out.clear()
        send(BenchStep(sim.now_ns), None)

    def _publish_truth(self) -> None:
        """Send the ground truth at the current time (only recorders read it).

        In lock-step it follows the host's ack, so the host drains these frames while
        the bench integrates the next step instead of before its tick.
        """
        sim = self.sim
        send = self._send
        now = sim.now_ns
        send(sim.truth_pose(), None)
        send(sim.truth_twist(), None)
        if now >= self._next_truth_wheels_ns:
            self._next_truth_wheels_ns = now + self._truth_wheels_period_ns
            send(sim.truth_wheels(), None)
            send(sim.truth_contact(), None)

    def _send_fault_events(self) -> None:
        for ev in self.faults.take_events():
            self.stats.fault_events += 1
            self._send(ev, None)

    def _send(self, payload: Any, node: Node | None) -> None:
        stats = self.stats
        try:
            msg = self._encode(payload, node)
        except EncodeError as err:
            stats.encode_failures += 1
            self._throttle.warn(
                "encode", "bench: cannot encode %s: %s", type(payload).__name__, err
            )
            return
        if self._nodes:
            self._nodes.to_wire(msg)
        try:
            self.bus.send(msg)
        except (can.CanError, OSError, ValueError) as err:
            stats.send_failures += 1
            self._throttle.warn("send", "bench: cannot send %s: %s", type(payload).__name__, err)
            return
        stats.frames_sent += 1

    # --------------------------------------------------------------- receive

    def _on_message(self, msg: can.Message) -> int | None:
        """Decode and apply one received frame; return the time of a ``Bench_Step_Ack``."""
        stats = self.stats
        stats.frames_received += 1
        if self._nodes:  # a drive that talks as another node ID than the contract's
            seen = self._nodes.from_wire(msg)
            if seen is None:  # to the contract's ID, where that drive is not
                stats.frames_ignored += 1
                return None
            msg = seen
        if not msg.is_remote_frame and (msg.arbitration_id, msg.is_extended_id) in self._own_ids:
            stats.frames_ignored += 1
            return None
        try:
            frame = self._decode(msg)
        except DecodeError as err:
            rej = stats.frames_rejected_by_reason
            rej[err.reason] = rej.get(err.reason, 0) + 1
            self._throttle.warn("decode:" + err.reason, "bench: rejected frame: %s", err)
            return None
        except Exception as err:  # a codec bug must not stop the bench
            rej = stats.frames_rejected_by_reason
            rej["internal"] = rej.get("internal", 0) + 1
            self._throttle.warn("decode:internal", "bench: decoder failed: %r", err)
            return None
        payload = frame.payload
        if type(payload) is RecordAck:
            self._record_ack_ns = max(self._record_ack_ns, payload.sim_time_ns)
            return None
        if type(payload) is BenchStepAck:
            return payload.sim_time_ns
        if type(payload) is FaultCommand:
            try:
                self.faults.command(payload, self.sim.now_ns)
            except Exception as err:  # a fault model bug must not stop the bench
                self._throttle.warn("fault", "bench: fault command %r failed: %r", payload, err)
            self._send_fault_events()
            return None
        if self.realtime and type(payload) in _SETPOINTS and frame.node is not None:
            self._note_setpoint(frame.node, msg)
        out = self._out
        try:
            handled = self.sim.handle(frame.node, payload, out, msg)
        except Exception as err:  # a drive bug must not stop the bench
            handled = False
            rej = stats.frames_rejected_by_reason
            rej["handler_error"] = rej.get("handler_error", 0) + 1
            self._throttle.warn("handle", "bench: handling %r failed: %r", payload, err)
        if not handled:
            stats.frames_ignored += 1
        if out:
            for reply, node in out:
                self._send(reply, node)
            out.clear()
        return None

    def _note_setpoint(self, node: Node, msg: can.Message) -> None:
        """Real time: keep the longest gap between a drive's setpoints (BenchStats)."""
        now_ns = self.sim.now_ns
        rx_ns = receive_ns(msg)
        last = self._last_setpoint.get(node)
        self._last_setpoint[node] = (now_ns, rx_ns)
        if last is None:
            return
        gaps = self.stats.setpoint_gap_max_ms.get(node.name)
        if gaps is None:
            gaps = self.stats.setpoint_gap_max_ms[node.name] = {"bench": 0.0, "wire": 0.0}
        gaps["bench"] = max(gaps["bench"], (now_ns - last[0]) / 1e6)
        if rx_ns and last[1]:
            gaps["wire"] = max(gaps["wire"], (rx_ns - last[1]) / 1e6)

    def _recv(self, timeout_s: float) -> can.Message | None:
        """One receive; a datagram that is no frame, or a bus error, is counted and gives None."""
        rej = self.stats.frames_rejected_by_reason
        before = sum(rej.values()) if rej else 0  # (nothing was ever rejected: no sum)
        msg = recv_dropping(self.bus, timeout_s, rej)
        n = sum(rej.values()) - before if rej else 0
        if n:
            self.stats.frames_received += n  # they arrived; rejected before they were frames
            self._throttle.warn("recv", "bench: dropped what the bus received: %s", dict(rej))
        return msg

    def _handshake(self) -> bool:
        """Repeat ``Bench_Step(0)`` until the first ack; False if stopped meanwhile."""
        cfg = self.config.bench
        stop = self.stop_event
        start = time.monotonic()
        give_up = start + cfg.handshake_timeout_s
        resend_s = cfg.handshake_resend_ms / 1e3
        resend_at = start + resend_s
        while True:
            if stop is not None and stop.is_set():
                self.stats.stopped_early = True
                return False
            now = time.monotonic()
            if now >= give_up:
                self._send(BenchEnd(0), None)
                raise BenchHandshakeError(
                    f"bench: no controller acknowledged Bench_Step(0) within "
                    f"{cfg.handshake_timeout_s:g} s (bench.handshake_timeout_s) on "
                    f"{self.bus.channel_info}; is a controller running in lock-step mode "
                    "on the same bus?"
                )
            if now >= resend_at:
                self._send(BenchStep(0), None)
                resend_at += resend_s
                continue
            msg = self._recv(min(resend_at, give_up) - now)
            if msg is not None and self._on_message(msg) == 0:
                self.stats.handshake_wall_s = time.monotonic() - start
                return True

    def _await_ack(self, t_ns: int) -> None:
        """Lock-step: receive until ``Bench_Step_Ack(t_ns)`` or the ack timeout."""
        stats = self.stats
        if self._controller_gone:
            # Only take what has already arrived; any ack means the controller is back.
            while (msg := self._recv(0.0)) is not None:
                ack = self._on_message(msg)
                if ack is not None:
                    self._controller_gone = False
                    self._consecutive_misses = 0
                    if ack == t_ns:
                        return
            if self._controller_gone:
                stats.missed_acks += 1
            return
        stop = self.stop_event
        deadline = time.monotonic() + self.config.bench.ack_timeout_s
        while True:
            if stop is not None and stop.is_set():
                return
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                # Past the deadline: still take what has already arrived, then count a miss.
                msg = self._recv(0.0)
                if msg is not None:
                    if self._on_message(msg) == t_ns:
                        self._consecutive_misses = 0
                        return
                    continue
                stats.missed_acks += 1
                self._consecutive_misses += 1
                if self._consecutive_misses >= self.config.bench.give_up_after_missed_acks:
                    self._controller_gone = True
                    self._throttle.warn(
                        "gone",
                        "bench: %d acks missed in a row at t=%.3f s; running on without waiting",
                        self._consecutive_misses,
                        t_ns / 1e9,
                    )
                return
            if stop is not None and remaining > _POLL_S:
                remaining = _POLL_S
            msg = self._recv(remaining)
            if msg is not None and self._on_message(msg) == t_ns:
                self._consecutive_misses = 0
                return

    def _pump_until(self, deadline_ns: int) -> None:
        """Real time: apply frames as they arrive until the monotonic deadline.

        A step that is already late still applies what has arrived before it runs
        (bounded, so that a flood cannot hold the physics): a bench that fell behind
        must not integrate on without the host's latest setpoints, or its drives'
        watchdogs would judge the host late for the bench's own lateness.
        """
        if time.monotonic_ns() >= deadline_ns:
            self.stats.overruns += 1
            for _ in range(_LATE_DRAIN_MAX):
                msg = self._recv(0.0)
                if msg is None:
                    return
                self._on_message(msg)
            return
        while True:
            remaining_ns = deadline_ns - time.monotonic_ns()
            if remaining_ns <= 0:
                return
            msg = self._recv(remaining_ns / 1e9)
            # what is queued behind a frame is taken before the clock is read again (a
            # clock read is a system call where there is no vDSO: 90 us in a user-mode
            # Linux guest), bounded as a late step's drain
            n = 0
            while msg is not None:
                self._on_message(msg)
                n += 1
                if n >= _LATE_DRAIN_MAX:
                    break
                msg = self._recv(0.0)
