"""Arguments of ``wheelchair-hil bench`` and its action: the benchmark suite (tools/perf/)."""

from __future__ import annotations

import argparse
from pathlib import Path

from dbc.runtime import jsonsafe


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", default=None, metavar="FILE", help="also write the figures as JSON")
    p.add_argument(
        "--quick", action="store_true", help="short version (fewer steps and states, 10 s loop)"
    )
    p.add_argument(
        "--rt-seconds", type=float, default=60.0, help="length of the real-time loop run"
    )
    p.add_argument("--rt-priority", type=int, default=10, help="SCHED_FIFO priority to ask for")
    p.add_argument(
        "--case",
        choices=("all", "live", "breakdown"),
        default="all",
        help="live: only the live view's cost per tick (real-time runs of --rt-seconds without "
        "the view, with it, with a client and with a slow client); breakdown: only where a "
        "lock-step step of the paper route goes, by component, for --controllers",
    )
    p.add_argument(
        "--rounds", type=int, default=2, help="--case live: runs per case (alternating order)"
    )
    p.add_argument(
        "--steps-only",
        action="store_true",
        help="only the controllers' step() times (p50 / p99) in an offline closed loop",
    )
    p.add_argument(
        "--controllers",
        default=None,
        metavar="A,B",
        help="with --steps-only or --case breakdown: these controllers (default: every "
        "registered one)",
    )


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Run the benchmarks the arguments choose, print their table, write ``--json``."""
    from tools.perf import bench  # lazy: the stack, numpy
    from tools.perf.breakdown import format_breakdown  # lazy
    from tools.perf.live import format_live  # lazy

    rt_seconds = min(args.rt_seconds, 10.0) if args.quick else args.rt_seconds
    if args.case == "live":
        r = bench.live_case(rt_seconds, args.rounds, quick=args.quick)
        text = format_live(r)
    elif args.case == "breakdown":
        r = bench.breakdown_case(bench.chosen_controllers(args.controllers))
        text = format_breakdown(r["breakdown"])
    else:
        r = bench.run(
            bench.chosen_controllers(args.controllers),
            argv=argv[1:],
            quick=args.quick,
            steps_only=args.steps_only,
            rt_seconds=rt_seconds,
            rt_priority=args.rt_priority,
        )
        text = bench.format_table(r)
    print(text)
    if args.json:
        Path(args.json).write_text(jsonsafe.dumps(r, indent=2, default=str) + "\n")
    return 0
