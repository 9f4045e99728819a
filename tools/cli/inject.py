"""Arguments of ``wheelchair-hil inject``: a fault into a running bench (Bench_Fault_Command).

The options are the fault kinds' wire-carried parameters, named after them with their unit
(:func:`tools.run.inject.wire_fields`), so this module imports the fault table.
"""

from __future__ import annotations

import argparse

from firmware_sim.faultspec import KINDS
from tools.cli.options import bus_options
from tools.run.inject import wire_options


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("kind", choices=[*KINDS, "all"], help="fault type (all: with --clear only)")
    p.add_argument("--side", choices=("left", "right", "both"), help="wheel the fault acts on")
    p.add_argument("--node", choices=("left", "right", "localizer"), help="node-silent/-reboot")
    for opt, w in sorted(wire_options().items()):
        unit = "" if w.unit in ("", "1") else f" ({w.unit})"
        p.add_argument(
            opt,
            dest=f"fault_{w.field}",
            type=float,
            default=None,
            metavar=w.metavar,
            help=f"{w.doc or w.field}{unit}; {', '.join(w.kinds)}",
        )
    p.add_argument(
        "--fault-duration",
        type=float,
        default=0.0,
        metavar="S",
        help="seconds of simulation time the fault lasts (0: until cleared)",
    )
    p.add_argument("--clear", action="store_true", help="clear instead of inject")
    p.add_argument(
        "--id",
        type=int,
        default=0,
        metavar="N",
        help="fault ID (inject: 0 = the bench picks; clear: that one)",
    )
    p.add_argument(
        "--wait",
        type=float,
        default=2.0,
        metavar="S",
        help="wall seconds to wait for the bench's answer",
    )
    bus_options(p, scenario_required=False)
