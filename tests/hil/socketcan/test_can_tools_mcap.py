"""python-can's ``can_logger`` and ``can_player`` with our ``.mcap`` format, on vcan0."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

from dbc.codec import Codec, EncoderEstimates, Heartbeat, Node, SetInputVel

from .conftest import skip_or_fail

pytestmark = pytest.mark.hil
BIN = str(Path(sys.executable).parent)


def _frames(codec: Codec) -> list[can.Message]:
    from dbc.codec import AxisState

    out = []
    for k in range(150):  # 1.5 s of two drives' traffic, played at its own pace
        step = []
        for node in (Node.LEFT, Node.RIGHT):
            step.append(codec.encode(EncoderEstimates(0.1 * k, 0.5 + 0.01 * k), node))
            step.append(codec.encode(SetInputVel(0.4 + 0.001 * k, 0.0), node))
            if k % 10 == 0:
                step.append(codec.encode(Heartbeat(0, AxisState.CLOSED_LOOP_CONTROL), node))
        for m in step:
            m.timestamp = 1000.0 + 0.01 * k
        out += step
    return out


def test_can_logger_records_what_can_player_plays_from_mcap_on_vcan0(tmp_path: Path) -> None:
    logger, player = (shutil.which(n, path=BIN) for n in ("can_logger", "can_player"))
    if logger is None or player is None:
        skip_or_fail(f"python-can's can_logger/can_player not installed in {BIN}")
    codec = Codec.default()
    sent = _frames(codec)
    src, live = tmp_path / "src.mcap", tmp_path / "live.mcap"
    with can.Logger(src) as w:
        for m in sent:
            w(m)
    rec = subprocess.Popen(
        [str(logger), "-i", "socketcan", "-c", "vcan0", "-f", str(live)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert rec.stdout is not None
        deadline = time.monotonic() + 60
        while "Connected to" not in (line := rec.stdout.readline()):
            assert line and time.monotonic() < deadline, f"can_logger did not start: {line!r}"
        played = subprocess.run(
            [str(player), "-i", "socketcan", "-c", "vcan0", str(src)],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        assert played.returncode == 0, played.stderr
        time.sleep(0.5)
    finally:
        rec.send_signal(signal.SIGINT)
        rec.wait(30)
    with can.LogReader(live) as reader:
        got = [(m.arbitration_id, bytes(m.data)) for m in reader]
    assert got == [(m.arbitration_id, bytes(m.data)) for m in sent]
