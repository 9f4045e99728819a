"""The Fuzz rule of the bus-fault wrapper: seeded random frames at a fixed rate."""

from __future__ import annotations

import itertools

import can
import pytest

from firmware_sim import busfaults as bf
from tools.bus.transport import open_bus, resolve

MS = 1_000_000
_chan = itertools.count()


def _received(rule: bf.Fuzz, *, seed: int = 3, until_ns: int = 100 * MS) -> list[can.Message]:
    spec = resolve("virtual", f"fuzz-{next(_chan)}")
    now = [0]
    inner = open_bus(spec)
    bus = bf.FaultInjectingBus(inner, now_ns=lambda: now[0], seed=seed, owns_bus=True)
    try:
        bus.add_rule(rule)
        out = []
        for t in range(0, until_ns + 1, MS):
            now[0] = t
            while (m := bus.recv(0.0)) is not None:
                out.append(m)
        return out
    finally:
        bus.shutdown()


def test_fuzz_frames_come_at_the_configured_rate_and_are_reproducible() -> None:
    rule = bf.Fuzz(direction=bf.Direction.RECV, start_ns=10 * MS, end_ns=60 * MS, period_ns=MS)
    a, b = _received(rule), _received(rule)
    assert len(a) == 50  # one per ms in [10, 60) ms
    key = [(m.arbitration_id, bytes(m.data), m.is_remote_frame) for m in a]
    assert key == [(m.arbitration_id, bytes(m.data), m.is_remote_frame) for m in b]
    other = _received(rule, seed=4)
    assert key != [(m.arbitration_id, bytes(m.data), m.is_remote_frame) for m in other]


def test_fuzz_draws_ids_lengths_and_remote_frames_as_configured() -> None:
    ids = (0x21, 0x28, 0x48)
    rule = bf.Fuzz(
        direction=bf.Direction.RECV,
        period_ns=MS // 4,
        ids=ids,
        max_length=12,
        remote_probability=0.2,
    )
    got = _received(rule, until_ns=200 * MS)
    assert {m.arbitration_id for m in got} == set(ids)
    assert not any(m.is_extended_id for m in got)
    lengths = {len(m.data) for m in got if not m.is_remote_frame}
    assert lengths == set(range(13))  # 0..12: truncated, nominal and oversized frames
    rtr = sum(m.is_remote_frame for m in got) / len(got)
    assert 0.15 < rtr < 0.25


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"period_ns": 0}, "period_ns"),
        ({"max_length": 65}, "max_length"),
        ({"remote_probability": 1.5}, "remote_probability"),
        ({"ids": (0x800,)}, "11-bit"),
    ],
)
def test_invalid_fuzz_rules_are_refused(kw: dict[str, object], match: str) -> None:
    spec = resolve("virtual", f"fuzz-{next(_chan)}")
    bus = bf.FaultInjectingBus(open_bus(spec), owns_bus=True)
    try:
        with pytest.raises(ValueError, match=match):
            bus.add_rule(bf.Fuzz(**kw))  # type: ignore[arg-type]
    finally:
        bus.shutdown()
