"""Arguments of ``wheelchair-hil record``: every frame on the bus to MCAP."""

from __future__ import annotations

import argparse

from tools.cli.options import bus_options, live_option


def add_arguments(p: argparse.ArgumentParser) -> None:
    bus_options(p, scenario_required=False)
    p.add_argument("--ready", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--out", required=True, help="MCAP file to write")
    live_option(p, "the recording's channels")
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        metavar="N",
        help="with --realtime: SCHED_FIFO at N and locked memory, so that a loaded machine "
        "cannot starve the recorder until the kernel drops frames (run and attack give it one "
        "below the controller's); 0: niced, the default",
    )
    # run's live view: the Unix socket its view process reads (run passes it to its parts)
    p.add_argument("--live-feed", default=None, help=argparse.SUPPRESS)
