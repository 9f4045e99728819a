"""Arguments of ``wheelchair-hil bench``: the benchmark suite (tools/perf/)."""

from __future__ import annotations

import argparse


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
