"""Arguments of ``wheelchair-hil soak``, and its action (parser and action together).

The schedule is printed and saved (``DIR/schedule.json``) before anything starts; the report
is ``DIR/soak.json``, its summary printed.  Exit status 0 when the soak passed, 1 when it
found an unexplained stop, an uncounted loss, a wheel moving after a stop or memory growing,
2 for bad input, 3 when a stop signal cut it short and what ran passed (a partial report).  The parts run over udp_multicast in a private network namespace, which the
command creates itself (it never opens udp_multicast outside one).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from controller.tracking import registry
from dbc.runtime.errors import ConfigError, WheelchairError
from tools.cli.options import controller_name

if TYPE_CHECKING:
    from tools.soak.schedule import Schedule

#: Exit status of a soak cut short (a stop signal) that found no failure: a partial report.
EXIT_PARTIAL = 3
#: The longest soak (min): a day.
MAX_MINUTES = 1440.0
#: Set in the re-executed soak inside its namespace: the schedule is already saved and printed.
_INSIDE = "--inside-namespace"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--minutes", type=float, default=None, metavar="N", help="length of the soak (min, >= 2)"
    )
    p.add_argument(
        "--seed", type=int, default=None, metavar="S", help="seed of the schedule and the bench"
    )
    p.add_argument("--out", default=None, metavar="DIR", help="new directory for logs and report")
    p.add_argument(
        "--judge",
        default=None,
        metavar="DIR",
        help="run nothing: judge the soak in DIR again from its logs, schedule and "
        "orchestration (after a change of the criteria), rewriting its soak.json",
    )
    p.add_argument(
        "--auth",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="authenticated setpoints (drives refuse the rogue node's frames); default on",
    )
    p.add_argument(
        "--controller",
        type=controller_name,
        default="antifragile",
        metavar="NAME",
        help="the tracking law (default antifragile)",
    )
    p.add_argument(
        "--routes",
        default=None,
        metavar="A,B,...",
        help="packaged route names driven in turn (default: short,paper,short-pause)",
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        metavar="N",
        help="SCHED_FIFO priority of the controller (bench N+1, recorder and attacker N-1); 0: none",
    )
    p.add_argument(
        "--bus",
        "-i",
        choices=("udp_multicast", "socketcan"),
        default="udp_multicast",
        help="the parts' bus: udp_multicast in a private namespace the soak creates (default), "
        "or socketcan (in the guest of `wheelchair-hil sandbox --socketcan`: --channel vcan0)",
    )
    p.add_argument("--channel", "-c", default=None, help="the bus's channel (socketcan: vcan0)")
    p.add_argument("--no-verify", action="store_true", help="skip replay --verify of each log")
    p.add_argument("--json", action="store_true", help="print the whole report as JSON")
    p.add_argument(_INSIDE, action="store_true", help=argparse.SUPPRESS)


def _options(args: argparse.Namespace) -> tuple[Schedule, Path, tuple[str, ...]]:
    """The schedule, the directory and the routes, validated (ConfigError naming the option)."""
    from tools.run import scenario as scenario_mod  # lazy: numpy
    from tools.soak import orchestrate, schedule  # lazy

    if args.minutes != args.minutes:
        raise ConfigError("--minutes nan: not a number")
    if args.minutes < schedule.MIN_MINUTES:
        raise ConfigError(
            f"--minutes {args.minutes:g} is below its minimum {schedule.MIN_MINUTES:g}"
        )
    if args.minutes > MAX_MINUTES:
        raise ConfigError(
            f"--minutes {args.minutes:g} is above its maximum {MAX_MINUTES:g} (a day)"
        )
    scenario_mod.check_seed(args.seed, source="--seed")
    if not 0 <= args.rt_priority <= 98:
        raise ConfigError(f"--rt-priority {args.rt_priority} is outside [0, 98]")
    routes = orchestrate.ROUTES
    if args.routes:
        routes = tuple(r.strip() for r in args.routes.split(",") if r.strip())
        for r in routes:
            try:
                scenario_mod.route_file(r)
            except WheelchairError as err:
                raise ConfigError(f"--routes: {err}") from err
    if args.controller not in registry.names():
        raise ConfigError(
            f"--controller {args.controller}: unknown (one of {', '.join(registry.names())})"
        )
    out = Path(args.out).expanduser().resolve()
    sched = schedule.build(args.seed, args.minutes)
    return sched, out, routes


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Run the soak (re-executed in a private namespace for udp_multicast), or judge one again
    (``--judge``); print and save its report; its exit status."""
    from tools.bus import transport  # lazy: python-can
    from tools.soak import orchestrate  # lazy: the stack

    if args.judge is not None:
        return _judge(args, Path(args.judge).expanduser())
    for name in ("minutes", "seed", "out"):
        if getattr(args, name) is None:
            raise ConfigError(f"soak: --{name} is required (or --judge DIR)")
    sched, out, routes = _options(args)
    if not getattr(args, "inside_namespace", False):
        if out.exists() and not out.is_dir():
            raise ConfigError(f"--out {out}: not a directory")
        if out.exists() and any(out.iterdir()):
            raise ConfigError(f"--out {out}: not empty (a soak writes a new directory)")
        out.mkdir(parents=True, exist_ok=True)
        (out / orchestrate.SCHEDULE).write_text(json.dumps(sched.as_dict(), indent=1) + "\n")
        print(
            f"soak: {args.minutes:g} min, seed {args.seed}, {len(sched.events)} events, "
            f"authentication {'on' if args.auth else 'off'}; schedule in {out / 'schedule.json'}"
        )
        for line in sched.describe():
            print(f"  {line}")
        sys.stdout.flush()
        if args.bus == "udp_multicast" and not transport.in_private_namespace():
            if os.environ.get(transport.SANDBOX_ENV) == "1":
                raise WheelchairError(
                    "inside the sandbox but the namespace is not private; refusing udp_multicast"
                )
            ok, why = transport.sandbox_supported()
            if not ok:
                raise WheelchairError(f"soak needs a private network namespace: {why}")
            return transport.exec_in_sandbox(transport.python_argv(*argv, _INSIDE))
    orchestrate.run(
        orchestrate.SoakOptions(
            sched,
            out,
            auth=args.auth,
            controller=args.controller,
            routes=routes,
            rt_priority=args.rt_priority,
            interface=args.bus,
            channel=args.channel,
        )
    )
    return _report(args, out)


def _judge(args: argparse.Namespace, out: Path) -> int:
    from tools.soak import orchestrate  # lazy: the stack

    for f in (orchestrate.SCHEDULE, orchestrate.ORCHESTRATION):
        if not (out / f).is_file():
            raise ConfigError(f"--judge {out}: no {f} (not a soak's directory)")
    return _report(args, out)


def _report(args: argparse.Namespace, out: Path) -> int:
    """Judge the soak in ``out``, write its report, print it; the exit status."""
    from tools.soak import analyse  # lazy: the stack

    report = analyse.analyse(out, run_verify=not args.no_verify)
    (out / analyse.REPORT).write_text(json.dumps(report, indent=1) + "\n")
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        print(json.dumps(report["summary"], indent=1))
    summary = report["summary"]
    verdict = "PASS" if summary["passed"] else "FAIL"
    if summary["passed"] and not summary["complete"]:
        verdict = "PARTIAL (cut short: judged as far as it ran)"
    print(f"soak: {verdict}; report {out / analyse.REPORT}")
    if not summary["passed"]:
        return 1
    return 0 if summary["complete"] else EXIT_PARTIAL
