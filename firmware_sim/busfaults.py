"""Bus faults: a python-can ``BusABC`` wrapper that loses, delays, duplicates, reorders and
corrupts frames, silences nodes and triggers reboots, seeded and reproducible.

:class:`FaultInjectingBus` wraps any python-can bus (it is not a bus of its own: every frame
still goes through the wrapped bus).  It applies :class:`Rule` objects to the frames its owner
sends (``Direction.SEND``) and receives (``Direction.RECV``):

=====================  ===============================================================
rule                   effect on a matching frame
=====================  ===============================================================
:class:`Drop`          lost with long-run ``probability``; losses come in bursts of
                       geometric length with mean ``burst_length`` (1 = independent
                       losses); a burst starts with ``q = p / (p + L (1 - p))``, so
                       bursts may follow back to back
:class:`Delay`         held for ``delay_ns`` plus a uniform ``[0, jitter_ns]``
:class:`Duplicate`     delivered ``copies + 1`` times with ``probability``
:class:`Reorder`       with ``probability`` held back and delivered after the next matching
                       frame (or after ``max_hold_ns`` if none follows)
:class:`Corrupt`       ``bits`` distinct data bits flipped with ``probability``
:class:`Silence`       every matching frame lost, both ways (a node whose transceiver died)
:class:`BusOff`        ``send`` raises :class:`can.CanOperationError`, receptions are lost
:class:`Inject`        a copy of ``message`` appears every ``period_ns`` (a babbling node)
:class:`Fuzz`          a seeded random frame appears every ``period_ns`` (random 11-bit
                       ID or one of ``ids``, random length and data, some RTR)
:class:`Trigger`       ``action()`` is called once at ``at_ns`` (e.g. a node reboot)
=====================  ===============================================================

Time comes from a ``now_ns`` callable: the bench passes its simulation clock, so that in
lock-step a delay is simulation time and a run is deterministic; the default is
``time.monotonic_ns``.  Delayed frames are released at the first ``send``, ``recv`` or
:meth:`FaultInjectingBus.poll` at or after their due time (in lock-step: the next bench step).
Each rule is active in ``[start_ns, end_ns)`` and has its own ``random.Random`` seeded from the
wrapper's seed and the rule's insertion number, so adding a rule does not change the others'
draws.  Every decision is counted (:attr:`FaultInjectingBus.counters`, per rule in
:meth:`FaultInjectingBus.rule_counters`).

Frames are selected by :class:`FrameMatch`: explicit ``(arbitration ID, extended)`` keys
and/or 11-bit node IDs (``id >> 5``, ODrive CAN Simple).  An empty match selects every
standard (11-bit) frame, never the bench's 29-bit frames, so a rule cannot break the lock-step
clock unless it names those frames.

This module knows python-can only; it imports neither ``controller`` nor ``tools``.
"""

from __future__ import annotations

import copy
import enum
import heapq
import itertools
import random
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import can

from dbc.runtime.busio import recv_monotonic

NowNs = Callable[[], int]


class Direction(enum.Flag):
    """Which way a rule applies, seen from the wrapper's owner."""

    SEND = 1
    RECV = 2
    BOTH = 3


@dataclass(frozen=True)
class FrameMatch:
    """Which frames a rule touches.

    ``ids``: ``(arbitration_id, is_extended_id)`` pairs; ``nodes``: 11-bit node IDs
    (``arbitration_id >> 5``).  A frame matches if either selects it; with both empty every
    standard frame matches (extended frames only when named in ``ids``).
    """

    ids: frozenset[tuple[int, bool]] = frozenset()
    nodes: frozenset[int] = frozenset()

    def __call__(self, msg: can.Message) -> bool:
        ext = bool(msg.is_extended_id)
        if not self.ids and not self.nodes:
            return not ext
        if (msg.arbitration_id, ext) in self.ids:
            return True
        return not ext and (msg.arbitration_id >> 5) in self.nodes


ALL_STANDARD = FrameMatch()
#: At most this many frames are taken from the bus in one ``recv`` call once its timeout has
#: passed (a flood must not hold the caller's tick).
DRAIN_MAX = 1024


@dataclass(frozen=True)
class Rule:
    """Base of every rule: which frames, which way, when (``end_ns`` None = forever)."""

    match: FrameMatch = ALL_STANDARD
    direction: Direction = Direction.BOTH
    start_ns: int = 0
    end_ns: int | None = None

    def active(self, now_ns: int) -> bool:
        """Whether the rule acts at ``now_ns``: in ``[start_ns, end_ns)``."""
        return self.start_ns <= now_ns and (self.end_ns is None or now_ns < self.end_ns)


@dataclass(frozen=True)
class Drop(Rule):
    """Lose matching frames with long-run ``probability``, in bursts of mean ``burst_length``."""

    probability: float = 0.0
    burst_length: float = 1.0


@dataclass(frozen=True)
class Delay(Rule):
    """Hold matching frames for ``delay_ns`` plus a uniform ``[0, jitter_ns]``."""

    delay_ns: int = 0
    jitter_ns: int = 0


@dataclass(frozen=True)
class Duplicate(Rule):
    """Deliver a matching frame ``copies + 1`` times with ``probability``."""

    probability: float = 0.0
    copies: int = 1


@dataclass(frozen=True)
class Reorder(Rule):
    """With ``probability``, deliver a matching frame after the next (or after ``max_hold_ns``)."""

    probability: float = 0.0
    max_hold_ns: int = 100_000_000


@dataclass(frozen=True)
class Corrupt(Rule):
    """Flip ``bits`` distinct data bits of a matching frame with ``probability``."""

    probability: float = 0.0
    bits: int = 1


@dataclass(frozen=True)
class Silence(Rule):
    """Lose every matching frame (a node whose transceiver died)."""

    pass


@dataclass(frozen=True)
class BusOff(Rule):
    """Refuse matching sends with :class:`can.CanOperationError`; lose matching receptions."""

    pass


@dataclass(frozen=True)
class Inject(Rule):
    """``message`` appears every ``period_ns`` from ``start_ns`` (RECV: to the owner; SEND: on
    the bus).  ``match`` is not used."""

    message: can.Message | None = None
    period_ns: int = 10_000_000


@dataclass(frozen=True)
class Fuzz(Rule):
    """A random frame every ``period_ns`` from ``start_ns`` (RECV: to the owner; SEND: on the
    bus): an 11-bit ID drawn from ``ids`` (empty: any), a data length drawn from
    ``0..max_length`` (above 8: an oversized frame, as a broken sender could hand over), random
    bytes, and a remote (RTR) frame with ``remote_probability``.  ``match`` is not used."""

    period_ns: int = 1_000_000
    ids: tuple[int, ...] = ()
    max_length: int = 8
    remote_probability: float = 0.0


@dataclass(frozen=True)
class Trigger(Rule):
    """``action()`` runs once, at the first wrapper call at or after ``start_ns``."""

    action: Callable[[], None] | None = None
    name: str = "trigger"


@dataclass
class RuleCounters:
    """What one rule did."""

    matched: int = 0
    dropped: int = 0
    delayed: int = 0
    duplicated: int = 0
    reordered: int = 0
    corrupted: int = 0
    silenced: int = 0
    refused: int = 0
    injected: int = 0
    triggered: int = 0


@dataclass
class BusCounters:
    """Totals of the wrapper: frames offered and delivered per direction, and per effect."""

    offered: dict[str, int] = field(default_factory=lambda: {"send": 0, "recv": 0})
    delivered: dict[str, int] = field(default_factory=lambda: {"send": 0, "recv": 0})
    effects: Counter[str] = field(default_factory=Counter)  # "dropped", "delayed", ...
    discarded_at_shutdown: int = 0


@dataclass
class _Slot:
    rule: Rule
    rng: random.Random
    counters: RuleCounters = field(default_factory=RuleCounters)
    in_burst: bool = False
    held: list[tuple[can.Message, int, Direction]] = field(default_factory=list)  # since, way
    next_inject_ns: int | None = None
    fired: bool = False


def _validate(rule: Rule) -> None:
    def prob(name: str, v: float) -> None:
        if not (0.0 <= v <= 1.0):
            raise ValueError(f"{type(rule).__name__}.{name} = {v} is outside [0, 1]")

    if rule.end_ns is not None and rule.end_ns < rule.start_ns:
        raise ValueError(f"{type(rule).__name__}: end_ns {rule.end_ns} < start_ns {rule.start_ns}")
    if isinstance(rule, Drop):
        prob("probability", rule.probability)
        if not rule.burst_length >= 1.0:
            raise ValueError(f"Drop.burst_length = {rule.burst_length} must be >= 1 (frames)")
    elif isinstance(rule, Delay):
        if rule.delay_ns < 0 or rule.jitter_ns < 0:
            raise ValueError("Delay.delay_ns and jitter_ns must be >= 0 (ns)")
    elif isinstance(rule, Duplicate):
        prob("probability", rule.probability)
        if rule.copies < 1:
            raise ValueError(f"Duplicate.copies = {rule.copies} must be >= 1")
    elif isinstance(rule, Reorder):
        prob("probability", rule.probability)
        if rule.max_hold_ns < 0:
            raise ValueError("Reorder.max_hold_ns must be >= 0 (ns)")
    elif isinstance(rule, Corrupt):
        prob("probability", rule.probability)
        if not 1 <= rule.bits <= 64:
            raise ValueError(f"Corrupt.bits = {rule.bits} is outside [1, 64]")
    elif isinstance(rule, Inject):
        if rule.message is None or rule.period_ns <= 0:
            raise ValueError("Inject needs a message and a period_ns > 0")
    elif isinstance(rule, Fuzz):
        prob("remote_probability", rule.remote_probability)
        if rule.period_ns <= 0:
            raise ValueError(f"Fuzz.period_ns = {rule.period_ns} must be > 0 (ns)")
        if not 0 <= rule.max_length <= 64:
            raise ValueError(f"Fuzz.max_length = {rule.max_length} is outside [0, 64] (bytes)")
        if any(not 0 <= i <= 0x7FF for i in rule.ids):
            raise ValueError("Fuzz.ids must be 11-bit IDs in [0, 0x7FF]")
    elif isinstance(rule, Trigger) and rule.action is None:
        raise ValueError("Trigger needs an action")


def _fuzz_frame(rule: Fuzz, rng: random.Random) -> can.Message:
    """One random frame for a :class:`Fuzz` rule, drawn from the rule's own RNG."""
    aid = rng.choice(rule.ids) if rule.ids else rng.randrange(0x800)
    if rng.random() < rule.remote_probability:
        return can.Message(
            arbitration_id=aid, is_extended_id=False, is_remote_frame=True, dlc=rng.randrange(9)
        )
    n = rng.randrange(rule.max_length + 1)
    data = bytes(rng.randrange(256) for _ in range(n))
    return can.Message(
        arbitration_id=aid, is_extended_id=False, data=data, dlc=min(n, 8), check=False
    )


class FaultInjectingBus(can.BusABC):
    """A python-can bus that forwards to ``bus`` through the fault rules.

    ``owns_bus``: whether :meth:`shutdown` also shuts the wrapped bus down.  The wrapper is
    meant for one owner thread (the bench's loop), as the bench uses its bus.
    """

    def __init__(
        self,
        bus: can.BusABC,
        *,
        now_ns: NowNs | None = None,
        seed: int = 0,
        rules: Iterable[Rule] = (),
        owns_bus: bool = False,
    ) -> None:
        self._bus = bus
        self._now = now_ns or time.monotonic_ns
        self._seed = seed
        self._owns_bus = owns_bus
        self._slots: dict[int, _Slot] = {}
        self._numbers = itertools.count(1)
        self._seq = itertools.count()
        self._tx_heap: list[tuple[int, int, can.Message]] = []
        self._rx_heap: list[tuple[int, int, can.Message]] = []
        self._rx_ready: deque[can.Message] = deque()
        self.counters = BusCounters()
        self.channel_info = f"faults({bus.channel_info})"
        super().__init__(channel=self.channel_info)
        for rule in rules:
            self.add_rule(rule)

    # ------------------------------------------------------------------ rules

    def add_rule(self, rule: Rule) -> int:
        """Install ``rule``; returns a handle for :meth:`remove_rule` (raises ValueError if invalid)."""
        _validate(rule)
        handle = next(self._numbers)
        rng = random.Random(f"busfaults:{self._seed}:{handle}")
        slot = _Slot(rule, rng)
        if isinstance(rule, Inject | Fuzz):
            slot.next_inject_ns = rule.start_ns
        self._slots[handle] = slot
        return handle

    def remove_rule(self, handle: int) -> RuleCounters | None:
        """Uninstall a rule (its held frames are released at once); returns its counters."""
        slot = self._slots.pop(handle, None)
        if slot is None:
            return None
        self._release_held(slot, self._now())
        return slot.counters

    def rule_counters(self) -> dict[int, RuleCounters]:
        """Each installed rule's counters, by handle."""
        return {h: s.counters for h, s in self._slots.items()}

    @property
    def rules(self) -> dict[int, Rule]:
        """Each installed rule, by handle."""
        return {h: s.rule for h, s in self._slots.items()}

    @property
    def wrapped(self) -> can.BusABC:
        """The python-can bus this wrapper forwards to."""
        return self._bus

    # ------------------------------------------------------------------- core

    def _effect(self, slot: _Slot, name: str, n: int = 1) -> None:
        setattr(slot.counters, name, getattr(slot.counters, name) + n)
        self.counters.effects[name] += n

    def _process(
        self, msg: can.Message, direction: Direction, now: int
    ) -> list[tuple[int, can.Message]]:
        """Apply every active rule to one frame; returns ``(due_ns, frame)`` to deliver."""
        out: list[tuple[int, can.Message]] = [(now, msg)]
        for slot in list(self._slots.values()):
            rule = slot.rule
            if not (rule.direction & direction) or not rule.active(now):
                continue
            if isinstance(rule, Inject | Fuzz | Trigger | BusOff):
                continue
            nxt: list[tuple[int, can.Message]] = []
            for due, m in out:
                if not rule.match(m):
                    nxt.append((due, m))
                    continue
                slot.counters.matched += 1
                nxt.extend(self._apply(slot, due, m, now, direction))
            out = nxt
            if not out:
                break
        return out

    def _apply(
        self, slot: _Slot, due: int, m: can.Message, now: int, direction: Direction
    ) -> list[tuple[int, can.Message]]:
        rule = slot.rule
        rng = slot.rng
        if isinstance(rule, Silence):
            self._effect(slot, "silenced")
            return []
        if isinstance(rule, Drop):
            if slot.in_burst:
                drop = True
            else:
                p, length = rule.probability, rule.burst_length
                # start a burst with q so that the long-run loss fraction is p
                q = p / (p + length * (1.0 - p)) if p < 1.0 else 1.0
                drop = rng.random() < q
            if drop:
                slot.in_burst = rng.random() < 1.0 - 1.0 / rule.burst_length
                self._effect(slot, "dropped")
                return []
            return [(due, m)]
        if isinstance(rule, Delay):
            extra = rule.delay_ns + (rng.randint(0, rule.jitter_ns) if rule.jitter_ns else 0)
            if extra > 0:
                self._effect(slot, "delayed")
            return [(due + extra, m)]
        if isinstance(rule, Duplicate):
            if rng.random() < rule.probability:
                self._effect(slot, "duplicated", rule.copies)
                return [(due, m)] + [(due, copy.deepcopy(m)) for _ in range(rule.copies)]
            return [(due, m)]
        if isinstance(rule, Corrupt):
            if rng.random() < rule.probability and len(m.data) > 0:
                data = bytearray(m.data)
                nbits = min(rule.bits, 8 * len(data))
                for bit in rng.sample(range(8 * len(data)), nbits):
                    data[bit // 8] ^= 1 << (bit % 8)
                m = copy.deepcopy(m)
                m.data = data
                self._effect(slot, "corrupted")
            return [(due, m)]
        if isinstance(rule, Reorder):
            released = [(due, h) for h, _since, d in slot.held if d == direction]
            slot.held = [h for h in slot.held if h[2] != direction]
            if not released and rng.random() < rule.probability:
                slot.held.append((m, now, direction))
                self._effect(slot, "reordered")
                return []
            return [(due, m), *released]
        return [(due, m)]

    def _release_held(self, slot: _Slot, now: int) -> None:
        for m, _since, direction in slot.held:
            self._emit(direction, now, m, now)
        slot.held.clear()

    def _emit(self, direction: Direction, due: int, m: can.Message, now: int) -> None:
        if direction == Direction.SEND:
            if due <= now:
                self._bus.send(m)
                self.counters.delivered["send"] += 1
            else:
                heapq.heappush(self._tx_heap, (due, next(self._seq), m))
        else:
            if due <= now:
                self._rx_ready.append(m)
            else:
                heapq.heappush(self._rx_heap, (due, next(self._seq), m))

    def poll(self) -> None:
        """Release due delayed frames, expire held ones, run triggers and injections."""
        self._poll(self._now())

    def _poll(self, now: int) -> None:
        for slot in list(self._slots.values()):
            rule = slot.rule
            if isinstance(rule, Trigger):
                if not slot.fired and now >= rule.start_ns:
                    slot.fired = True
                    self._effect(slot, "triggered")
                    assert rule.action is not None
                    rule.action()
            elif isinstance(rule, Inject):
                nxt = slot.next_inject_ns
                while nxt is not None and nxt <= now and rule.active(nxt):
                    assert rule.message is not None
                    m = copy.deepcopy(rule.message)
                    if rule.direction & Direction.RECV:
                        self._rx_ready.append(m)
                    if rule.direction & Direction.SEND:
                        self._bus.send(m)
                    self._effect(slot, "injected")
                    nxt += rule.period_ns
                slot.next_inject_ns = nxt
            elif isinstance(rule, Fuzz):
                nxt = slot.next_inject_ns
                while nxt is not None and nxt <= now and rule.active(nxt):
                    m = _fuzz_frame(rule, slot.rng)
                    if rule.direction & Direction.RECV:
                        self._rx_ready.append(m)
                    if rule.direction & Direction.SEND:
                        self._bus.send(m)
                    self._effect(slot, "injected")
                    nxt += rule.period_ns
                slot.next_inject_ns = nxt
            elif slot.held and (
                not rule.active(now)
                or (isinstance(rule, Reorder) and now - slot.held[0][1] >= rule.max_hold_ns)
            ):
                self._release_held(slot, now)
        heap = self._tx_heap
        while heap and heap[0][0] <= now:
            _due, _n, m = heapq.heappop(heap)
            self._bus.send(m)
            self.counters.delivered["send"] += 1
        heap = self._rx_heap
        while heap and heap[0][0] <= now:
            self._rx_ready.append(heapq.heappop(heap)[2])

    def _bus_off(self, msg: can.Message, direction: Direction, now: int) -> bool:
        for slot in self._slots.values():
            rule = slot.rule
            if (
                isinstance(rule, BusOff)
                and rule.direction & direction
                and rule.active(now)
                and rule.match(msg)
            ):
                slot.counters.matched += 1
                self._effect(slot, "refused")
                return True
        return False

    # ----------------------------------------------------------- BusABC API

    def _idle(self) -> bool:
        """No rule installed and nothing pending: frames pass straight through."""
        return not (self._slots or self._tx_heap or self._rx_heap or self._rx_ready)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send ``msg`` through the rules (a BusOff rule raises :class:`can.CanOperationError`)."""
        c = self.counters
        if self._idle():
            self._bus.send(msg, timeout)
            c.offered["send"] += 1
            c.delivered["send"] += 1
            return
        now = self._now()
        self._poll(now)
        c.offered["send"] += 1
        if self._bus_off(msg, Direction.SEND, now):
            raise can.CanOperationError("bus-off: frame not sent (injected fault)")
        for due, m in self._process(msg, Direction.SEND, now):
            self._emit(Direction.SEND, due, m, now)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame through the rules, or None after ``timeout`` s."""
        if self._idle():
            msg = self._bus.recv(timeout)
            if msg is not None:
                c = self.counters
                c.offered["recv"] += 1
                c.delivered["recv"] += 1
            return msg
        return super().recv(timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        taken = 0  # frames taken from the bus in this call
        while True:
            now = self._now()
            self._poll(now)
            if self._rx_ready:
                self.counters.delivered["recv"] += 1
                return self._rx_ready.popleft(), False
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            if self._rx_heap:
                due_s = (self._rx_heap[0][0] - now) / 1e9
                wait = due_s if wait is None else min(wait, due_s)
            msg = recv_monotonic(self._bus, wait)
            if msg is not None:
                taken += 1
                self.counters.offered["recv"] += 1
                if not self._slots:
                    self.counters.delivered["recv"] += 1
                    return msg, False
                if not self._bus_off(msg, Direction.RECV, now):
                    for due, m in self._process(msg, Direction.RECV, now):
                        self._emit(Direction.RECV, due, m, now)
                if self._rx_ready:
                    continue
                if taken < DRAIN_MAX:
                    # past the deadline too: every frame already waiting is taken (and its
                    # delay starts) now, not one per call, however long the caller took
                    continue
            if deadline is not None and time.monotonic() >= deadline:
                return None, False

    def shutdown(self) -> None:
        """Discard delayed and held frames (counted), shut an owned bus down; idempotent."""
        if self._is_shutdown:
            return
        self.counters.discarded_at_shutdown = (
            len(self._tx_heap)
            + len(self._rx_heap)
            + len(self._rx_ready)
            + sum(len(s.held) for s in self._slots.values())
        )
        self._tx_heap.clear()
        self._rx_heap.clear()
        self._rx_ready.clear()
        try:
            if self._owns_bus:
                self._bus.shutdown()
        finally:
            super().shutdown()

    @property
    def protocol(self) -> Any:
        """The wrapped bus' CAN protocol."""
        return self._bus.protocol
