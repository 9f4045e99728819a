"""tools.perf.unlogged: each run's CPU time, its minimum and median, and the run's figures."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tools.perf import unlogged


def test_the_table_gives_each_run_the_minimum_the_median_and_the_factor(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    asked: list[tuple[str, int]] = []

    def fake(controller: str, runs: int, where: Path) -> tuple[list[float], dict[str, Any]]:
        asked.append((controller, runs))
        return [2.0, 1.0, 4.0], {"sim_duration_s": 87.5, "rmse_pos_m": 0.0061}

    monkeypatch.setattr(unlogged, "cpu_of_runs", fake)
    assert unlogged.main(["--controllers", "baseline, robust", "--runs", "3"]) == 0
    out = capsys.readouterr().out
    assert asked == [("baseline", 3), ("robust", 3)]
    # median 2.0 s: 87.5 / 2.0 = 43.75 simulated seconds per CPU second
    assert "| baseline | 2.000 1.000 4.000 | 1.000 | 2.000 | 43.8x | 0.0061 |" in out


def test_fewer_than_one_run_is_refused_naming_the_option(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit):
        unlogged.main(["--runs", "0"])
    assert "--runs must be at least 1, not 0" in capsys.readouterr().err
