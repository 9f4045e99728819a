"""A run whose parts lost frames is marked incomplete; ``run`` says how it chose its bus."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tools.cli import run as run_command
from tools.logs import runlog
from tools.run import summary


def _summary() -> dict[str, object]:
    return {
        "controller": "baseline",
        "scenario": "short",
        "mode": "lockstep",
        "bus": "socketcan:vcan0",
        "rmse_pos_m": 0.0306,
        "max_pos_err_m": 0.358,
        "samples": 900,
        "frames_total": 6595,
        "stop_reason": "ROUTE_DONE",
    }


def test_a_part_with_kernel_drops_makes_the_summary_incomplete_and_withholds_the_figures(
    tmp_path: Path,
) -> None:
    (tmp_path / "recorder_stats.json").write_text(json.dumps({"rx_dropped": 9738}))
    (tmp_path / "controller_stats.json").write_text(json.dumps({"rx_dropped": 0}))
    lost = summary.lost_frames(tmp_path)
    assert lost == {"record": 9738}
    s = runlog.mark_completeness(_summary(), lost)
    assert s["complete"] is False
    assert s["rmse_pos_m"] is None and s["samples"] is None
    assert s["partial"] == {"rmse_pos_m": 0.0306, "max_pos_err_m": 0.358, "samples": 900}
    text = summary.format_summary(s)
    assert "INCOMPLETE" in text and "record lost 9738 frames" in text
    assert "RMSE" not in text


def test_missing_steps_in_the_recorders_log_count_as_loss(tmp_path: Path) -> None:
    (tmp_path / "recorder_stats.json").write_text(json.dumps({"rx_dropped": 0, "missed_steps": 5}))
    assert summary.lost_frames(tmp_path) == {"record": 5}


def test_a_whole_run_keeps_its_figures(tmp_path: Path) -> None:
    s = runlog.mark_completeness(_summary(), summary.lost_frames(tmp_path))
    assert s["complete"] is True and s["rmse_pos_m"] == 0.0306
    assert "position RMSE 3.06 cm" in summary.format_summary({**s, "max_phie_rad": 0.1})


def test_run_says_chosen_when_python_cans_configuration_picked_the_bus(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("CAN_INTERFACE", "socketcan")
    assert run_command.choose_bus(None) == ("socketcan", "chosen: from CAN_INTERFACE=socketcan")
    assert run_command.choose_bus("virtual") == ("virtual", "as requested")
    monkeypatch.delenv("CAN_INTERFACE")
    _iface, why = run_command.choose_bus(None)
    assert why.startswith("chosen: ") and "as requested" not in why
