"""A run's summary is computed from the frames kept in memory while it runs
(``tools.logs.collect``): it is the summary of its log (``wheelchair-hil summarize``), figure
for figure, and a run without a log (``run_experiment(log=False)``, an evaluation's
Monte-Carlo replicates) gives the same one and writes no MCAP."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from controller.limits import RATE_LIMITS
from tests.integration.conftest import WALL_CLOCK_KEYS
from tools.logs import runlog
from tools.run import scenario as scenario_mod
from tools.run.experiment import run_experiment


def _comparable(summary: dict[str, Any]) -> dict[str, Any]:
    return json.loads(
        json.dumps(
            {k: v for k, v in summary.items() if k not in WALL_CLOCK_KEYS},
            sort_keys=True,
            default=str,
        )
    )


@pytest.mark.parametrize(
    ("scenario", "setting", "controller"),
    [
        ("flat-left", "physical", "antifragile"),
        ("bump-right", "diagnosed", "adaptive"),
    ],
)
def test_the_summary_of_a_run_is_its_logs_and_a_run_without_a_log_gives_it_too(
    tmp_path: Path, scenario: str, setting: str, controller: str
) -> None:
    # 23 s: the fault starts at 20 s, so the diagnosis, the fault window and the tracking
    # figures all have something to say
    scen = scenario_mod.with_setting(scenario_mod.load(scenario), setting)
    logged = run_experiment(tmp_path / "logged", scen, controller, duration_s=23.0)
    unlogged = run_experiment(tmp_path / "unlogged", scen, controller, duration_s=23.0, log=False)
    assert (tmp_path / "logged" / "run.mcap").exists()
    assert not (tmp_path / "unlogged" / "run.mcap").exists()
    assert not (tmp_path / "unlogged" / "controller.mcap").exists()
    assert logged["complete"] and logged["samples"] > 1000
    assert logged["fault_diagnosis"]["injected"] == scenario
    from_log = runlog.summarize(tmp_path / "logged" / "run.mcap")
    assert _comparable(logged) == _comparable({**from_log, "bus": logged["bus"]})
    assert _comparable(unlogged) == _comparable(logged)
    # how the law met the envelope and what it did, with or without a log, in summary.json
    for name in ("logged", "unlogged"):
        written = json.loads((tmp_path / name / "summary.json").read_text())
        rates, acts = written["rate_limit_share"], written["law_activity_share"]
        assert list(rates) == list(RATE_LIMITS)
        assert all(0.0 <= v <= 1.0 for v in (*rates.values(), *acts.values())), written
        # the estimator's health: its 10 Hz fixes fused (23 s), nothing refused or rolled back
        est = written["estimator"]
        assert est["fixes_fused"] > 150 and est["bank_fixes_used"] > 150, est
        assert est["nonfinite_inputs"] == 0 and est["numerical_failures"] == 0, est
    if controller == "adaptive":  # counts its solves (controller.tracking.mpc)
        assert logged["law_activity_share"]["qp_solved"] > 0.9


def test_a_run_without_a_log_leaves_an_earlier_runs_log_in_its_directory_as_it_was(
    tmp_path: Path,
) -> None:
    # an earlier run's log in the same directory is not this run's: finalizing it would
    # rewrite it with this run's metadata (and cost a merge of a log nobody asked for)
    scen = scenario_mod.load("short")
    run_experiment(tmp_path, scen, "baseline", duration_s=3.0)
    log = tmp_path / "run.mcap"
    before = log.read_bytes()
    unlogged = run_experiment(tmp_path, scen, "robust", duration_s=2.0, seed=7, log=False)
    assert unlogged["controller"] == "robust" and unlogged["seed"] == 7
    assert log.read_bytes() == before
    assert runlog.summarize(log)["controller"] == "baseline"
