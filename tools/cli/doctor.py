"""Arguments of ``wheelchair-hil doctor``: the pre-flight check of a chair (or the bench), one
line per check (ok, warning, FAIL with the fix); it moves no wheel and exits 1 on any failure.

    wheelchair-hil doctor --config /etc/wheelchair-hil/chair.toml
    wheelchair-hil doctor --bus socketcan --channel can0 --config chair.toml --rt-priority 80
"""

from __future__ import annotations

import argparse

from tools.cli.options import bus_arguments


def add_arguments(p: argparse.ArgumentParser) -> None:
    bus_arguments(
        p, what="socketcan on a chair; default: the config's [bus], then CAN_INTERFACE / can.conf"
    )
    p.add_argument(
        "--config",
        default=None,
        help="the chair's controller TOML (install-service --chair-template PATH writes the template)",
    )
    p.add_argument("--dbc", default=None, help="DBC file instead of dbc/wheelchair.dbc")
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="the SCHED_FIFO priority the controller will ask for: not being permitted it is "
        "then a failure (0: only a warning)",
    )
    p.add_argument(
        "--window",
        type=float,
        default=2.0,
        help="seconds to listen to the bus (heartbeats, answers, bus load); default 2",
    )
