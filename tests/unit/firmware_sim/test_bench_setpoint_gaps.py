"""A real-time bench keeps, per drive, the longest time between two setpoints it was given,
in its own (bench) time and between their receive times: a bench that applies frames long
after they arrived shows the first far above the second (bench_stats.json)."""

from __future__ import annotations

import pytest

from dbc.codec import Codec, Node, SetInputVel
from firmware_sim.bench import Bench
from firmware_sim.config import load_bench_config
from tools.bus.transport import LightVirtualBus


def _given(bench: Bench, codec: Codec, node: Node, received_s: float) -> None:
    msg = codec.encode(SetInputVel(0.0), node)
    msg.timestamp = received_s
    bench._on_message(msg)


@pytest.mark.parametrize("realtime", [True, False])
def test_each_drives_longest_setpoint_gap_in_bench_time_and_on_the_wire(realtime: bool) -> None:
    codec = Codec.default()
    bus = LightVirtualBus(f"gap-test-{realtime}")
    try:
        bench = Bench(bus, load_bench_config({}, source="test"), duration_s=1.0, realtime=realtime)
        _given(bench, codec, Node.LEFT, 100.000)
        _given(bench, codec, Node.RIGHT, 100.001)
        for _ in range(5):  # 50 ms of bench time while the next frames were 10 ms apart
            bench.sim.advance()
        _given(bench, codec, Node.LEFT, 100.010)
        bench.sim.advance()
        _given(bench, codec, Node.LEFT, 100.015)
    finally:
        bus.shutdown()
    gaps = bench.stats.setpoint_gap_max_ms
    if not realtime:  # lock-step: the bench's time is the wire's, nothing to compare
        assert gaps == {}
        return
    assert gaps["LEFT"] == {"bench": pytest.approx(50.0), "wire": pytest.approx(10.0)}
    assert "RIGHT" not in gaps  # one setpoint: no gap yet
