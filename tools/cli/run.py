"""Arguments of ``wheelchair-hil run``: bench, controller and recorder on one bus."""

from __future__ import annotations

import argparse

from tools.cli.options import bus_options, controller_option, live_option


def add_arguments(p: argparse.ArgumentParser) -> None:
    bus_options(p)
    controller_option(p)
    p.add_argument(
        "--out",
        required=True,
        help="output directory: run.mcap (the whole run, docs/logs.md), summary.json",
    )
    live_option(p, "the run's channels (those of run.mcap)")
    # the live view run started before it re-executed itself in a private namespace
    p.add_argument("--live-feed", default=None, help=argparse.SUPPRESS)
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="real time over separate processes: the controller asks for SCHED_FIFO with this "
        "priority and locked memory, the bench (standing in for the drives' own hardware) "
        "for one above it (the summary and bench_stats.json say what was granted)",
    )
