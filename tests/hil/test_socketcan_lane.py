"""The socketcan lane, where the host kernel has no CAN: one user-mode Linux guest runs it.

``tests/hil/socketcan/`` needs SocketCAN with ``vcan0`` up.  Here the host computes the
virtual-bus references (fast), boots one guest (``tools.bus.umlguest``, as ``wheelchair-hil
sandbox --socketcan`` does) and runs that whole directory inside it: one boot and one
import of the stack for the lane, instead of one per test.  In CI
(``WHEELCHAIR_HIL_REQUIRE_SOCKETCAN=1``) neither this test nor any test inside may skip.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.hil.socketcan.conftest import (
    EQUALITY_SCENARIOS,
    REFERENCE_ENV,
    REQUIRE_ENV,
    VCAN_UP,
    handshake_frames,
    skip_or_fail,
)
from tests.integration.conftest import run_stack
from tools.bus import umlguest

pytestmark = pytest.mark.hil
ROOT = Path(__file__).resolve().parents[2]


def test_the_socketcan_lane_passes_in_a_user_mode_linux_guest(tmp_path: Path) -> None:
    if VCAN_UP:
        pytest.skip("vcan0 is up on this kernel: tests/hil/socketcan runs directly")
    ok, why = umlguest.guest_supported()
    if not ok:
        skip_or_fail(f"no SocketCAN here and no user-mode Linux guest: {why}")
    reference = {}
    for name in EQUALITY_SCENARIOS:
        reference[name] = run_stack(tmp_path / name, name, "baseline", recorder="thread")
        reference[name]["handshake_frames"] = handshake_frames(tmp_path / name / "run.mcap")
    ref_path = tmp_path / "virtual_reference.json"
    ref_path.write_text(json.dumps(reference, default=str))
    inner = [
        sys.executable,
        "-m",
        "pytest",
        "-q",
        "-rs",
        "--tb=short",
        "--color=no",
        "-p",
        "no:cacheprovider",
        "--durations=0",
    ]
    # its own base directory: the guest's pytest must not prune the host's temporary dirs
    inner += ["--basetemp", str(tmp_path / "guest"), str(ROOT / "tests" / "hil" / "socketcan")]
    env = {**os.environ, REFERENCE_ENV: str(ref_path), REQUIRE_ENV: "1"}
    res = subprocess.run(
        [sys.executable, "-m", "tools.cli", "sandbox", "--socketcan", "--", *inner],
        capture_output=True,
        text=True,
        timeout=1500,
        check=False,
        env=env,
        cwd=ROOT,
        stdin=subprocess.DEVNULL,
    )
    report = f"--- stdout\n{res.stdout}\n--- stderr\n{res.stderr}"
    print(report)  # each test's time in the guest: the lane's log shows it (pytest -rP, or -s)
    assert "user-mode Linux guest" in res.stderr, report
    assert res.returncode == 0, report
    tally = re.search(r"(\d+) passed", res.stdout)
    assert tally is not None and int(tally.group(1)) >= 4, report
    # nothing inside may skip: the guest has all the lane needs
    assert not re.findall(r"SKIPPED \[\d+\] ([^:]+):", res.stdout), report
