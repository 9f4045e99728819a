"""Arguments of ``wheelchair-hil inject`` and its action: a fault into a running bench
(Bench_Fault_Command).

The options are the fault kinds' wire-carried parameters, named after them with their unit
(:func:`tools.run.inject.wire_fields`), so this module imports the fault table.
"""

from __future__ import annotations

import argparse
from typing import Any

from dbc.codec import FaultState
from firmware_sim.faultspec import KINDS
from tools.cli.options import bus_options
from tools.run.inject import build_command, describe_event, inject, wire_fields, wire_options


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


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Inject or clear the fault the arguments describe, print each answer of the bench.

    Examples (on the bench's bus, e.g. inside ``wheelchair-hil sandbox``)::

        wheelchair-hil inject flat-tire --side left --to-radius 0.26 --time-constant 2
        wheelchair-hil inject shaft-bump --side right --amplitude 0.015
        wheelchair-hil inject flat-tire --side left --clear      # every left flat tire
        wheelchair-hil inject all --clear                        # every active fault
        wheelchair-hil inject --id 3 all --clear                 # fault 3 only

    The command waits for the bench's clock (a ``Bench_Step``), sends one
    ``Bench_Fault_Command`` and waits for the bench's ``Bench_Fault_Event`` answer, which it
    prints with the simulation time of the latest ``Bench_Step`` (``--wait``: wall seconds for
    each of the two waits).  Options carry the parameter's unit (see ``--help`` or
    docs/faults.md); only the parameters a ``Bench_Fault_Command`` can carry are offered.  Exit
    status 0 when the bench confirmed, 1 when it refused, 2 when no bench answered.
    """
    from tools.cli import from_args  # lazy: python-can

    cmd = build_command(
        args.kind,
        side=args.side,
        node=args.node,
        params={
            field: getattr(args, f"fault_{field}")
            for _opt, (field, _u) in wire_fields().items()
            if getattr(args, f"fault_{field}", None) is not None
        },
        duration_s=args.fault_duration,
        clear=args.clear,
        fault_id=args.id,
    )
    codec = from_args.codec_for(args)
    spec = from_args.bus_spec(args)

    def show(event: Any, sim_ns: int | None) -> None:
        at = f" at t={sim_ns / 1e9:.3f} s" if sim_ns is not None else ""
        print(f"{describe_event(event)}{at}")

    answers = inject(spec, codec, cmd, wait_s=args.wait, on_answer=show)
    return 1 if all(a.state == FaultState.REJECTED for a in answers) else 0
