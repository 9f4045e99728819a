"""Arguments of ``wheelchair-hil install-service`` and its action: write the systemd unit that
runs the controller on a chair: the doctor first (ExecStartPre=), real-time limits, a log directory,
the journal, and no automatic restart (a restart would re-arm a latched stop).

    wheelchair-hil install-service --config /etc/wheelchair-hil/chair.toml \\
        --scenario /etc/wheelchair-hil/route.toml            # into /etc/systemd/system
    wheelchair-hil install-service --config chair.toml --scenario short --print
    wheelchair-hil install-service --chair-template /etc/wheelchair-hil/chair.toml
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dbc.runtime.errors import ConfigError


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


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Write the chair config template (``--chair-template``), or the unit for the chair's
    config and route: printed (``--print``) or into ``--dest``, with what to run next."""
    from tools.deploy.service import render, unit_options, write_chair_template  # lazy

    if args.chair_template:
        preset = getattr(args, "preset", "secured")
        path = write_chair_template(Path(args.chair_template), preset)
        print(f"wrote {path}: the chair config template (preset {preset})")
        print(f"next: measure every value as its comment says, then doctor --config {path}")
        return 0
    missing = [opt for opt in ("config", "scenario") if not getattr(args, opt)]
    if missing:
        raise ConfigError(
            f"install-service: {' and '.join('--' + m for m in missing)} required "
            "(or --chair-template PATH to start a chair's config)"
        )
    o = unit_options(
        args.config,
        args.scenario,
        bus=args.bus,
        channel=args.channel,
        bitrate=args.bitrate,
        controller=args.controller,
        rt_priority=args.rt_priority,
        user=args.user,
        log_dir=args.log_dir,
        name=args.name,
        executable=args.executable,
    )
    text = render(o)
    if args.print:
        sys.stdout.write(text)
        return 0
    dest = Path(args.dest)
    dest.mkdir(parents=True, exist_ok=True)
    path = dest / f"{o.name}.service"
    path.write_text(text)
    print(f"wrote {path}")
    print(f"next: systemctl daemon-reload && systemctl start {o.name}   (journalctl -u {o.name})")
    print(f"at boot as well: systemctl enable {o.name}   (the chair then arms and drives at boot)")
    return 0
