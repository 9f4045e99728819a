"""A campaign from its options to its report, through the evaluation's three layers:
:func:`evaluate` plans the campaign and runs it (the runs: :mod:`tools.evaluation.campaign`,
:mod:`tools.evaluation.execute`, resuming from earlier runs on request), assembles
``results.json`` from them (the results: :mod:`tools.evaluation.assemble`) and writes the
figures and ``report.md`` from that (the presentation: :mod:`tools.evaluation.figures`,
:mod:`tools.evaluation.report`).  ``wheelchair-hil evaluate`` (tools/cli/evaluate.py) is its
command line.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

from tools.evaluation import figures as figures_mod
from tools.evaluation import report as report_mod
from tools.evaluation.assemble import build_results, write_results
from tools.evaluation.campaign import Options, plan_campaign
from tools.evaluation.execute import execute
from tools.evaluation.task import load_cached


def evaluate(
    opt: Options,
    out: str | Path,
    *,
    workers: int = 1,
    scheduler: Any = None,
    progress: bool = True,
    figures: bool = True,
    report: bool = True,
    resume: bool = False,
) -> dict[str, Any]:
    """Plan, run and write a campaign into ``out``; return ``results.json``'s content.

    ``resume``: reuse the runs already in ``out`` whose ``result.json`` records the same task
    (an interrupted campaign goes on where it stopped; their timing says ``resumed``).
    """
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    camp = plan_campaign(opt)
    t0 = time.monotonic()
    runs: dict[str, dict[str, Any]] = {}
    if resume:
        for key, task in camp.tasks.items():
            if (cached := load_cached(out_dir, task)) is not None:
                runs[key] = cached
    todo = [t for k, t in camp.tasks.items() if k not in runs]
    runs.update(
        execute(
            todo,
            out_dir,
            workers=workers,
            scheduler=scheduler,
            progress=progress,
            table=opt.scenarios,
        )
    )
    shutil.rmtree(out_dir / "runs" / ".branches", ignore_errors=True)
    for k, r in runs.items():  # a remote worker's series reach this machine here
        path = out_dir / "runs" / k / "series.npz"
        if r.get("series") and not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            savez: Any = np.savez_compressed
            savez(path, **r["series"])
    executor = (
        f"dask {scheduler}"
        if isinstance(scheduler, str)
        else ("dask cluster" if scheduler is not None else f"{workers} worker process(es)")
    )
    results = build_results(
        camp, runs, time.monotonic() - t0, executor, workers if scheduler is None else 1
    )
    made: list[str] = []
    if figures:
        made = figures_mod.make_all(results, out_dir)
    results["timing"]["total_wall_s"] = time.monotonic() - t0
    write_results(results, out_dir / "results.json")
    if report:
        report_mod.write_report(results, out_dir, made)
    return results
