"""Hardware-in-the-loop over a real bus backend: bench, controller and recorder as OS processes.

Here the processes share a python-can udp_multicast bus inside a private network
namespace (``unshare -rn``); ``tests/hil/socketcan/`` runs the same checks on SocketCAN's
vcan0 (in a user-mode Linux guest where the host kernel has no CAN).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.integration.conftest import run_stack
from tools.bus import transport

pytestmark = pytest.mark.hil

SANDBOX_OK, SANDBOX_WHY = transport.sandbox_supported()
needs_sandbox = pytest.mark.skipif(
    not SANDBOX_OK, reason=f"no private network namespace: {SANDBOX_WHY}"
)


def _cli(*args: str, timeout: float = 300.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tools.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


@pytest.fixture(scope="module")
def virtual_reference(tmp_path_factory: pytest.TempPathFactory) -> dict:
    # the recorder as a bus participant, as in the three processes (it sends Bench_Record_Ack)
    return run_stack(
        tmp_path_factory.mktemp("virtual"), "short", "baseline", recorder="thread", duration_s=6.0
    )


@needs_sandbox
def test_sandbox_namespace_has_only_loopback_with_a_multicast_route() -> None:
    res = _cli(
        "sandbox",
        "--",
        sys.executable,
        "-c",
        "import socket, subprocess; print(sorted(n for _, n in socket.if_nameindex()));"
        "print(subprocess.run(['ip', 'route'], capture_output=True, text=True).stdout)",
    )
    assert res.returncode == 0, res.stderr
    assert "['lo']" in res.stdout
    assert "224.0.0.0/4 dev lo" in res.stdout


@needs_sandbox
def test_three_processes_over_udp_multicast_match_the_virtual_bus(
    tmp_path: Path, virtual_reference: dict
) -> None:
    res = _cli(
        "run",
        "--controller",
        "baseline",
        "--scenario",
        "short",
        # 6 s of the route (600 lock-step rounds through three processes, about a third of
        # the route's): the equality does not depend on the length, its cost does
        "--duration",
        "6",
        "--bus",
        "udp_multicast",
        "--out",
        str(tmp_path),
    )
    assert res.returncode == 0, res.stderr
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["bus"] == "udp_multicast:239.74.163.2"
    for part in ("sim", "control", "record"):  # each part ran as its own process with its own log
        assert (tmp_path / "logs" / f"{part}.log").exists()
    assert s["stop_reason"] == virtual_reference["stop_reason"] == "NONE"  # ended by the duration
    assert s["deadline_misses"] == 0
    for key in ("rmse_xe_m", "rmse_ye_m", "rmse_phie_rad", "rmse_pos_m", "max_pos_err_m"):
        assert s[key] == pytest.approx(virtual_reference[key], abs=1e-6), key
    assert s["frames_total"] == virtual_reference["frames_total"]


@needs_sandbox
def test_bench_and_controller_started_separately_share_one_sandboxed_bus(tmp_path: Path) -> None:
    # The user's way: one namespace, the bench in one process, the controller in another.
    script = (
        f"{sys.executable} -m tools.cli sim --bus udp_multicast --scenario short --duration 4 --out {tmp_path} & "
        f"{sys.executable} -m tools.cli control --bus udp_multicast --scenario short --duration 4 "
        f"--controller baseline --out {tmp_path}; wait"
    )
    res = _cli("sandbox", "--", "sh", "-c", script, timeout=120)
    assert res.returncode == 0, res.stderr
    ctl = json.loads((tmp_path / "controller_stats.json").read_text())
    bench = json.loads((tmp_path / "bench_stats.json").read_text())
    assert ctl["tracking_ticks"] > 300
    assert bench["missed_acks"] == 0


# The socketcan version of these tests is tests/hil/socketcan/ (run in a user-mode Linux
# guest where the host kernel has no CAN: tests/hil/test_socketcan_lane.py).
