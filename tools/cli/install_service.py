"""Arguments of ``wheelchair-hil install-service``: write the systemd unit that runs the
controller on a chair: the doctor first (ExecStartPre=), real-time limits, a log directory,
the journal, and no automatic restart (a restart would re-arm a latched stop).

    wheelchair-hil install-service --config /etc/wheelchair-hil/chair.toml \\
        --scenario /etc/wheelchair-hil/route.toml            # into /etc/systemd/system
    wheelchair-hil install-service --config chair.toml --scenario short --print
    wheelchair-hil install-service --chair-template /etc/wheelchair-hil/chair.toml
"""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--config", default=None, help="the chair's controller TOML (validated; required)"
    )
    p.add_argument(
        "--scenario",
        default=None,
        help="the route the chair drives when the service starts (scenario name or TOML path; "
        "required)",
    )
    p.add_argument(
        "--controller", default=None, help="tracking controller (default: the scenario's)"
    )
    p.add_argument("--bus", default=None, help="python-can interface (default: [bus], socketcan)")
    p.add_argument("--channel", default=None, help="bus channel (default: [bus], can0)")
    p.add_argument("--bitrate", type=int, default=None, help="bit/s (default: [bus], 500000)")
    p.add_argument("--rt-priority", type=int, default=80, help="SCHED_FIFO priority (default 80)")
    p.add_argument("--user", default="wheelchair", help="the user the service runs as")
    p.add_argument(
        "--log-dir",
        default="/var/log/wheelchair-hil",
        help="each start's logs go into a new subdirectory of this",
    )
    p.add_argument("--name", default="wheelchair-hil", help="unit name (NAME.service)")
    p.add_argument(
        "--executable",
        default=None,
        help="the wheelchair-hil to run (default: this one, with its venv)",
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--chair-template",
        metavar="PATH",
        default=None,
        help="only write the chair config template (every parameter with its unit and how to "
        "measure it) to PATH, to start the chair's --config from",
    )
    p.add_argument(
        "--preset",
        choices=("secured", "odrive-stock"),
        default="secured",
        help="with --chair-template: secured (authenticated setpoints, the wire-contract check; "
        "drives with this project's firmware) or odrive-stock (drives on ODrive's own firmware: "
        "both off, and the template says what that gives up)",
    )
    where.add_argument("--print", action="store_true", help="print the unit instead of writing it")
    where.add_argument(
        "--dest", default="/etc/systemd/system", help="directory to write NAME.service into"
    )
