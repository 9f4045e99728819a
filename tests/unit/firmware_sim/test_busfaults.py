"""The bus-fault wrapper around python-can: every effect happens, at the configured rate, seeded."""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import can
import pytest

from firmware_sim import busfaults as bf

MS = 1_000_000


class Clock:
    """Synthetic time for the wrapper (the bench passes its simulation clock)."""

    def __init__(self) -> None:
        self.ns = 0

    def __call__(self) -> int:
        return self.ns


@pytest.fixture
def pair() -> Iterator[tuple[bf.FaultInjectingBus, can.BusABC, Clock]]:
    """A wrapped bus and a plain peer on one fresh virtual channel, with a synthetic clock."""
    channel = f"busfaults-{uuid.uuid4()}"
    clock = Clock()
    with (
        can.Bus(interface="virtual", channel=channel) as inner,
        can.Bus(interface="virtual", channel=channel) as peer,
    ):
        wrapped = bf.FaultInjectingBus(inner, now_ns=clock, seed=7)
        try:
            yield wrapped, peer, clock
        finally:
            wrapped.shutdown()


def frame(i: int = 0, aid: int = 0x2D, ext: bool = False) -> can.Message:
    return can.Message(
        arbitration_id=aid, data=bytes([i & 0xFF, i >> 8, 0, 0, 0, 0, 0, 0]), is_extended_id=ext
    )


def drain(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (m := bus.recv(0.0)) is not None:
        out.append(m)
    return out


def index(m: can.Message) -> int:
    return m.data[0] | m.data[1] << 8


def test_a_wrapper_without_rules_passes_every_frame_both_ways(pair) -> None:
    wrapped, peer, _ = pair
    for i in range(20):
        wrapped.send(frame(i))
    assert [index(m) for m in drain(peer)] == list(range(20))
    for i in range(20):
        peer.send(frame(i))
    got = [wrapped.recv(0.0) for _ in range(20)]
    assert [index(m) for m in got if m is not None] == list(range(20))
    assert wrapped.counters.offered["send"] == 20 and wrapped.counters.delivered["recv"] == 20


@pytest.mark.parametrize(("p", "burst"), [(0.2, 1.0), (0.1, 5.0)])
def test_drops_occur_at_the_configured_rate_and_burst_length(pair, p: float, burst: float) -> None:
    wrapped, peer, _ = pair
    wrapped.add_rule(bf.Drop(direction=bf.Direction.SEND, probability=p, burst_length=burst))
    n = 6000
    for i in range(n):
        wrapped.send(frame(i))
        drain(peer)  # keep the virtual queue short
    delivered = n - wrapped.counters.effects["dropped"]
    assert wrapped.counters.delivered["send"] == delivered
    lost = wrapped.counters.effects["dropped"] / n
    assert lost == pytest.approx(p, abs=0.03)
    # mean burst length from the loss pattern
    pattern = []
    wrapped2 = bf.FaultInjectingBus(peer, now_ns=lambda: 0, seed=3)
    try:
        h = wrapped2.add_rule(bf.Drop(probability=p, burst_length=burst))
        for i in range(n):
            before = wrapped2.counters.effects["dropped"]
            wrapped2._process(frame(i), bf.Direction.SEND, 0)
            pattern.append(wrapped2.counters.effects["dropped"] > before)
        assert wrapped2.rule_counters()[h].dropped == sum(pattern)
    finally:
        wrapped2.shutdown()
    bursts, run = [], 0
    for lost_one in pattern:
        if lost_one:
            run += 1
        elif run:
            bursts.append(run)
            run = 0
    # bursts of mean length L start with q = p / (p + L (1 - p)) and may follow back to back,
    # so runs of consecutive losses average L / (1 - q) (1 / (1 - p) for independent losses)
    q = p / (p + burst * (1.0 - p))
    assert sum(bursts) / len(bursts) == pytest.approx(burst / (1.0 - q), rel=0.15)


def test_the_same_seed_drops_the_same_frames_and_another_seed_does_not() -> None:
    def pattern(seed: int) -> list[bool]:
        with can.Bus(interface="virtual", channel=f"seed-{uuid.uuid4()}") as inner:
            w = bf.FaultInjectingBus(inner, now_ns=lambda: 0, seed=seed)
            try:
                w.add_rule(bf.Drop(probability=0.3))
                return [not w._process(frame(i), bf.Direction.SEND, 0) for i in range(300)]
            finally:
                w.shutdown()

    assert pattern(1) == pattern(1)
    assert pattern(1) != pattern(2)


def test_a_delay_holds_frames_for_simulation_time_and_keeps_their_order(pair) -> None:
    wrapped, peer, clock = pair
    wrapped.add_rule(bf.Delay(direction=bf.Direction.SEND, delay_ns=20 * MS))
    for i in range(3):
        wrapped.send(frame(i))
    assert drain(peer) == []
    clock.ns = 19 * MS
    wrapped.poll()
    assert drain(peer) == []
    clock.ns = 20 * MS
    wrapped.poll()
    assert [index(m) for m in drain(peer)] == [0, 1, 2]
    assert wrapped.counters.effects["delayed"] == 3


def test_jitter_stays_within_its_bound_on_the_receive_side(pair) -> None:
    wrapped, peer, clock = pair
    wrapped.add_rule(bf.Delay(direction=bf.Direction.RECV, delay_ns=10 * MS, jitter_ns=10 * MS))
    for i in range(200):
        peer.send(frame(i))
    assert wrapped.recv(0.01) is None  # nothing due at t = 0
    arrivals: dict[int, int] = {}
    for t_ms in range(0, 25):
        clock.ns = t_ms * MS
        while (m := wrapped.recv(0.0)) is not None:
            arrivals[index(m)] = t_ms
    assert len(arrivals) == 200
    assert min(arrivals.values()) >= 10 and max(arrivals.values()) <= 20
    assert len(set(arrivals.values())) > 5  # spread, not a constant delay


def test_one_recv_takes_every_waiting_frame_so_each_delay_starts_when_it_came(pair) -> None:
    wrapped, peer, clock = pair
    wrapped.add_rule(bf.Delay(direction=bf.Direction.RECV, delay_ns=10 * MS))
    for i in range(200):
        peer.send(frame(i))
    assert wrapped.recv(0.0) is None  # not due yet, however little time the call had
    assert wrapped.counters.offered["recv"] == 200
    clock.ns = 10 * MS
    assert [index(m) for m in iter(lambda: wrapped.recv(0.0), None)] == list(range(200))
    # a flood is taken at most DRAIN_MAX frames per call once the timeout has passed
    for i in range(bf.DRAIN_MAX + 10):
        peer.send(frame(i % 256))
    wrapped.recv(0.0)
    assert wrapped.counters.offered["recv"] == 200 + bf.DRAIN_MAX


def test_duplicates_occur_at_the_configured_rate(pair) -> None:
    wrapped, peer, _ = pair
    wrapped.add_rule(bf.Duplicate(probability=0.25))
    got = 0
    for i in range(4000):
        wrapped.send(frame(i))
        got += len(drain(peer))
    assert got - 4000 == wrapped.counters.effects["duplicated"]
    assert (got - 4000) / 4000 == pytest.approx(0.25, abs=0.03)


def test_reordering_delivers_a_held_frame_after_the_next_one(pair) -> None:
    wrapped, peer, clock = pair
    wrapped.add_rule(bf.Reorder(probability=1.0, max_hold_ns=50 * MS))
    wrapped.send(frame(0))
    assert drain(peer) == []
    wrapped.send(frame(1))
    assert [index(m) for m in drain(peer)] == [1, 0]
    wrapped.send(frame(2))  # held again; nothing follows
    clock.ns = 60 * MS
    wrapped.poll()
    assert [index(m) for m in drain(peer)] == [2]


def test_corruption_flips_exactly_the_configured_number_of_bits(pair) -> None:
    wrapped, peer, _ = pair
    wrapped.add_rule(bf.Corrupt(probability=0.5, bits=3))
    flipped = []
    for i in range(1000):
        sent = frame(i)
        wrapped.send(sent)
        (m,) = drain(peer)
        diff = sum(bin(a ^ b).count("1") for a, b in zip(sent.data, m.data, strict=True))
        flipped.append(diff)
        assert m.arbitration_id == sent.arbitration_id
    assert set(flipped) == {0, 3}
    assert sum(1 for d in flipped if d) / 1000 == pytest.approx(0.5, abs=0.05)
    assert wrapped.counters.effects["corrupted"] == sum(1 for d in flipped if d)


def test_a_silent_node_neither_sends_nor_receives_and_others_are_untouched(pair) -> None:
    wrapped, peer, _ = pair
    wrapped.add_rule(bf.Silence(match=bf.FrameMatch(nodes=frozenset({1}))))
    wrapped.send(frame(0, aid=(1 << 5) | 0x09))  # node 1
    wrapped.send(frame(1, aid=(2 << 5) | 0x09))  # node 2
    assert [index(m) for m in drain(peer)] == [1]
    peer.send(frame(2, aid=(1 << 5) | 0x0D))
    peer.send(frame(3, aid=(2 << 5) | 0x0D))
    got = [wrapped.recv(0.05), wrapped.recv(0.05)]
    assert [index(m) for m in got if m is not None] == [3]
    assert wrapped.counters.effects["silenced"] == 2


def test_bench_frames_on_extended_ids_are_untouched_unless_named(pair) -> None:
    wrapped, peer, _ = pair
    wrapped.add_rule(bf.Drop(probability=1.0))
    wrapped.send(frame(0, aid=0x1CA00001, ext=True))
    wrapped.send(frame(1))
    assert [index(m) for m in drain(peer)] == [0]
    wrapped.add_rule(
        bf.Drop(probability=1.0, match=bf.FrameMatch(ids=frozenset({(0x1CA00001, True)})))
    )
    wrapped.send(frame(2, aid=0x1CA00001, ext=True))
    assert drain(peer) == []


def test_rules_act_only_inside_their_time_window(pair) -> None:
    wrapped, peer, clock = pair
    wrapped.add_rule(bf.Drop(probability=1.0, start_ns=10 * MS, end_ns=20 * MS))
    for t in (0, 10, 15, 20):
        clock.ns = t * MS
        wrapped.send(frame(t))
    assert [index(m) for m in drain(peer)] == [0, 20]


def test_bus_off_refuses_to_send(pair) -> None:
    wrapped, peer, _ = pair
    h = wrapped.add_rule(bf.BusOff())
    with pytest.raises(can.CanOperationError, match="bus-off"):
        wrapped.send(frame(0))
    wrapped.remove_rule(h)
    wrapped.send(frame(1))
    assert [index(m) for m in drain(peer)] == [1]


def test_a_trigger_fires_once_at_its_time(pair) -> None:
    wrapped, _peer, clock = pair
    fired: list[int] = []
    wrapped.add_rule(bf.Trigger(start_ns=30 * MS, action=lambda: fired.append(clock.ns)))
    for t in range(0, 100, 10):
        clock.ns = t * MS
        wrapped.poll()
    assert fired == [30 * MS]


def test_a_babbling_node_is_injected_every_period(pair) -> None:
    wrapped, _peer, clock = pair
    babble = can.Message(arbitration_id=0x001, data=bytes(8), is_extended_id=False)
    wrapped.add_rule(
        bf.Inject(message=babble, period_ns=5 * MS, direction=bf.Direction.RECV, end_ns=50 * MS)
    )
    got = 0
    for t in range(0, 100):
        clock.ns = t * MS
        while wrapped.recv(0.0) is not None:
            got += 1
    assert got == 10
    assert wrapped.counters.effects["injected"] == 10


def test_invalid_rules_are_refused_with_the_field_and_bound(pair) -> None:
    wrapped, _peer, _ = pair
    with pytest.raises(ValueError, match=r"Drop.probability = 1.5 is outside \[0, 1\]"):
        wrapped.add_rule(bf.Drop(probability=1.5))
    with pytest.raises(ValueError, match="burst_length"):
        wrapped.add_rule(bf.Drop(probability=0.1, burst_length=0.5))
    with pytest.raises(ValueError, match=r"Corrupt\.bits"):
        wrapped.add_rule(bf.Corrupt(probability=0.1, bits=0))


def test_shutting_the_wrapper_down_leaves_a_bus_it_does_not_own_open() -> None:
    with can.Bus(interface="virtual", channel=f"own-{uuid.uuid4()}") as inner:
        w = bf.FaultInjectingBus(inner)
        w.add_rule(bf.Delay(delay_ns=10**12))
        w.send(frame(0))
        w.shutdown()
        w.shutdown()  # idempotent
        assert w.counters.discarded_at_shutdown == 1
        assert not inner._is_shutdown
