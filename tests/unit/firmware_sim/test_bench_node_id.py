"""A bench drive configured with another node ID than the wire contract's (drive.*_node_id)
talks and listens as that ID, as a misconfigured ODrive would; the contract's ID is deaf."""

from __future__ import annotations

import threading
import time

import can
import pytest

from dbc.codec import Codec, GetError, Heartbeat, Node
from dbc.runtime.errors import ConfigError
from firmware_sim.bench import Bench
from firmware_sim.config import load_bench_config
from tools.bus.transport import LightVirtualBus


def test_a_drive_at_node_5_sends_and_answers_as_node_5_only() -> None:
    codec = Codec.default()
    cfg = load_bench_config({"drive": {"right_node_id": 5}}, source="test")
    bench_bus = LightVirtualBus("node-id-test")
    tap = LightVirtualBus("node-id-test")
    stop = threading.Event()
    bench = Bench(bench_bus, cfg, duration_s=60.0, realtime=True, stop_event=stop)
    thread = threading.Thread(target=bench.run, daemon=True)
    thread.start()
    try:
        time.sleep(0.3)
        ge = codec.request(GetError, Node.RIGHT)  # 0x043: the contract's ID, nobody there
        tap.send(ge)
        tap.send(
            can.Message(
                arbitration_id=(5 << 5) | (ge.arbitration_id & 0x1F),
                is_remote_frame=True,
                dlc=ge.dlc,
                is_extended_id=False,
            )
        )
        seen: set[int] = set()
        t_end = time.monotonic() + 0.5
        while time.monotonic() < t_end:
            m = tap.recv(0.05)
            if m is not None and not m.is_extended_id:
                seen.add(m.arbitration_id)
    finally:
        stop.set()
        thread.join(10.0)
        tap.shutdown()
        bench_bus.shutdown()
    hb = codec.frame_id(Heartbeat, Node.LEFT) & 0x1F
    assert codec.frame_id(Heartbeat, Node.LEFT) in seen
    assert (5 << 5) | hb in seen  # the right drive's heartbeat, as node 5
    assert codec.frame_id(Heartbeat, Node.RIGHT) not in seen
    assert (5 << 5) | (ge.arbitration_id & 0x1F) in seen  # its Get_Error answer, as node 5
    assert not any(i >> 5 == 2 for i in seen)  # nothing at all from node 2


def test_a_node_id_that_collides_is_refused_naming_the_key() -> None:
    with pytest.raises(ConfigError, match=r"drive\.right_node_id = 8 is the host's node ID"):
        load_bench_config({"drive": {"right_node_id": 8}}, source="test")
    with pytest.raises(ConfigError, match="are both 1"):
        load_bench_config({"drive": {"right_node_id": 1}}, source="test")
