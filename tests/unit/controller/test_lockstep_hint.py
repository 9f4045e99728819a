"""A lock-step controller on a chair's drives says at once why nothing happens: lock-step
ticks on a bench's steps, which drives never send (``control`` without ``--realtime``)."""

from __future__ import annotations

import logging
import threading
import time

import can
import pytest

from controller import clock as clock_mod
from controller.clock import LockstepClock
from dbc.codec import Codec, EncoderEstimates, Node

CODEC = Codec.default()


def _clock(bus: can.BusABC, start_timeout_s: float) -> LockstepClock:
    return LockstepClock(bus, 10_000_000, codec=CODEC, start_timeout_s=start_timeout_s)


def test_drives_heard_without_a_step_give_the_hint_within_a_second_or_two(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(clock_mod, "HINT_DRIVES_S", 0.3)
    host = can.Bus(interface="virtual", channel="hint-drives")
    drive = can.Bus(interface="virtual", channel="hint-drives")
    stop = threading.Event()

    def feed() -> None:  # a drive's encoder estimates at 100 Hz, no Bench_Step ever
        while not stop.is_set():
            drive.send(CODEC.encode(EncoderEstimates(0.0, 0.0), Node.LEFT))
            time.sleep(0.01)

    sender = threading.Thread(target=feed, daemon=True)
    sender.start()
    clk = _clock(host, start_timeout_s=1.5)
    frames: list[can.Message] = []
    try:
        with caplog.at_level(logging.WARNING, logger="controller.clock"):
            t0 = time.monotonic()
            assert clk.wait_tick(frames.append) is None  # no step within the start timeout
            waited = time.monotonic() - t0
    finally:
        stop.set()
        sender.join(2)
        host.shutdown()
        drive.shutdown()
    hints = [r.getMessage() for r in caplog.records if "--realtime" in r.getMessage()]
    assert len(hints) == 1, caplog.text  # said once
    assert "frames from drives" in hints[0]
    assert frames and waited >= 1.5


def test_a_bench_that_steps_right_after_its_first_frames_gives_no_hint(
    caplog: pytest.LogCaptureFixture,
) -> None:
    from dbc.codec import BenchStep

    host = can.Bus(interface="virtual", channel="hint-bench")
    bench = can.Bus(interface="virtual", channel="hint-bench")
    clk = _clock(host, start_timeout_s=5.0)
    try:
        with caplog.at_level(logging.WARNING, logger="controller.clock"):
            bench.send(CODEC.encode(EncoderEstimates(0.0, 0.0), Node.LEFT))
            bench.send(CODEC.encode(BenchStep(0), None))
            assert clk.wait_tick(lambda _m: None) == 0
    finally:
        host.shutdown()
        bench.shutdown()
    assert "--realtime" not in caplog.text
