"""Three processes over SocketCAN vcan0, lock-step: the virtual bus's figures, every frame."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from .conftest import EQUALITY_SCENARIOS, handshake_frames

pytestmark = pytest.mark.hil

TRACKING_KEYS = (
    "rmse_xe_m",
    "rmse_ye_m",
    "rmse_phie_rad",
    "rmse_pos_m",
    "max_pos_err_m",
    "max_phie_rad",
    "samples",
)


def _run(out: Path, scenario: str, *extra: str, env: dict[str, str] | None = None) -> Any:
    import os

    return subprocess.run(
        [
            sys.executable,
            "-m",
            "tools.cli",
            "run",
            "--controller",
            "baseline",
            "--scenario",
            scenario,
            "--bus",
            "socketcan",
            "--channel",
            "vcan0",
            "--out",
            str(out),
            *extra,
        ],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
        env={**os.environ, **(env or {})},
    )


@pytest.mark.parametrize("scenario", EQUALITY_SCENARIOS)
def test_three_processes_over_vcan0_match_the_virtual_bus(
    tmp_path: Path, scenario: str, virtual_reference: dict[str, dict[str, Any]]
) -> None:
    ref = virtual_reference[scenario]
    res = _run(tmp_path, scenario)
    assert res.returncode == 0, res.stderr + res.stdout
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["complete"] is True, s.get("lost_frames")
    assert s["bus"] == "socketcan:vcan0"
    assert s["stop_reason"] == "ROUTE_DONE"
    for key in TRACKING_KEYS:
        assert s[key] == pytest.approx(ref[key], abs=1e-6), key
    # every frame, less the start-up handshake's re-sends (their number is wall time)
    ours = s["frames_total"] - handshake_frames(tmp_path / "run.mcap")
    assert ours == ref["frames_total"] - ref["handshake_frames"]
    for part in ("bench_stats", "controller_stats", "recorder_stats"):
        stats = json.loads((tmp_path / f"{part}.json").read_text())
        assert stats["rx_dropped"] == 0, part
        assert stats["rx_buffer_bytes"] > 0, part


def test_a_tiny_receive_buffer_makes_the_run_fail_naming_the_part_and_the_count(
    tmp_path: Path,
) -> None:
    res = _run(tmp_path, "short", "--duration", "6", env={"WHEELCHAIR_HIL_RCVBUF": "record=4096"})
    assert res.returncode != 0
    assert "lost" in res.stderr and "record" in res.stderr, res.stderr
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["complete"] is False
    assert s["lost_frames"]["record"] > 0
    assert s["rmse_pos_m"] is None  # no figure from a partial log passes for a whole one
    assert "INCOMPLETE" in res.stdout
    assert "position RMSE" not in res.stdout
