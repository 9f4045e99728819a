"""Runs that share their start (tools.run.branches): each branch, forked from the trunk just
before the first fault, gives what a fresh run of its scenario gives, figure for figure."""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from tests.integration.conftest import WALL_CLOCK_KEYS
from tools.run import branches
from tools.run import scenario as scenario_mod
from tools.run.experiment import run_experiment
from tools.run.plan import make_plan

#: the faults start at 20 s: 23 s is the shared start and 3 s of faults
DURATION_S = 23.0


def _figures(summary: dict[str, Any]) -> dict[str, Any]:
    kept = {k: v for k, v in summary.items() if k not in WALL_CLOCK_KEYS}
    return dict(json.loads(json.dumps(kept, sort_keys=True, default=str)))


def _scenarios(names: list[str], setting: str) -> list[scenario_mod.Scenario]:
    return [scenario_mod.with_setting(scenario_mod.load(n), setting) for n in names]


def _keep(i: int, summary: dict[str, Any], frames: Any, started: float) -> dict[str, Any]:
    return {"pid": os.getpid(), "summary": summary}


def _branched(names: list[str], setting: str, controller: str, scratch: Path) -> list[Any]:
    """run_branches in a process of its own: a test process has threads (pytest-xdist's),
    where run_branches does not fork but runs each scenario afresh."""
    return branches.run_branches(
        _scenarios(names, setting), controller, scratch, _keep, duration_s=DURATION_S
    )


@pytest.mark.parametrize(
    ("names", "setting", "controller"),
    [
        # bench faults: the trunk has none, the branches a bump and a (physical) flat tire
        (["fault-free", "bump-left", "flat-right"], "physical", "antifragile"),
        # sensor faults in the controller's odometry (the paper's flat tire)
        (["flat-left", "flat-right"], "paper", "robust"),
    ],
)
def test_each_branch_is_the_fresh_run_of_its_scenario(
    tmp_path: Path, names: list[str], setting: str, controller: str, resource_tracker: None
) -> None:
    scens = _scenarios(names, setting)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        out = pool.submit(_branched, names, setting, controller, tmp_path / "scratch").result()
    assert not [o for o in out if isinstance(o, branches.BranchError)], out
    # the branches ran in processes of their own: the run was shared, not repeated
    assert len({o["pid"] for o in out}) == len(names)
    for name, scen, o in zip(names, scens, out, strict=True):
        fresh = run_experiment(tmp_path / name, scen, controller, duration_s=DURATION_S, log=False)
        assert fresh["samples"] > 1500 and fresh["scenario"] == name
        assert _figures(o["summary"]) == _figures(fresh), name


def test_runs_that_differ_before_their_faults_are_not_branched() -> None:
    step_ns = 10_000_000
    plans = [
        make_plan(s, "baseline", realtime=False) for s in _scenarios(["fault-free"], "physical")
    ]
    assert branches.branch_point(plans, step_ns) == (None, "one run")
    mixed = [
        make_plan(s, "baseline", realtime=False)
        for s in (*_scenarios(["fault-free"], "paper"), *_scenarios(["flat-left"], "paper"))
    ]
    assert branches.branch_point(mixed, step_ns)[1] == "sensor faults in some runs only"
    a, b = _scenarios(["fault-free", "bump-left"], "physical")
    moved = dataclasses.replace(b, params=dataclasses.replace(b.params, seed=99))
    plans = [make_plan(s, "baseline", realtime=False) for s in (a, moved)]
    assert branches.branch_point(plans, step_ns)[0] is None
    plans = [make_plan(s, "baseline", realtime=False) for s in (a, b)]
    fork_ns, why = branches.branch_point(plans, step_ns)
    assert why == "" and fork_ns == 20_000_000_000 - 2 * step_ns
