"""Arguments of ``wheelchair-hil tune`` and its action: tune a controller's gains the same way
as every other's (tools/tuning/tune.py, docs/evaluation.md "Tuning")."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dbc.runtime.errors import ConfigError
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


def summary_line(name: str, p: Mapping[str, Any]) -> str:
    """One line per tuned controller: objective start -> end, evaluations, converged,
    keys on an edge."""
    edges = ", ".join(
        f"{k} ({e['side']}{', at its limit' if e['at_limit'] else ''})"
        for k, e in p["on_edge"].items()
    )
    return (
        f"tune {name}: objective {p['objective_start']:.5f} -> {p['objective_value']:.5f}, "
        f"{p['evaluations']}/{p['budget_evaluations']} evaluations ({p['runs']} runs, "
        f"{p['wall_s']:.0f} s), converged: {'yes' if p['converged'] else 'no'}, "
        f"on an edge: {edges or 'none'}"
    )


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Tune each controller the arguments name (every one checked before any run), print a
    line per controller and its gains."""
    from controller.tracking import registry  # lazy: the stack
    from tools.run import scenario as scenario_mod  # lazy
    from tools.tuning.search import check_budget  # lazy: numpy, scipy
    from tools.tuning.space import SPACE_FILE, method, space, tunable  # lazy
    from tools.tuning.tune import tune  # lazy

    space_file = Path(args.space) if getattr(args, "space", None) else SPACE_FILE
    if not space_file.is_file():
        raise ConfigError(f"--space {space_file}: no such file")
    names = (
        tunable(path=space_file)
        if args.controller == "all"
        else [registry.canonical(n) for n in args.controller.split(",")]
    )
    m = method(path=space_file)
    for name in names:  # TuningError or ConfigError naming it, before any run
        check_budget(args.budget, m, len(space(name, path=space_file)), name)
    out = Path(args.out) if args.out else None
    gains_path = Path(args.gains_file)
    if not gains_path.is_absolute() and not gains_path.parent.is_dir():
        # the default, from anywhere: among the packaged scenarios
        parts = gains_path.parts[1:] if gains_path.parts[:1] == ("scenarios",) else gains_path.parts
        gains_path = scenario_mod.SCENARIO_DIR.joinpath(*parts)
    for name in names:
        res = tune(
            name,
            budget=args.budget,
            workers=args.workers,
            out=out / name if out else None,
            gains_file=None if args.dry_run else gains_path,
            space_file=space_file,
            progress=None if args.no_progress else (lambda m: print(m, file=sys.stderr)),
        )
        print(summary_line(name, res["provenance"]))
        print(f"  gains: {json.dumps(res['gains'], sort_keys=True)}")
    if not args.dry_run:
        print(f"  written to {gains_path}")
    return 0
