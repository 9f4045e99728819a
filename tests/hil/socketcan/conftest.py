"""The socketcan lane: tests that need SocketCAN with ``vcan0`` up.

Where the kernel has CAN and ``vcan0`` is up (a chair's computer, a CI runner with
vcan, or the user-mode Linux guest of ``wheelchair-hil sandbox --socketcan``) they run
here.  Elsewhere they are not collected: ``tests/hil/test_socketcan_lane.py`` boots one
guest and runs this whole directory inside it, once.

``WHEELCHAIR_HIL_REQUIRE_SOCKETCAN=1`` (set by ``.ci/run``) turns every reason to skip
these tests into a failure.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from dbc.codec import BenchStep, BenchStepAck, Codec
from tools.bus import umlguest
from tools.logs import mcap_io
from tools.run.processes import RT_OFFSETS, rt_option

REQUIRE_ENV = "WHEELCHAIR_HIL_REQUIRE_SOCKETCAN"
#: JSON file of virtual-bus summaries computed on the host: {scenario: summary} for EQUALITY_SCENARIOS
REFERENCE_ENV = "WHEELCHAIR_HIL_VIRTUAL_REFERENCE"
#: The scenarios the lock-step equality runs over vcan0.  The short route only: the paper
#: route (fault-free) took 122 s of the one-CPU guest's 312 s and checked nothing more (a
#: lock-step run's frames do not depend on its length; the recorder's window bounds every
#: kernel queue), and the fuzz test runs it through three processes over udp_multicast.
EQUALITY_SCENARIOS = ("short",)
VCAN_UP, VCAN_WHY = umlguest.host_can_ready("vcan0")

if not VCAN_UP:
    # not here: the guest runs them (tests/hil/test_socketcan_lane.py)
    collect_ignore_glob = ["test_*.py"]


def handshake_frames(log: Path) -> int:
    """``Bench_Step(0)`` and ``Bench_Step_Ack(0)`` frames in ``log``: the start-up handshake.

    The bench re-sends ``Bench_Step(0)`` every 100 ms of wall time until the controller's
    first ack (and the controller acks each), so their number depends on how fast the
    parts started, not on the run: the frame counts of two runs are compared without them.
    """
    codec = Codec.default()
    ids = {codec.frame_id(BenchStep), codec.frame_id(BenchStepAck)}
    n = 0
    for _t, msg in mcap_io.iter_frames(log):
        if msg.arbitration_id in ids and msg.is_extended_id and not any(msg.data[:8]):
            n += 1
    return n


#: The stack's command line, as a part of a test's run is started.
CLI = [sys.executable, "-m", "tools.cli"]
#: A real-time part on vcan0 along the short route.
REALTIME_VCAN = ["--bus", "socketcan", "--channel", "vcan0", "--realtime", "--scenario", "short"]


#: The SCHED_FIFO priority of the controller when a test starts a part on real-time
#: scheduling (``start_part(..., realtime=True)``): the bench runs one above it and the recorder
#: one below (``tools.run.processes.RT_OFFSETS``), as a chair's parts do.  The tests start only
#: the recorder so: in the guest's one CPU a recorder left on its default (niced) scheduling
#: was starved by the bench and the controller (it logged 4 s of a 20 s run and the kernel
#: dropped the rest), while a bench and a controller on SCHED_FIFO starve what the test runs
#: itself (``ip``, candump, its own reads of the bus) for seconds.
PART_RT_PRIORITY = 10


def start_part(
    tmp_path: Path, name: str, *argv: str, realtime: bool = False
) -> subprocess.Popen[str]:
    """``wheelchair-hil ARGV --ready``, its stderr in ``tmp_path/NAME.err``; returns once it
    printed READY (fails the test with that stderr if it did not).  ``realtime``: a bench,
    controller or recorder runs on SCHED_FIFO (:data:`PART_RT_PRIORITY`)."""
    err = tmp_path / f"{name}.err"
    rt = rt_option(argv[0], PART_RT_PRIORITY) if realtime and argv[0] in RT_OFFSETS else ()
    p = subprocess.Popen(
        [*CLI, *argv, *rt, "--ready"], stdout=subprocess.PIPE, stderr=err.open("w"), text=True
    )
    if p.stdout is None or p.stdout.readline().strip() != "READY":
        p.kill()
        p.wait()
        pytest.fail(f"{name} did not start: {err.read_text()}")
    return p


def skip_or_fail(reason: str) -> None:
    """Skip with ``reason``, or fail where the socketcan lane is required (CI)."""
    if os.environ.get(REQUIRE_ENV) == "1":
        pytest.fail(f"socketcan lane required ({REQUIRE_ENV}=1) but: {reason}")
    pytest.skip(reason)


@pytest.fixture(scope="session")
def virtual_reference(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, Any]]:
    """Virtual-bus summaries to compare with: from the host if it passed them, else run here."""
    path = os.environ.get(REFERENCE_ENV)
    if path and Path(path).exists():
        data: dict[str, dict[str, Any]] = json.loads(Path(path).read_text())
        return data
    from tests.integration.conftest import run_stack

    out = {}
    for name in EQUALITY_SCENARIOS:
        d = tmp_path_factory.mktemp(name)
        out[name] = run_stack(d, name, "baseline", recorder="thread")
        out[name]["handshake_frames"] = handshake_frames(d / "run.mcap")
    return out


#: The real-time tests here check what a kill or a downed interface does, not how fast a
#: host must be (tests/unit/controller and the safety suite test staleness and the
#: watchdog's own timing).  In the user-mode Linux guest, one CPU on a shared host, a part
#: can be descheduled for tens to hundreds of ms: the controller they start tolerates 400 ms
#: of silent feedback instead of 30 (200 ms once stopped a clean-clone CI run while arming, at
#: 220 ms), gives the drives 10 s instead of 2 to confirm closed loop (a clean-clone CI run
#: stopped for ARMING_TIMEOUT at 2.25 s, one drive still on its way), and sets the drives'
#: setpoint watchdog to 500 ms and their host timeout to 1 s, so that a busy host cannot stop
#: the chair before the event under test.  The tests' bounds use these values
#: (:data:`TOLERANT_WATCHDOG_S`).
TOLERANT_WATCHDOG_S = 0.5
TOLERANT_CHAIR = f"""\
[loop]
arming_timeout_s = 10.0

[safety]
encoder_stale_periods = 40
heartbeat_missed_max = 10

[drives]
watchdog_timeout_ms = {round(TOLERANT_WATCHDOG_S * 1000)}
host_timeout_ms = 1000
"""


@pytest.fixture
def tolerant_chair(tmp_path: Path) -> Path:
    """A chair config (``control --config``) for real time in a slow guest (see above)."""
    path = tmp_path / "chair-guest.toml"
    path.write_text(TOLERANT_CHAIR)
    return path
