"""The live view across processes: ``run --live`` over udp_multicast, ``control --live``.

``run`` re-executes itself in a private network namespace for udp_multicast; its view is
started outside it, so that this test's client (outside, like Foxglove on the machine)
reaches it.  ``control --live`` alone serves the controller's channels and every frame on
the bus (read by a ``record`` process of its own); there the client runs inside the
sandbox with the parts.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.unit.tools.live.test_live_run import _check_against_log
from tools.bus import transport
from tools.live.client import LiveClient, Received

pytestmark = pytest.mark.hil

SANDBOX_OK, SANDBOX_WHY = transport.sandbox_supported()
needs_sandbox = pytest.mark.skipif(
    not SANDBOX_OK, reason=f"no private network namespace: {SANDBOX_WHY}"
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _connect(url: str, proc: subprocess.Popen[str], timeout_s: float = 60.0) -> LiveClient:
    """Connect as soon as the view listens (the run starts it first)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return LiveClient(url).start()
        except OSError:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise
            time.sleep(0.05)


@needs_sandbox
def test_run_over_udp_multicast_serves_its_log_outside_the_namespace(tmp_path: Path) -> None:
    port = _free_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tools.cli",
            "run",
            "--controller",
            "baseline",
            "--scenario",
            "short",
            "--duration",
            "4",
            "--bus",
            "udp_multicast",
            "--live",
            f"127.0.0.1:{port}",
            "--out",
            str(tmp_path),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        client = _connect(f"ws://127.0.0.1:{port}", proc)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    received: Received = client.join(10.0)
    assert proc.returncode == 0, err
    assert f"live: ws://127.0.0.1:{port}" in err
    _check_against_log(received, tmp_path)
    stats = json.loads((tmp_path / "live_stats.json").read_text())
    assert stats["feeds"] == 2 and stats["unknown_channel"] == 0  # record's and control's


@needs_sandbox
def test_control_live_serves_the_controllers_channels_and_the_bus(tmp_path: Path) -> None:
    port = 8765  # inside the sandbox's own network namespace: nothing else listens there
    py = sys.executable
    common = "--bus udp_multicast --scenario short --duration 4"
    script = (
        f"{py} -m tools.live.client ws://127.0.0.1:{port} --json {tmp_path}/client.json & "
        f"{py} -m tools.cli control {common} --controller baseline --out {tmp_path} "
        f"--live 127.0.0.1:{port} & "
        "sleep 3; "  # the controller is listening for the bench's first step by then
        f"{py} -m tools.cli sim {common} --out {tmp_path}; wait"
    )
    res = subprocess.run(
        [py, "-m", "tools.cli", "sandbox", "--", "sh", "-c", script],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert res.returncode == 0, res.stderr
    got = json.loads((tmp_path / "client.json").read_text())
    topics = got["by_topic"]
    for topic in ("/controller/estimate/pose", "/controller/internals", "/controller/loop"):
        assert topics.get(topic, 0) > 0, (topic, topics)
    for topic in ("/can/raw", "/truth/pose", "/wheels/joint_states", "/can/Bench_Step"):
        assert topics.get(topic, 0) > 0, (topic, topics)
