"""The forked log writer of one-process runs: frames in order, failures reported, never raised at send."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import can
import pytest

from tools.bus import transport
from tools.logs.bustap import ChannelTap, TapError
from tools.logs.mcap_io import iter_messages


def _frames(n: int) -> list[can.Message]:
    return [
        can.Message(arbitration_id=0x7FE, data=bytes([i & 0xFF]), is_extended_id=False)
        for i in range(n)
    ]


def test_every_frame_reaches_the_log_in_send_order(tmp_path: Path) -> None:
    spec = transport.resolve("virtual", "bustap-order")
    tap = ChannelTap(spec.channel, tmp_path / "run.mcap", lockstep=False, batch=7)
    tap.start()
    a, b = transport.open_bus(spec), transport.open_bus(spec)
    plain = can.Bus(interface="virtual", channel=spec.channel)
    try:
        for i, msg in enumerate(_frames(50)):
            (a, b, plain)[i % 3].send(msg)
    finally:
        stats = tap.stop()
        for bus in (a, b, plain):
            bus.shutdown()
    assert stats.frames == 50 and tap.lost == 0
    raw = [m.data for ch, m in iter_messages(tmp_path / "run.mcap") if ch.topic == "/can/raw"]
    # payload byte i, base64-encoded, in the order sent
    import base64
    import json

    got = [base64.b64decode(json.loads(d)["data"])[0] for d in raw]
    assert got == list(range(50))


def test_a_log_that_cannot_be_opened_fails_at_start_naming_the_file(tmp_path: Path) -> None:
    path = tmp_path / "missing-dir" / "run.mcap"
    tap = ChannelTap("bustap-bad-path", path, lockstep=False)
    with pytest.raises(TapError, match="missing-dir"):
        tap.start()


def test_a_writer_that_dies_costs_frames_not_an_exception_at_send(tmp_path: Path) -> None:
    spec = transport.resolve("virtual", "bustap-killed")
    tap = ChannelTap(spec.channel, tmp_path / "run.mcap", lockstep=False, batch=1)
    tap.start()
    bus = transport.open_bus(spec)
    try:
        bus.send(_frames(1)[0])
        pid = tap.writer.pid
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        for msg in _frames(20):
            bus.send(msg)  # must not raise
        with pytest.raises(TapError, match="not written"):
            tap.stop()
    finally:
        bus.shutdown()
    assert tap.lost >= 1
