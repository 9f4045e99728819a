"""Arguments of ``wheelchair-hil sim``: the bench alone, for a controller elsewhere."""

from __future__ import annotations

import argparse

from tools.cli.options import bus_options, child_options


def add_arguments(p: argparse.ArgumentParser) -> None:
    bus_options(p)
    child_options(p)
    p.add_argument(
        "--recorder-window",
        type=int,
        default=0,
        metavar="STEPS",
        help="lock-step: stay at most STEPS steps ahead of a recorder's Bench_Record_Ack "
        "(0: do not wait; 'run' uses 100 so that no frame is lost)",
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        metavar="PRIO",
        help="real time: the bench asks for SCHED_FIFO with this priority and locked memory; "
        "it stands in for the drives, which on a chair no load on the host can starve "
        "(bench_stats.json says what was granted)",
    )
