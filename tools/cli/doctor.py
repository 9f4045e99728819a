"""Arguments of ``wheelchair-hil doctor`` and its action: the pre-flight check of a chair (or
the bench), one line per check (ok, warning, FAIL with the fix); it moves no wheel and exits 1
on any failure.

    wheelchair-hil doctor --config /etc/wheelchair-hil/chair.toml
    wheelchair-hil doctor --bus socketcan --channel can0 --config chair.toml --rt-priority 80
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import TYPE_CHECKING

from dbc.runtime.errors import ConfigError, WheelchairError
from tools.cli.options import bus_arguments
from tools.deploy.check import Check, Status

if TYPE_CHECKING:
    from tools.bus.transport import BusSpec


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


def report(checks: list[Check], out: Callable[[str], object] = print) -> int:
    """Print the lines and a verdict; 1 if any check failed, else 0."""
    for c in checks:
        out(c.line())
    fails = sum(c.status is Status.FAIL for c in checks)
    warns = sum(c.status is Status.WARN for c in checks)
    warnings = f"{warns} warning{'' if warns == 1 else 's'}"
    if fails:
        out(f"doctor: {fails} failed, {warnings}: the controller must not arm")
        return 1
    out(f"doctor: no failure ({warnings})")
    return 0


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Run every check (:func:`tools.deploy.doctor.run_checks`) on the bus the arguments or the
    chair's ``[bus]`` name, print the report; 1 on any failure."""
    from controller.config import load_config  # lazy
    from tools.cli import from_args  # lazy: python-can, the codec
    from tools.deploy.doctor import NOT_CHECKED, run_checks  # lazy

    if not 0.1 <= args.window <= 60.0:
        raise WheelchairError(f"doctor --window {args.window:g} is outside [0.1, 60] s")
    codec = from_args.codec_for(args)
    bus_cfg = None
    config_loaded = True
    try:
        bus_cfg = load_config(args.config).bus
    except ConfigError:  # reported by the config check
        config_loaded = False
    spec: BusSpec | None = None
    spec_error = ""
    try:
        spec = from_args.bus_spec(args, bus_cfg)
    except WheelchairError as err:
        spec_error = str(err)
        if not config_loaded and args.config and args.bus is None:
            # the file names the bus in its [bus]: not a second fault, the same one
            spec_error = f"{NOT_CHECKED} the config did not load (its [bus] names the bus)"
    checks = run_checks(
        args.config,
        spec,
        window_s=args.window,
        rt_priority=args.rt_priority,
        codec=codec,
        spec_error=spec_error,
    )
    return report(checks)
