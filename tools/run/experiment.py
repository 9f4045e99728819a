"""One experiment as a function: a scenario (possibly modified), a controller, a seed -> summary.

This is the entry point for evaluation campaigns and benchmarks: it runs the whole
stack (bench, controller, recorder) in lock-step on python-can's virtual bus inside
the calling process, writes ``out/run.mcap`` and ``out/summary.json`` and returns the
summary.  Callers that vary a scenario build a modified :class:`~tools.run.scenario.Scenario`
with :func:`dataclasses.replace` (bench overrides, fault schedule, initial offset,
seed) instead of writing files.
"""

from __future__ import annotations

import itertools
import os
import time
from pathlib import Path
from typing import Any

from dbc.codec import Codec
from dbc.runtime import jsonsafe
from tools.bus.transport import resolve
from tools.metrics.tracking import BusCollector
from tools.run import scenario as scenario_mod
from tools.run.in_process import run_threads
from tools.run.plan import make_plan
from tools.run.scenario import Scenario
from tools.run.summary import build_summary

_channels = itertools.count()


def run_experiment(
    out: str | Path,
    scenario: str | Scenario,
    controller: str | None = None,
    *,
    seed: int | None = None,
    duration_s: float | None = None,
    collector: BusCollector | None = None,
    log: bool = True,
) -> dict[str, Any]:
    """Run one lock-step experiment in this process; return (and write) its summary.

    The summary is computed from the frames kept in memory while the run goes
    (:mod:`tools.logs.collect`: the same figures as from the log, without reading it back).
    ``collector`` gets those decoded bus messages, and its extra (controller) topics from the
    log while it is merged.  ``log=False``: no ``run.mcap`` and no controller log (the extra
    topics stay empty).

    ``scenario`` is a name, a path, or a :class:`Scenario` object.  Each call uses its
    own virtual channel, so experiments may run concurrently in threads of one process
    only if they do not share ``out``; campaigns use one process per worker.
    """
    scen = scenario if isinstance(scenario, Scenario) else scenario_mod.load(scenario)
    plan = make_plan(scen, controller, realtime=False, duration_s=duration_s, seed=seed)
    spec = resolve("virtual", f"experiment-{os.getpid()}-{next(_channels)}")
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    results = run_threads(
        spec, plan, out_dir, Codec.default(), recorder="process" if log else "none", collect=True
    )
    # the summary from the frames kept in memory; the merge of the log (if any) feeds only
    # the caller's other topics (the controller's), not the bus channels again
    merged = BusCollector(names=(), extra_topics=collector.extra) if collector and log else None
    summary = build_summary(out_dir, plan, spec, time.monotonic() - t0, merged, results=results)
    if collector is not None:
        collector.columns.update(results["frames"].series.columns)
        if merged is not None:
            collector.columns.update(merged.columns)
    (out_dir / "summary.json").write_text(jsonsafe.dumps(summary, indent=2, default=str) + "\n")
    return summary
