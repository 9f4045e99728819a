"""Arguments of ``wheelchair-hil safety-report`` and its action: the safety fault-injection
suite as a table.

Every case the safety tests run is run in lock-step; the table gives, per case, what detected
the fault and when, the stop time and distance against their bounds, whether anything resumed,
and the frames rejected by reason (docs/safety.md).  ``--realtime`` also runs bench, controller
and recorder as processes in real time and kills (SIGKILL) or stops (SIGSTOP) the controller.
Exit status 0 when every case meets its criteria, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Any

from dbc.runtime.errors import ConfigError
from tools.console.progress import Progress


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


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """List the cases, or run them (and with ``--realtime`` the real-time signal runs) and
    print the table; 0 when every case meets its criteria, 1 otherwise."""
    from tools.safety import cases as sc  # lazy: the stack

    if args.list:
        for c in sc.CASES:
            print(f"{c.name:<28} {c.expect:<13} {c.fault}")
        return 0
    quiet = () if args.verbose else ("controller", "firmware_sim", "tools")
    levels = {name: logging.getLogger(name).level for name in quiet}
    try:
        for name in quiet:  # thousands of rejected frames are the point here, not news
            logging.getLogger(name).setLevel(logging.ERROR)
        return _run(args, sc)
    finally:
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


def _run(args: argparse.Namespace, sc: Any) -> int:
    from tools.safety import criteria, realtime  # lazy: the stack
    from tools.safety.report import format_table, realtime_lines  # lazy

    cases = list(sc.CASES)
    if args.case:
        unknown = sorted(set(args.case) - set(sc.CASES_BY_NAME))
        if unknown:
            raise ConfigError(
                f"unknown safety case(s) {', '.join(unknown)}; --list shows the cases"
            )
        cases = [sc.CASES_BY_NAME[n] for n in args.case]
    results = []
    with Progress(
        len(cases), "safety-report", "case", enabled=not args.no_progress, lines="each"
    ) as bar:
        for c in cases:
            r = criteria.evaluate(c)
            results.append(r)
            bar.update(note=f"{c.name}: {'pass' if r.passed else 'FAIL'}")
    print(format_table(results, markdown=args.markdown))
    failed = [r for r in results if not r.passed]
    for r in failed:
        print(f"FAIL {r.name}: " + "; ".join(r.failures))
    print(
        f"\n{len(results) - len(failed)}/{len(results)} cases meet their criteria "
        f"(a_stop = {criteria.A_STOP_MPS2} m/s^2, watchdog {sc.WATCHDOG_S * 1000:.0f} ms, "
        f"T = {sc.PERIOD_S * 1000:.0f} ms)"
    )
    report: dict[str, Any] = {"cases": [r.as_dict() for r in results]}
    if args.realtime:
        out = Path(args.out)
        rt = []
        for sig in ("SIGKILL", "SIGSTOP"):
            res = realtime.realtime_signal_run(
                out / sig.lower(),
                sig=sig,
                scenario=args.realtime_scenario,
                at_s=args.realtime_at,
                duration_s=args.realtime_at + 6.0,
            )
            rt.append(res)
            print("\n" + "\n".join(realtime_lines(res)))
        report["realtime"] = [r.as_dict() for r in rt]
        rt_failed = [r for r in rt if not r.passed]
    else:
        rt_failed = []
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(report, indent=2, default=str) + "\n")
    return 0 if not failed and not rt_failed else 1
