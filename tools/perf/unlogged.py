"""The CPU time of a campaign's run: the paper route in lock-step, without a log, in one process.

``python -m tools.perf.unlogged [--controllers baseline,antifragile] [--runs 3]``

What a worker of ``wheelchair-hil evaluate`` spends on each replicate
(:func:`tools.run.experiment.run_experiment` with ``log=False``: no recorder process, no
controller log, the figures from the frames kept in memory). After one run that pays the
process's imports and the route's planning, each law runs ``--runs`` times; the process's CPU
time (user and system) of each run is printed, with the minimum and the median, the simulated
seconds per CPU second (the lock-step factor of one core given to this run alone) and the
run's position RMSE (the same in every build: its frames, not its speed).  Run it with
``PYTHONPATH`` set to another tree (its compiled modules built there) to compare two builds
side by side, in turn, on the same machine.
"""

from __future__ import annotations

import argparse
import logging
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from tools.perf.common import PAPER

DEFAULT_CONTROLLERS = "baseline"


def cpu_of_runs(controller: str, runs: int, where: Path) -> tuple[list[float], dict[str, Any]]:
    """(CPU seconds of each of ``runs`` unlogged runs of ``controller``, the last run's
    summary), after one run not counted."""
    from tools.run.experiment import run_experiment  # lazy: --help without the stack

    run_experiment(where / "warm", PAPER, controller, log=False)
    out = []
    summary: dict[str, Any] = {}
    for i in range(runs):
        t0 = time.process_time()
        summary = run_experiment(where / f"run{i}", PAPER, controller, log=False)
        out.append(time.process_time() - t0)
    return out, summary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.perf.unlogged", description=__doc__)
    ap.add_argument("--controllers", default=DEFAULT_CONTROLLERS, help="default baseline")
    ap.add_argument("--runs", type=int, default=3, help="runs of each law counted (default 3)")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error(f"--runs must be at least 1, not {args.runs}")
    logging.basicConfig(level=logging.ERROR)  # the test key's warning once per run
    print("| controller | CPU s per run (each) | min | median | simulated s per CPU s | RMSE (m) |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="unlogged-") as tmp:
        for name in (c.strip() for c in args.controllers.split(",") if c.strip()):
            cpu, summary = cpu_of_runs(name, args.runs, Path(tmp) / name)
            med = statistics.median(cpu)
            each = " ".join(f"{c:.3f}" for c in cpu)
            factor = float(summary["sim_duration_s"]) / med
            print(
                f"| {name} | {each} | {min(cpu):.3f} | {med:.3f} | {factor:.1f}x "
                f"| {summary['rmse_pos_m']!r} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
