"""Arguments of ``wheelchair-hil tune``: tune a controller's gains the same way as every
other's (tools/tuning/tune.py, docs/evaluation.md "Tuning")."""

from __future__ import annotations

import argparse

from tools.evaluation.plan import TUNED_GAINS

#: Objective evaluations per controller, the x0 stage's Sobol points included (each runs
#: every tuning scenario once).  Sized on stubbed objectives (python -m tools.tuning.sizing,
#: docs/evaluation.md "Tuning"): 120 bowls converged in a median of 108, at most 210.
DEFAULT_BUDGET = 250


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--controller",
        required=True,
        metavar="NAME",
        help="controller to tune, a comma-separated list, or 'all' (every controller "
        "scenarios/tuning/space.toml gives boxes to; no other is tuned)",
    )
    p.add_argument(
        "--budget",
        type=int,
        default=DEFAULT_BUDGET,
        metavar="N",
        help=f"objective evaluations per controller, the x0 stage's included (default "
        f"{DEFAULT_BUDGET}; the same for every controller)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=2,
        help="worker processes for the runs: the x0 stage's points and each "
        "evaluation's scenarios (default 2)",
    )
    p.add_argument("--out", default=None, help="directory for the runs and tuning.json")
    p.add_argument(
        "--gains-file",
        default=TUNED_GAINS,
        metavar="FILE",
        help=f"tuned gains file to update (default {TUNED_GAINS})",
    )
    p.add_argument(
        "--space",
        default=None,
        metavar="FILE",
        help="the search space: [NAME] boxes of the gains to tune (default "
        "scenarios/tuning/space.toml; a controller of your own: a file with its own [NAME], "
        "the packaged [method] applies unless the file has one)",
    )
    p.add_argument("--dry-run", action="store_true", help="tune, but write no gains file")
    p.add_argument("--no-progress", action="store_true", help="no line per evaluation")
