"""The doctor against the bench across processes on udp_multicast, in a private namespace.

The bench (``wheelchair-hil sim --realtime``, as a chair's drives run) and the doctor
(``wheelchair-hil doctor``) are separate processes: healthy, a chair's own key with mode
0644, a drive missing (a scenario silences it from t = 0), a drive at a wrong node ID (the
bench's right drive configured as node 5, ``[bench.drive] right_node_id``) and the interface
down.  On udp_multicast "down" is the namespace's loopback taken down (``ip link set lo
down``): that is the only interface its frames travel; the CAN controller checks (bitrate,
error state) do not apply there and are tested in the socketcan lane and on recorded ``ip
-json`` output.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.rt import rt
from tests.unit.tools.deploy.benchkit import (
    chair_config,
    silent_drive_scenario,
    wrong_node_scenario,
)
from tools.bus import transport

# one bench for the module's checks (a module fixture: make test gives a `paired` file's tests
# to one worker).  Paired: the bench on SCHED_FIFO keeps its rates beside another real-time
# test and lock-step work (all its checks passed beside two spinning processes)
pytestmark = [pytest.mark.hil, pytest.mark.alone, pytest.mark.paired]

SANDBOX_OK, SANDBOX_WHY = transport.sandbox_supported()

_SCRIPT = r"""
import json, subprocess, sys, time
from tools.bus.transport import open_bus, resolve

cfg, cfg644, silent, wrong = sys.argv[1:5]
bench_rt = sys.argv[5].split()  # "--rt-priority N", or nothing
cli = [sys.executable, "-m", "tools.cli"]

def bench(scenario):
    p = subprocess.Popen(
        cli + ["sim", "--bus", "udp_multicast", "--realtime", *bench_rt, "--scenario", scenario,
               "--duration", "600"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    bus = open_bus(resolve("udp_multicast", None))
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and p.poll() is None:
            m = bus.recv(0.2)
            if m is not None and not m.is_extended_id:
                break
    finally:
        bus.shutdown()
    return p

def stop(p):
    p.terminate()
    try:
        p.wait(30)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()

def doctor(config):
    r = subprocess.run(cli + ["doctor", "--bus", "udp_multicast", "--config", config],
                       capture_output=True, text=True, timeout=300)
    return {"rc": r.returncode, "out": r.stdout, "err": r.stderr}

out = {}
b = bench("short")
try:
    out["healthy"] = doctor(cfg)
    out["key644"] = doctor(cfg644)
    subprocess.run(["ip", "link", "set", "lo", "down"], check=True)
    try:
        out["down"] = doctor(cfg)
    finally:
        subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
        subprocess.run(["ip", "route", "replace", "224.0.0.0/4", "dev", "lo"], check=True)
finally:
    stop(b)
for name, scenario in (("missing", silent), ("wrong_node", wrong)):
    b = bench(scenario)
    try:
        out[name] = doctor(cfg)
    finally:
        stop(b)
print(json.dumps(out))
"""


def _lines(case: dict[str, Any]) -> dict[str, str]:
    """The doctor's lines by check name (``ok      drive left  ...`` -> ``drive left``)."""
    out = {}
    for line in case["out"].splitlines():
        if line.startswith("doctor:"):
            continue
        out[line[8:20].strip()] = line
    return out


@pytest.fixture(scope="module")
def cases(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, Any]]:
    if not SANDBOX_OK:
        pytest.skip(f"no private network namespace: {SANDBOX_WHY}")
    tmp = tmp_path_factory.mktemp("doctor")
    good, bad = tmp / "good", tmp / "bad"
    good.mkdir()
    bad.mkdir()
    argv = [str(chair_config(good)), str(chair_config(bad, key_mode=0o644, chairs_own=True))]
    argv += [str(silent_drive_scenario(tmp, "right")), str(wrong_node_scenario(tmp, 5))]
    argv += [rt("sim")]  # the bench stands in for the drives' own hardware
    res = subprocess.run(
        [sys.executable, "-m", "tools.cli", "sandbox", "--", sys.executable, "-c", _SCRIPT, *argv],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
        cwd=Path(__file__).resolve().parents[2],
    )
    assert res.returncode == 0, res.stderr
    got: dict[str, dict[str, Any]] = json.loads(res.stdout.strip().splitlines()[-1])
    report = "\n".join(f"--- {k} (exit {v['rc']})\n{v['out']}{v['err']}" for k, v in got.items())
    print(report)  # the doctor's output of every case, for the log
    return got


def test_a_healthy_bench_passes_every_check(cases: dict[str, dict[str, Any]]) -> None:
    c = cases["healthy"]
    assert c["rc"] == 0, c
    lines = _lines(c)
    assert not [ln for ln in lines.values() if ln.startswith("FAIL")], c["out"]
    assert lines["drive left"].startswith("ok") and lines["drive right"].startswith("ok")
    assert lines["contract"].startswith("ok") and lines["interface"].startswith("n/a")


def test_a_key_with_mode_0644_fails(cases: dict[str, dict[str, Any]]) -> None:
    c = cases["key644"]
    assert c["rc"] == 1
    line = _lines(c)["key"]
    assert line.startswith("FAIL") and "mode 0644" in line and "fix: chmod 600" in line


def test_a_missing_drive_fails(cases: dict[str, dict[str, Any]]) -> None:
    c = cases["missing"]
    assert c["rc"] == 1
    lines = _lines(c)
    assert lines["drive right"].startswith("FAIL") and "not on the bus" in lines["drive right"]
    assert lines["drive left"].startswith("ok")


def test_a_drive_at_a_wrong_node_id_fails_with_the_fix(cases: dict[str, dict[str, Any]]) -> None:
    c = cases["wrong_node"]
    assert c["rc"] == 1
    lines = _lines(c)
    assert "as node 5 (0x0A1)" in lines["drive right"] and "node_id = 2" in lines["drive right"]
    assert lines["nodes"].startswith("FAIL")


def test_the_interface_down_fails(cases: dict[str, dict[str, Any]]) -> None:
    c = cases["down"]
    assert c["rc"] == 1
    lines = _lines(c)
    assert lines["interface"].startswith("FAIL") and "loopback lo is down" in lines["interface"]
    # one failure per cause: the drives behind a bus that did not open are not checked, and
    # say so, instead of failing again
    for drive in ("drive left", "drive right"):
        assert (
            lines[drive].startswith("n/a") and "not checked: the bus did not open" in lines[drive]
        )
