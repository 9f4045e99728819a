"""python-can's own tools on our MCAP: ``can_player`` drives a real-time bench from a recording.

A lock-step run is recorded; its host frames (arming, setpoints, heartbeats) are
written to their own MCAP with ``can.Logger``; in a private namespace a real-time
bench and a recorder listen on udp_multicast while ``can_player`` plays the host
frames.  The bench's chair must drive the recorded path.  ``Set_Watchdog`` is left
out: on a shared CPU a stalled real-time bench would otherwise trip the drives'
100 ms setpoint watchdog (in simulation time) and stop the chair.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import can
import numpy as np
import pytest

from dbc.codec import Codec, SetWatchdog
from tests.integration.conftest import run_stack
from tests.rt import RT_PRIORITY, rt
from tools.bus import transport
from tools.metrics.tracking import read_bus_log

# the path driven, judged from its own log with the watchdog left out: two may go side by side
pytestmark = [pytest.mark.hil, pytest.mark.alone, pytest.mark.paired]

SANDBOX_OK, SANDBOX_WHY = transport.sandbox_supported()
PLAYER = shutil.which("can_player", path=str(Path(sys.executable).parent))


def _host_frames_only(src: Path, dst: Path) -> int:
    codec = Codec.default()
    host_ids = {
        codec.frame_id(cls, node)
        for cls, node, _n in codec.all_messages()
        if node is not None and codec.sender(cls, node) == "Host" and cls is not SetWatchdog
    }
    n = 0
    with can.LogReader(src) as reader, can.Logger(dst) as writer:
        for m in reader:
            if not m.is_extended_id and m.arbitration_id in host_ids:
                writer(m)
                n += 1
    return n


def _path(xs: np.ndarray, ys: np.ndarray) -> float:
    return float(np.sum(np.hypot(np.diff(xs), np.diff(ys))))


@pytest.mark.skipif(not SANDBOX_OK, reason=f"no private network namespace: {SANDBOX_WHY}")
@pytest.mark.skipif(PLAYER is None, reason="can_player not installed")
def test_can_player_drives_a_bench_from_a_recording(tmp_path: Path) -> None:
    run_stack(tmp_path / "recorded", "short", "baseline", duration_s=8.0)
    host = tmp_path / "host.mcap"
    assert _host_frames_only(tmp_path / "recorded" / "run.mcap", host) > 1000
    py = f"{sys.executable} -m tools.cli"
    # the player stands in for the host: on SCHED_FIFO as the controller would be
    chrt = f"chrt -f {RT_PRIORITY} " if RT_PRIORITY else ""
    d = tmp_path
    script = f"""
{py} record --bus udp_multicast --realtime {rt("record")} --ready --out {d}/live.mcap > {d}/rec.out 2> {d}/rec.err &
until grep -q READY {d}/rec.out; do sleep 0.05; done
{py} sim --bus udp_multicast --realtime {rt("sim")} --scenario short --duration 10 --out {d}/sim --ready > {d}/sim.out 2> {d}/sim.err &
until grep -q READY {d}/sim.out; do sleep 0.05; done
{chrt}{PLAYER} -i udp_multicast -c {transport.DEFAULT_MULTICAST_GROUP} {host} > {d}/player.out 2>&1
wait
"""
    res = subprocess.run(
        transport.sandbox_argv(["sh", "-c", script]),
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert res.returncode == 0, res.stderr + (d / "player.out").read_text()
    live = read_bus_log(d / "live.mcap", ["Bench_Truth_Pose"]).get("Bench_Truth_Pose")
    rec = read_bus_log(d / "recorded" / "run.mcap", ["Bench_Truth_Pose"]).get("Bench_Truth_Pose")
    assert live["t"].size > 500
    # the live chair drove (most of) the recorded path, and stayed on it (the bench runs
    # longer than the recording: after the last setpoint it drives on, off the recorded end)
    recorded_length = _path(rec["X"], rec["Y"])
    assert _path(live["X"], live["Y"]) > 0.5 * recorded_length > 1.0
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(live["X"]), np.diff(live["Y"])))])
    on = s <= recorded_length
    pts = np.stack([rec["X"], rec["Y"]], axis=1)
    off = [
        float(np.min(np.hypot(pts[:, 0] - x, pts[:, 1] - y)))
        for x, y in zip(live["X"][on], live["Y"][on], strict=True)
    ]
    assert max(off) < 0.1, f"left the recorded path by {max(off):.3f} m"
