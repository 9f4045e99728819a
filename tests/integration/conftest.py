"""Helpers to run the whole stack (bench, controller, recorder) in-process on the virtual bus."""

from __future__ import annotations

import itertools
import math
import multiprocessing.resource_tracker
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from controller.config import load_config
from dbc.codec import Codec
from tools.bus.transport import resolve
from tools.logs import summary_keys
from tools.metrics.tracking import BusCollector, BusSeries, read_bus_log, setpoint_frames
from tools.run import scenario as scenario_mod
from tools.run.experiment import run_experiment
from tools.run.in_process import run_threads
from tools.run.plan import make_plan
from tools.run.summary import build_summary

_channel = itertools.count()

#: Summary keys that depend on the wall clock or name the run's own bus: the only ones two
#: runs of the same scenario may differ in.
WALL_CLOCK_KEYS = {"bus", *summary_keys.WALL_CLOCK_KEYS}


@pytest.fixture(scope="module")
def resource_tracker() -> None:
    """Start multiprocessing's resource tracker before the tests that check for leaked
    children: a process pool starts it once and it stays for the whole session."""
    multiprocessing.resource_tracker.ensure_running()


def run_stack(
    out: Path,
    scenario: str = "short",
    controller: str | None = None,
    *,
    duration_s: float | None = None,
    seed: int | None = None,
    recorder: str = "process",
    one_thread: bool = True,
) -> dict[str, Any]:
    """Run one lock-step experiment on a fresh virtual channel; return its summary.

    ``recorder``, ``one_thread``: as :func:`tools.run.in_process.run_threads` takes them."""
    scen = scenario_mod.load(scenario)
    plan = make_plan(scen, controller, realtime=False, duration_s=duration_s, seed=seed)
    spec = resolve("virtual", f"test{next(_channel)}")
    out.mkdir(parents=True, exist_ok=True)
    run_threads(spec, plan, out, Codec.default(), recorder=recorder, one_thread=one_thread)
    return build_summary(out, plan, spec, 0.0)


def run_unlogged(
    out: Path, scenario: str, controller: str | None = None, *, duration_s: float | None = None
) -> tuple[dict[str, Any], BusSeries]:
    """A run as an evaluation's replicates run (``run_experiment(log=False)``): no MCAP, the
    summary and the bus frames it reads collected in this process; returns both.  For the
    tests of the laws' behaviour, which read no log: a logged run's two forked writers and
    its merge cost about as much CPU as the run itself."""
    bus = BusCollector()
    summary = run_experiment(
        out, scenario, controller, duration_s=duration_s, collector=bus, log=False
    )
    return summary, bus.series({}, {})


def setpoints(run: Path | BusSeries) -> dict[str, np.ndarray]:
    """Every wheel setpoint the controller sent, in order: from a run's directory (its log)
    or from the frames :func:`run_unlogged` collected."""
    names = [f"{side}_Set_Input_Vel{kind}" for side in ("Left", "Right") for kind in ("", "_Auth")]
    bus = run if isinstance(run, BusSeries) else read_bus_log(run / "run.mcap", names)
    return {
        side: np.asarray(setpoint_frames(bus, side).get("Input_Vel", []))
        for side in ("Left", "Right")
    }


def check_commands(run: Path | BusSeries) -> None:
    """Every wheel setpoint of the run finite, inside the chair's wheel limit, the first 0."""
    limit_revps = load_config().limits.wheel_max_radps / (2 * math.pi) + 1e-6
    sp = setpoints(run)
    for side in ("Left", "Right"):
        w = sp[side]
        assert w.size > 100
        assert np.all(np.isfinite(w))
        assert np.max(np.abs(w)) <= limit_revps, side
        assert w[0] == 0.0  # starts from rest (neutral command while arming)
