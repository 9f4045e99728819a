"""``wheelchair-hil soak`` for 3 minutes, as a user runs it: bench, controllers and recorders
over udp_multicast in its own private namespace, in real time, with every fault kind, the
rogue node and the signals of its schedule.  Judged by its report (physical and accounting
criteria from its own logs, in simulation time), never by wall-clock figures.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from firmware_sim.faultspec import KINDS
from tests.rt import RT_PRIORITY
from tools.bus import transport
from tools.soak import schedule

pytestmark = [
    pytest.mark.hil,
    pytest.mark.alone,
    pytest.mark.paired,
    pytest.mark.heavy(seconds=195),
]

SANDBOX_OK, SANDBOX_WHY = transport.sandbox_supported()
MINUTES, SEED = 3, 11


@pytest.mark.skipif(not SANDBOX_OK, reason=f"no private network namespace: {SANDBOX_WHY}")
def test_a_three_minute_soak_has_every_stop_explained_and_every_loss_counted(
    tmp_path: Path,
) -> None:
    out = tmp_path / "soak"
    argv = transport.python_argv(
        "soak",
        "--minutes",
        str(MINUTES),
        "--seed",
        str(SEED),
        "--out",
        str(out),
        "--rt-priority",
        str(RT_PRIORITY),
    )
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=MINUTES * 60 + 600)
    assert (out / "schedule.json").exists(), proc.stderr[-3000:]
    # the schedule was printed before the run
    assert schedule.build(SEED, MINUTES).describe()[0] in proc.stdout
    report = json.loads((out / "soak.json").read_text())
    summary = report["summary"]
    assert summary["failures"] == [], summary
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert summary["passed"] and summary["complete"] and summary["stops_unexplained"] == 0
    assert summary["losses_uncounted"] == 0 and summary["wheel_moved_after_stop"] == 0
    assert summary["fault_kinds_covered"] == f"{len(KINDS)}/{len(KINDS)}"
    assert summary["signals_covered"] == sorted(schedule.SIGNALS)
    assert summary["events_not_done"] == 0
    # the chair drove route after route: more than one controller, each stop accounted for
    assert summary["controllers"] >= 2
    # the recorder was restarted after its SIGTERM and its SIGKILL: three logs at least
    assert summary["recorders"] >= 3
    assert all(log["last_s"] > log["first_s"] for log in report["logs"])
    assert report["memory"]["sim"]["growth_mib_per_min"] is not None
