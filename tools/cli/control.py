"""Arguments of ``wheelchair-hil control``: the controller alone, for the bench or a chair."""

from __future__ import annotations

import argparse

from tools.cli.options import bus_options, child_options, controller_option


def add_arguments(p: argparse.ArgumentParser) -> None:
    bus_options(p)
    child_options(p)
    controller_option(p)
    p.add_argument(
        "--config",
        default=None,
        help="controller deployment TOML (default controller/controller.toml)",
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="real time: run the loop under SCHED_FIFO with this priority and lock memory, "
        "where the system permits (controller_stats.json says what was granted)",
    )
