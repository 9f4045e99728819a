"""``wheelchair-hil evaluate``: the paper's experiments as a campaign, its arguments and its action.

Run the paper's table (and optionally Monte-Carlo cells, amplitude sweeps and repeated
exposures) in lock-step, in parallel; see docs/evaluation.md.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from tools.cli.options import controller_name
from tools.evaluation.plan import (
    DEFAULT_CONTROLLERS,
    FAULT_SETTINGS,
    PAPER_SCENARIOS,
    SPECTRUM_FAULTS,
    TUNED_GAINS,
    EvaluationError,
)


def _csv(value: str) -> tuple[str, ...]:
    items = tuple(v.strip() for v in value.split(",") if v.strip())
    if not items:
        raise argparse.ArgumentTypeError("expected a comma-separated list")
    return items


def _names(value: str) -> tuple[str, ...]:
    """Controller names, case-insensitive (``ANTIFRAGILE,robust``)."""
    return tuple(controller_name(v) for v in _csv(value))


def _seeds(text: str) -> tuple[int, tuple[tuple[str, int], ...]]:
    """``N``, ``SETTING=N,...`` or ``N,SETTING=N,...``: (replicates elsewhere, per setting)."""
    default, per = 1, []
    for i, part in enumerate(p.strip() for p in text.split(",")):
        name, eq, value = part.partition("=")
        try:
            n = int(value if eq else name)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{part!r}: give N or SETTING=N (for example paper=20,physical=10)"
            ) from None
        if not eq:
            if i:
                raise argparse.ArgumentTypeError(f"{part!r}: a bare N comes first")
            default = n
        else:
            per.append((name.strip(), n))
    return default, tuple(per)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument(
        "--controllers",
        type=_names,
        default=DEFAULT_CONTROLLERS,
        help=f"comma-separated (default {','.join(DEFAULT_CONTROLLERS)}; baseline is a "
        "reference row, not ranked)",
    )
    p.add_argument(
        "--scenarios",
        type=_csv,
        default=PAPER_SCENARIOS,
        help=f"table columns (default the paper's: {','.join(PAPER_SCENARIOS)})",
    )
    p.add_argument(
        "--settings",
        type=_csv,
        default=FAULT_SETTINGS,
        help=f"fault settings, the first one primary (default {','.join(FAULT_SETTINGS)}): "
        "paper = flat tires as sensor faults in the controller's odometry, bumps on the "
        "bench; physical = every fault on the bench; diagnosed = physical plus the filter "
        "bank's radii fed back into odometry",
    )
    p.add_argument(
        "--gains",
        default=TUNED_GAINS,
        metavar="FILE",
        help=f"tuned gains (default {TUNED_GAINS}, written by `wheelchair-hil tune`); "
        "'none': controller/gains.toml as it is",
    )
    p.add_argument("--seed", type=int, default=1, help="base seed of the campaign (default 1)")
    p.add_argument(
        "--seeds",
        type=_seeds,
        default=(1, ()),
        metavar="N|SETTING=N,...",
        help="N > 1: N Monte-Carlo replicates per cell besides the nominal run (noise, onset, "
        "amplitude, initial pose, mass); per setting: paper=20,physical=10,diagnosed=10 "
        "(a setting not named: 1, or N given alone first: 5,paper=20)",
    )
    p.add_argument("--spectrum", action="store_true", help="sweep each fault's amplitude")
    p.add_argument(
        "--spectrum-faults",
        type=_csv,
        default=SPECTRUM_FAULTS,
        help=f"faults to sweep (default {','.join(SPECTRUM_FAULTS)})",
    )
    p.add_argument(
        "--spectrum-seeds",
        type=int,
        default=3,
        metavar="R",
        help="replicates per sweep for the noise band (default 3: nominal + 2 Monte-Carlo)",
    )
    p.add_argument(
        "--exposure",
        action="store_true",
        help="repeated exposures to the same fault, per controller",
    )
    p.add_argument(
        "--logs",
        choices=("nominal", "all"),
        default="nominal",
        help="which runs keep their MCAP log and time series: nominal (the primary fault "
        "setting's nominal runs, which the figures draw; the others keep only their figures, "
        "the same numbers in a third of the time), or all (default nominal)",
    )
    p.add_argument(
        "--reference-mc",
        action="store_true",
        help="Monte-Carlo replicates for the reference row (BASELINE) too",
    )
    p.add_argument(
        "--cascade-seeds",
        type=int,
        default=0,
        metavar="N",
        help="N replicates of the cascaded run with its faults at random moments and "
        "magnitudes (the paper's text; default 0: Fig. 13's fixed schedule only)",
    )
    p.add_argument("--no-cascaded", action="store_true", help="skip the cascaded runs (Fig. 13)")
    p.add_argument("--no-figures", action="store_true", help="write no PNG")
    p.add_argument(
        "--workers",
        type=int,
        default=max(1, os.cpu_count() or 1),
        help="worker processes (default: one per CPU)",
    )
    p.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run on a Dask cluster (e.g. tcp://host:8786); needs the [dask] extra and "
        "--out on a filesystem the workers share for the MCAP logs",
    )
    p.add_argument(
        "--duration", type=float, default=None, help="simulated seconds per run (default: full)"
    )
    p.add_argument(
        "--no-progress",
        action="store_true",
        help="no progress on stderr (a bar on a terminal, else a line per 10 %% of the runs)",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="reuse the runs already in --out that were made for the same task",
    )


def _repo_path(p: str) -> Path:
    """A relative path as given if it exists here, else among the packaged scenarios (for
    ``scenarios/...``) or relative to the repository."""
    from tools.run import scenario as scenario_mod  # lazy: numpy

    path = Path(p)
    if path.is_absolute() or path.exists():
        return path
    if path.parts and path.parts[0] == "scenarios":
        return scenario_mod.SCENARIO_DIR.joinpath(*path.parts[1:])
    return scenario_mod.REPO_ROOT / path


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Run the campaign the arguments describe, print its summary; 1 if a run failed."""
    from tools.evaluation.campaign import Options  # lazy: numpy, scipy, the stack
    from tools.evaluation.pipeline import evaluate  # lazy
    from tools.evaluation.report import console_summary  # lazy

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

    print(console_summary(results, Path(args.out)))
    return 1 if results["meta"]["failed_runs"] else 0
