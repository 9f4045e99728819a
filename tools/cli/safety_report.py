"""Arguments of ``wheelchair-hil safety-report``: the safety fault-injection suite as a table.

Every case the safety tests run is run in lock-step; the table gives, per case, what detected
the fault and when, the stop time and distance against their bounds, whether anything resumed,
and the frames rejected by reason (docs/safety.md).  ``--realtime`` also runs bench, controller
and recorder as processes in real time and kills (SIGKILL) or stops (SIGSTOP) the controller.
Exit status 0 when every case meets its criteria, 1 otherwise.
"""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", metavar="FILE", help="also write every figure as JSON")
    p.add_argument(
        "--case", action="append", metavar="NAME", help="run only this case (repeatable)"
    )
    p.add_argument("--list", action="store_true", help="list the cases and exit")
    p.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    p.add_argument(
        "--no-progress",
        action="store_true",
        help="no progress on stderr (a bar on a terminal, else a line per case)",
    )
    p.add_argument(
        "--realtime",
        action="store_true",
        help="also SIGKILL and SIGSTOP the controller of a real-time 3-process run "
        "(udp_multicast in a private network namespace)",
    )
    p.add_argument(
        "--realtime-scenario",
        default="fault-free",
        help="scenario of the real-time runs (default: fault-free, the paper route)",
    )
    p.add_argument(
        "--realtime-at",
        type=float,
        default=20.0,
        metavar="S",
        help="wall seconds after the bench starts at which the controller gets the signal",
    )
    p.add_argument(
        "--out",
        default="out/safety",
        help="directory of the real-time runs' logs (default out/safety)",
    )
