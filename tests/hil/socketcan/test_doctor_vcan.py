"""The doctor on SocketCAN vcan0 against the bench: healthy, a drive missing, a drive at a
wrong node ID, a chair's own key with mode 0644, and vcan0 taken down (``ip link set vcan0
down``).

The bench runs in this process (a thread, in real time), so that the one-CPU guest imports
the stack once for all five cases."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from controller.config import load_config
from tests.unit.tools.deploy.benchkit import (
    bench_running,
    chair_config,
    silent_drive_scenario,
    wrong_node_scenario,
)
from tools.bus.transport import resolve
from tools.deploy import doctor, host_checks
from tools.deploy.check import Check, Status

pytestmark = pytest.mark.hil
SPEC = resolve("socketcan", "vcan0")


def _by(checks: list[Check]) -> dict[str, Check]:
    for c in checks:
        print(c.line())  # the doctor's output, for the lane's log
    return {c.name: c for c in checks}


def test_the_doctor_on_vcan0_healthy_then_each_injected_problem(tmp_path: Path) -> None:
    cfg = chair_config(tmp_path)
    with bench_running(SPEC):
        by = _by(doctor.run_checks(cfg, SPEC, window_s=2.0))
        assert {n for n, c in by.items() if c.status is Status.FAIL} == set()
        assert by["interface"].status is Status.OK and "vcan0 up" in by["interface"].detail
        subprocess.run(["ip", "link", "set", "vcan0", "down"], check=True)
        try:
            down = _by(doctor.run_checks(cfg, SPEC, window_s=1.0))
        finally:
            subprocess.run(["ip", "link", "set", "vcan0", "up"], check=True)
    assert down["interface"].status is Status.FAIL and "is down" in down["interface"].detail
    assert down["interface"].fix == "sudo ip link set vcan0 up"
    assert down["drive left"].status is Status.FAIL
    (tmp_path / "bad").mkdir()
    key = host_checks.check_key(
        load_config(chair_config(tmp_path / "bad", key_mode=0o644, chairs_own=True))
    )
    print(key.line())
    assert key.status is Status.FAIL and "mode 0644" in key.detail
    with bench_running(SPEC, str(silent_drive_scenario(tmp_path, "right"))):
        missing = _by(doctor.run_checks(cfg, SPEC, window_s=1.0))
    with bench_running(SPEC, str(wrong_node_scenario(tmp_path, 5))):
        wrong = _by(doctor.run_checks(cfg, SPEC, window_s=1.0))
    assert missing["drive right"].status is Status.FAIL
    assert "not on the bus" in missing["drive right"].detail
    assert missing["drive left"].status is Status.OK
    assert "as node 5 (0x0A1)" in wrong["drive right"].detail
    assert wrong["nodes"].status is Status.FAIL
