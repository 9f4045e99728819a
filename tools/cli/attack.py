"""Arguments of ``wheelchair-hil attack``: the bus attacks of docs/safety.md on real-time runs
across processes, with and without authentication, and the authentication's cost per tick."""

from __future__ import annotations

import argparse

from tools.cli.options import controller_name
from tools.safety.attacks import ATTACKS


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--attack", action="append", choices=ATTACKS, help="default: all")
    p.add_argument("--auth", choices=("on", "off", "both"), default="both")
    p.add_argument("--scenario", default="fault-free")
    p.add_argument("--controller", type=controller_name, default="antifragile", metavar="NAME")
    p.add_argument("--at", type=float, default=8.0, help="attack onset, simulated s")
    p.add_argument("--duration", type=float, default=16.0, help="simulated s per run")
    p.add_argument(
        "--false-alarms",
        type=int,
        default=0,
        metavar="N",
        help="instead: N real-time runs without an attack; count plausibility stops",
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        metavar="N",
        help="SCHED_FIFO priority of the controller (the bench gets N+1), as on a chair; 0: none",
    )
    p.add_argument("--cost", action="store_true", help="only the auth cost per tick")
    p.add_argument("--out", required=False, default="out/attacks")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
