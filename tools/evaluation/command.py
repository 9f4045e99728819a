"""``wheelchair-hil evaluate``: the paper's experiments as a campaign of lock-step runs.

:func:`evaluate` plans the campaign (:mod:`tools.evaluation.campaign`), runs it
(:mod:`tools.evaluation.execute`, resuming from earlier runs on request), assembles
``results.json`` (:mod:`tools.evaluation.assemble`) and writes the figures and ``report.md``;
:func:`run` is the command line's entry.
"""

from __future__ import annotations

import argparse
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
from tools.evaluation.plan import EvaluationError
from tools.evaluation.task import load_cached
from tools.run import scenario as scenario_mod


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


def _repo_path(p: str) -> Path:
    """A relative path as given if it exists here, else among the packaged scenarios (for
    ``scenarios/...``) or relative to the repository."""
    path = Path(p)
    if path.is_absolute() or path.exists():
        return path
    if path.parts and path.parts[0] == "scenarios":
        return scenario_mod.SCENARIO_DIR.joinpath(*path.parts[1:])
    return scenario_mod.REPO_ROOT / path


def run(args: argparse.Namespace, argv: list[str]) -> int:
    opt = Options(
        controllers=tuple(args.controllers),
        scenarios=tuple(args.scenarios),
        seed=args.seed,
        seeds=args.seeds[0],
        seeds_per_setting=args.seeds[1],
        cascaded=not args.no_cascaded,
        spectrum=args.spectrum,
        spectrum_faults=tuple(args.spectrum_faults),
        spectrum_seeds=args.spectrum_seeds,
        exposure=args.exposure,
        duration_s=args.duration,
        settings=tuple(args.settings),
        gains=None if args.gains == "none" else str(_repo_path(args.gains)),
        logs=args.logs,
        reference_mc=args.reference_mc,
        cascade_seeds=args.cascade_seeds,
    )
    if args.workers < 1:
        raise EvaluationError(f"--workers {args.workers}: must be at least 1")
    results = evaluate(
        opt,
        args.out,
        workers=args.workers,
        scheduler=args.scheduler,
        progress=not args.no_progress,
        figures=not args.no_figures,
        resume=args.resume,
    )

    print(report_mod.console_summary(results, Path(args.out)))
    return 1 if results["meta"]["failed_runs"] else 0
