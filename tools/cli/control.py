"""Arguments of ``wheelchair-hil control``: the controller alone, for the bench or a chair."""

from __future__ import annotations

import argparse

from tools.cli.options import bus_options, child_options, controller_option, live_option


def add_arguments(p: argparse.ArgumentParser) -> None:
    bus_options(p)
    child_options(p)
    controller_option(p)
    p.add_argument(
        "--config",
        default=None,
        help="controller deployment TOML (default controller/controller.toml; a chair's: "
        "install-service --chair-template writes its template); its [bus] is used where --bus is not given",
    )
    p.add_argument(
        "--lockstep",
        action="store_true",
        help="lock-step with a bench's Bench_Step frames even where the configuration's "
        "[loop] clock is realtime (--realtime: the wall clock where it is lockstep)",
    )
    p.add_argument(
        "--log-root",
        default=None,
        metavar="DIR",
        help="write this run's logs into a new directory DIR/<UTC start time> (a service keeps "
        "every start's logs; instead of --out)",
    )
    live_option(
        p, "the controller's channels (those of controller.mcap) and every frame on the bus"
    )
    # run's live view: the Unix socket its view process reads (run passes it to its parts)
    p.add_argument("--live-feed", default=None, help=argparse.SUPPRESS)
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="real time: run the loop under SCHED_FIFO with this priority and lock memory, "
        "where the system permits (controller_stats.json says what was granted)",
    )
