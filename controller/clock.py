"""What clocks the controller loop: the bench's step frames, or the monotonic clock.

Both implement :class:`Clock`.  ``wait_tick`` drains the bus, handing each
drive/localizer frame to the loop's ``on_frame`` callback, and returns the time
of the next tick in integer nanoseconds (``None`` when the run is over);
``tick_done`` closes the tick.  The loop above them is the same code in both
modes (docs/architecture.md, "Time").

A lock-step clock built with ``wait=False`` never waits: it takes the frames already
received and returns :data:`NOT_DUE` when no step is among them.  A run that has the
bench and the controller in one thread (``tools.run.in_process``) polls the controller that
way whenever the bench would wait for it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import can

from dbc.codec import BenchEnd, BenchStep, BenchStepAck, Codec
from dbc.errors import CodecError
from dbc.runtime import stopping
from dbc.runtime.busio import recv_dropping
from dbc.runtime.realtime import acquire as try_realtime  # the parts ask with it too (tools.run)

log = logging.getLogger(__name__)

OnFrame = Callable[[can.Message], None]

#: Real time: frames taken at most before a late tick (a flood must not hold the loop).
_LATE_DRAIN_MAX = 256

#: ``wait_tick`` of a clock that does not wait: no tick is due yet (simulation time is never
#: negative).
NOT_DUE = -1


@dataclass
class ClockStats:
    """What a clock counted over a run: ticks, missed ticks, lateness, invalid receptions."""

    ticks: int = 0
    missed_ticks: int = 0  # ticks skipped because the loop fell behind (real time) or steps jumped
    #: real time: wake-up minus schedule, the most recent ticks (bounded for all-day runs)
    lateness_ns: deque[int] = field(default_factory=lambda: deque(maxlen=1_000_000))
    realtime_notes: list[str] = field(default_factory=list)
    #: What the bus received that was no frame (or a receive that failed), by reason
    #: (``dbc.runtime.busio.rx_reason``): dropped, and the loop went on.
    rx_invalid: dict[str, int] = field(default_factory=dict)
    #: real time: ticks whose deadline had passed when the loop came to wait for them
    #: (each still takes the frames already received before it runs)
    late_drains: int = 0


class Clock(Protocol):
    """What ticks the controller loop: the bench's steps (lock-step) or the monotonic clock."""

    period_ns: int
    stats: ClockStats
    lockstep: bool  # True: the run ends on Bench_End, not on its own

    def start(self) -> None:
        """Begin the run, before the first ``wait_tick``."""

    def wait_tick(self, on_frame: OnFrame) -> int | None:
        """Pass frames to ``on_frame`` until the next tick; its time (ns), None at the run's end."""

    def tick_done(self, t_ns: int) -> None:
        """Close the tick at ``t_ns`` (lock-step: acknowledge the step)."""


#: Before the first Bench_Step, a lock-step clock says why nothing happens after this long
#: (:meth:`LockstepClock._hint`), or once the drives have been heard this long without a step
#: (a chair's drives; a bench sends its step right after its first drive frames).
HINT_S = 5.0
HINT_DRIVES_S = 1.0


class LockstepClock:
    """Ticks on ``Bench_Step`` frames; acknowledges each tick with ``Bench_Step_Ack``.

    ``wait=False``: ``wait_tick`` returns :data:`NOT_DUE` instead of waiting when the
    frames received so far hold no step (the idle timeout does not apply then).
    """

    lockstep = True

    def __init__(
        self,
        bus: can.BusABC,
        period_ns: int,
        *,
        codec: Codec | None = None,
        idle_timeout_s: float = 10.0,
        start_timeout_s: float | None = None,
        stop_event: threading.Event | None = None,
        wait: bool = True,
    ) -> None:
        self.bus = bus
        #: before the first step (the bench may still be starting): this long, not idle_timeout_s
        self.start_timeout_s = idle_timeout_s if start_timeout_s is None else start_timeout_s
        self.period_ns = period_ns
        self.codec = codec or Codec.default()
        self.idle_timeout_s = idle_timeout_s
        self.wait = wait
        self.stop_event = stop_event or threading.Event()
        self.stats = ClockStats()
        self._step_id = self.codec.frame_id(BenchStep)
        self._end_id = self.codec.frame_id(BenchEnd)
        self._last_t: int | None = None
        self.ended_by = ""
        self._hinted = False
        self._drive_frames = 0  # frames from the drives before the first step
        self._first_drive_frame = 0.0  # when the first of them came (monotonic)

    def start(self) -> None:
        """Forget the last step: the next Bench_Step starts the run."""
        self._last_t = None

    def _hint(self, waited_s: float) -> None:
        """Say early why nothing happens yet: lock-step waits for a bench's steps, which a
        chair's drives never send (``control`` on a chair without ``--realtime``)."""
        if self._hinted or self._last_t is not None:
            return
        drives = self._drive_frames > 0
        heard_s = time.monotonic() - self._first_drive_frame if drives else 0.0
        if waited_s < HINT_S and heard_s < HINT_DRIVES_S:
            return
        self._hinted = True
        log.warning(
            "lock-step clock: no Bench_Step in %.0f s%s; lock-step ticks on a bench's steps "
            "(wheelchair-hil sim); on a chair's drives, run with --realtime (waiting up to "
            "%.0f s)",
            waited_s,
            f" but {self._drive_frames} frames from drives" if drives else "",
            self.start_timeout_s,
        )

    def wait_tick(self, on_frame: OnFrame) -> int | None:
        """Pass 11-bit frames to ``on_frame`` until a new Bench_Step; its time (ns), or None."""
        idle_since = time.monotonic()
        timeout_s = 0.2 if self.wait else 0.0
        while not self.stop_event.is_set():
            msg = recv_dropping(self.bus, timeout_s, self.stats.rx_invalid)
            if msg is None or not msg.is_extended_id:
                if msg is None and not self.wait:
                    return NOT_DUE
                if self.wait or self._last_t is None:  # not in a one-thread run's steady state
                    # the bus may be busy with the drives' frames (a chair's, which send no
                    # step): the timeout counts from the last step (or the start) whatever
                    # else arrives
                    limit_s = (
                        self.idle_timeout_s if self._last_t is not None else self.start_timeout_s
                    )
                    waited_s = time.monotonic() - idle_since
                    if self.wait and waited_s > limit_s:
                        self.ended_by = f"no Bench_Step for {limit_s:.1f} s"
                        log.error("lock-step clock: %s; is the bench running?", self.ended_by)
                        return None
                    if msg is not None and self._last_t is None:
                        if not self._drive_frames:
                            self._first_drive_frame = time.monotonic()
                        self._drive_frames += 1
                    self._hint(waited_s)
                if msg is None:
                    continue
                on_frame(msg)
                continue
            aid = msg.arbitration_id
            if aid == self._step_id:
                try:
                    t_ns = self.codec.decode(msg).payload.sim_time_ns
                except CodecError:
                    continue
                if self._last_t is not None and t_ns <= self._last_t:
                    self.tick_done(t_ns)  # a re-sent step (start-up handshake): ack it again
                    continue
                if self._last_t is not None and t_ns - self._last_t > self.period_ns:
                    self.stats.missed_ticks += (t_ns - self._last_t) // self.period_ns - 1
                self._last_t = t_ns
                self.stats.ticks += 1
                return t_ns
            if aid == self._end_id:
                self.ended_by = "Bench_End"
                stopping.at("bench-end")
                return None
        self.ended_by = "stopped"
        return None

    def tick_done(self, t_ns: int) -> None:
        """Acknowledge the step at ``t_ns`` with Bench_Step_Ack (a failed send is logged)."""
        try:
            self.bus.send(self.codec.encode(BenchStepAck(t_ns)))
        except (can.CanError, OSError, CodecError) as err:
            log.warning("cannot acknowledge step %d: %s", t_ns, err)


class RealtimeClock:
    """Ticks at ``t0 + k*T`` of ``time.monotonic_ns`` (absolute schedule, no drift).

    If the loop falls a whole period or more behind, the missed ticks are skipped
    and counted.  ``start`` tries SCHED_FIFO and locked memory when ``realtime_priority``
    is set and records what the system allowed.
    """

    lockstep = False

    def __init__(
        self,
        bus: can.BusABC,
        period_ns: int,
        *,
        stop_event: threading.Event | None = None,
        realtime_priority: int = 0,
        duration_s: float | None = None,
    ) -> None:
        self.bus = bus
        self.period_ns = period_ns
        self.stop_event = stop_event or threading.Event()
        self.realtime_priority = realtime_priority
        self.duration_ns = None if duration_s is None else int(duration_s * 1e9)
        self.stats = ClockStats()
        self._t0 = 0
        self._k = 0
        self.ended_by = ""

    def start(self) -> None:
        """Ask for real-time priority if configured, and start the schedule now."""
        if self.realtime_priority > 0:
            self.stats.realtime_notes.extend(try_realtime(self.realtime_priority))
        self._t0 = time.monotonic_ns()
        self._k = 0

    def wait_tick(self, on_frame: OnFrame) -> int | None:
        """Pass frames to ``on_frame`` until the next deadline; its time (ns from start), or None."""
        deadline = self._t0 + self._k * self.period_ns
        bus = self.bus
        dropped = self.stats.rx_invalid
        now = time.monotonic_ns()
        if now >= deadline:
            self.stats.late_drains += 1
        while True:
            if self.stop_event.is_set():
                self.ended_by = "stopped"
                return None
            remaining = deadline - now
            if remaining <= 0:
                break
            msg = recv_dropping(bus, remaining / 1e9, dropped, monotonic=True)
            # the drives' frames come in bursts (a bench step's, a drive's cycle): what is
            # queued behind the first is taken before the clock is read again (a clock
            # read is a system call where there is no vDSO: 90 us in a user-mode Linux guest)
            n = 0
            while msg is not None:
                if not msg.is_extended_id:
                    on_frame(msg)
                n += 1
                if n >= _LATE_DRAIN_MAX:
                    break
                msg = recv_dropping(bus, 0.0, dropped, monotonic=True)
            now = time.monotonic_ns()
        # At the deadline, and above all past it (the process was not scheduled, or the
        # last tick ran long), take what is already queued before the tick: the tick must
        # not judge the drives' feedback stale for the host's own lateness.
        for _ in range(_LATE_DRAIN_MAX):
            msg = recv_dropping(bus, 0.0, dropped, monotonic=True)
            if msg is None:
                break
            if not msg.is_extended_id:
                on_frame(msg)
        lateness = now - deadline
        if lateness >= self.period_ns:
            skipped = lateness // self.period_ns
            self.stats.missed_ticks += skipped
            self._k += skipped
            deadline = self._t0 + self._k * self.period_ns
            lateness = now - deadline
        self.stats.lateness_ns.append(lateness)
        self.stats.ticks += 1
        t_ns = self._k * self.period_ns
        self._k += 1
        if self.duration_ns is not None and t_ns > self.duration_ns:
            self.ended_by = "duration"
            return None
        return t_ns

    def tick_done(self, t_ns: int) -> None:
        """Nothing to do: a real-time tick needs no acknowledgement."""
        pass
