"""``wheelchair-hil``: the project's command line.

Subcommands are imported on first use, so a missing optional dependency breaks
one subcommand with a clear message, not the whole program.  Errors the project
raises on purpose (bad scenario, unknown controller, unreachable bus ...) are
printed as one line naming the file, key or limit, with exit status 2.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from dbc.errors import WheelchairError

log = logging.getLogger("wheelchair-hil")


def _bus_options(p: argparse.ArgumentParser, *, scenario_required: bool = True) -> None:
    p.add_argument(
        "--bus",
        choices=("virtual", "udp_multicast", "socketcan"),
        default=None,
        help="python-can interface (default: CAN_INTERFACE / can.conf; 'run' picks one itself)",
    )
    p.add_argument(
        "--channel",
        default=None,
        help="bus channel (udp_multicast: multicast group, default 239.74.163.2; socketcan: can0, vcan0)",
    )
    p.add_argument(
        "--allow-network-multicast",
        action="store_true",
        help="open udp_multicast even where frames could leave the machine (not recommended)",
    )
    p.add_argument(
        "--scenario",
        required=scenario_required,
        default=None,
        help="scenario name in scenarios/ or a path to a scenario TOML file",
    )
    p.add_argument("--realtime", action="store_true", help="wall-clock time instead of lock-step")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        help="simulated seconds (default: from the scenario)",
    )
    p.add_argument(
        "--seed", type=int, default=None, help="seed of every random process (default: scenario's)"
    )
    p.add_argument(
        "--dbc", default=None, help="DBC file to use instead of the project's dbc/wheelchair.dbc"
    )


def _child_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ready", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--out", default=None, help="output directory (stats, logs)")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="wheelchair-hil",
        description="Antifragile wheelchair trajectory tracking over CAN: controller, bench, logs, evaluation.",
    )
    ap.add_argument(
        "-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)"
    )
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="bench + controller + recorder on one bus, then summary.json")
    _bus_options(p)
    p.add_argument(
        "--controller", default=None, help="baseline, antifragile, robust, adaptive, resilient"
    )
    p.add_argument(
        "--out", required=True, help="output directory: run.mcap, controller.mcap, summary.json"
    )

    p = sub.add_parser(
        "sim", help="the bench alone (drives, physics, localizer) for a controller elsewhere"
    )
    _bus_options(p)
    _child_options(p)

    p = sub.add_parser(
        "control", help="the controller alone, for the bench or a real chair's drives"
    )
    _bus_options(p)
    _child_options(p)
    p.add_argument(
        "--controller", default=None, help="baseline, antifragile, robust, adaptive, resilient"
    )
    p.add_argument(
        "--config",
        default=None,
        help="controller deployment TOML (default controller/controller.toml)",
    )

    p = sub.add_parser("record", help="record every frame on the bus to MCAP")
    _bus_options(p, scenario_required=False)
    p.add_argument("--ready", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--out", required=True, help="MCAP file to write")

    p = sub.add_parser(
        "sandbox", help="run CMD in a private network namespace prepared for udp_multicast"
    )
    p.add_argument("cmd", nargs=argparse.REMAINDER, help="command (after --); default: $SHELL")

    p = sub.add_parser("params", help="list every parameter with unit, default and bounds")
    p.add_argument("--markdown", action="store_true", help="as a Markdown table")

    return ap


# ----------------------------------------------------------------------- helpers


def _stop_on_signals() -> threading.Event:
    stop = threading.Event()

    def handler(signum: int, _frame: Any) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)
    return stop


def _ready_cb(args: argparse.Namespace) -> Callable[[], None] | None:
    if not getattr(args, "ready", False):
        return None

    def ready() -> None:
        print("READY", flush=True)

    return ready


def _spec(args: argparse.Namespace) -> Any:
    from tools import transport

    return transport.resolve(
        args.bus, args.channel, allow_network_multicast=args.allow_network_multicast
    )


def _codec(args: argparse.Namespace) -> Any:
    from dbc.codec import Codec

    return Codec(args.dbc) if args.dbc else Codec.default()


def _plan(args: argparse.Namespace, controller: str | None = None) -> Any:
    from tools import scenario as scenario_mod
    from tools.runner import make_plan

    scen = scenario_mod.load(args.scenario)
    return make_plan(
        scen, controller, realtime=args.realtime, duration_s=args.duration, seed=args.seed
    )


# ---------------------------------------------------------------------- commands


def cmd_run(args: argparse.Namespace, argv: list[str]) -> int:
    from tools import launcher

    return launcher.run(args, argv)


def cmd_sim(args: argparse.Namespace, argv: list[str]) -> int:
    from tools.runner import run_bench

    codec = _codec(args)
    plan_ = _plan(args)
    spec = _spec(args)
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    stats = run_bench(
        spec,
        plan_,
        out_dir=out,
        stop_event=_stop_on_signals(),
        on_ready=_ready_cb(args),
        codec=codec,
    )
    log.info(
        "bench: %.1f s simulated in %.2f s wall, %d missed acks",
        stats.sim_time_s,
        stats.wall_s,
        stats.missed_acks,
    )
    return 0


def cmd_control(args: argparse.Namespace, argv: list[str]) -> int:
    from controller.config import load_config
    from tools.runner import run_controller

    codec = _codec(args)
    cfg = load_config(args.config)
    plan_ = _plan(args, args.controller)
    spec = _spec(args)
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    res = run_controller(
        spec,
        plan_,
        config=cfg,
        out_dir=out,
        stop_event=_stop_on_signals(),
        on_ready=_ready_cb(args),
        codec=codec,
    )
    log.info("controller %s: %s (%s)", res["controller"], res["final_state"], res["stop_reason"])
    return 0


def cmd_record(args: argparse.Namespace, argv: list[str]) -> int:
    import json

    from tools import scenario as scenario_mod
    from tools.runner import run_recorder

    codec = _codec(args)
    scen = scenario_mod.load(args.scenario) if args.scenario else None
    spec = _spec(args)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    stats = run_recorder(
        spec,
        out,
        lockstep=not args.realtime,
        scenario=scen,
        stop_event=_stop_on_signals(),
        on_ready=_ready_cb(args),
        codec=codec,
        run_info={"bus": spec.describe()},
    )
    (out.parent / "recorder_stats.json").write_text(
        json.dumps(
            {
                "frames": stats.frames,
                "decoded": stats.decoded,
                "rejected": dict(stats.rejected),
                "bits": stats.bits,
                "ended_by": stats.ended_by,
                "by_name": dict(stats.by_name),
            },
            indent=2,
        )
    )
    log.info("recorded %d frames to %s (%s)", stats.frames, out, stats.ended_by)
    return 0


def cmd_sandbox(args: argparse.Namespace, argv: list[str]) -> int:
    import os

    from tools import transport

    cmd = list(args.cmd)
    if cmd and cmd[0] == "--":
        cmd = cmd[1:]
    if not cmd:
        cmd = [os.environ.get("SHELL", "/bin/sh")]
    return transport.exec_in_sandbox(cmd)


def cmd_params(args: argparse.Namespace, argv: list[str]) -> int:
    from controller.config import ControllerConfig
    from controller.tracking import registry
    from dbc.params import describe
    from firmware_sim.config import BenchConfig
    from tools.scenario import ScenarioParams

    tables: list[tuple[str, Any]] = [
        ("controller/controller.toml", ControllerConfig),
        ("firmware_sim/chair.toml", BenchConfig),
        ("scenario [scenario]", ScenarioParams),
    ]
    for name in registry.names():
        try:
            tables.append(
                (f"controller/gains.toml [{name}]", registry.controller_class(name).Params)
            )
        except WheelchairError as err:
            print(f"# {name}: {err}")
    for title, cls in tables:
        rows = describe(cls)
        if args.markdown:
            print(
                f"\n### {title}\n\n| key | unit | default | bounds | meaning |\n|---|---|---|---|---|"
            )
            for r in rows:
                print(
                    f"| `{r['key']}` | {r['unit']} | {r['default']} | {_bounds(r)} | {r['doc']} |"
                )
        else:
            print(f"\n[{title}]")
            for r in rows:
                print(
                    f"  {r['key']:<40} {r['default']!s:>12} {r['unit']:<14} {_bounds(r):<18} {r['doc']}"
                )
    return 0


def _bounds(r: dict[str, Any]) -> str:
    lo, hi = r["lo"], r["hi"]
    if lo is None and hi is None:
        return ""
    return f"[{'' if lo is None else lo}, {'' if hi is None else hi}]"


COMMANDS: dict[str, Callable[[argparse.Namespace, list[str]], int]] = {
    "run": cmd_run,
    "sim": cmd_sim,
    "control": cmd_control,
    "record": cmd_record,
    "sandbox": cmd_sandbox,
    "params": cmd_params,
}


def _lockstep_scheduling(part: str) -> None:
    """Scheduling policy of lock-step parts (throughput jobs on a shared machine)."""
    mode = os.environ.get("WHEELCHAIR_HIL_SCHED", "batch-nice")
    try:
        if mode in ("batch-nice", "batch") and part != "record":
            os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
        if mode in ("batch-nice", "nice") and part == "record":
            os.nice(int(os.environ.get("WHEELCHAIR_HIL_NICE", "10")))
    except (AttributeError, OSError) as err:
        log.debug("scheduling policy not available: %s", err)


def _profiled(args: argparse.Namespace, argv: list[str], out_dir: Path) -> int:
    """Run one part under cProfile (WHEELCHAIR_HIL_PROFILE=DIR) and dump DIR/<part>.prof."""
    import cProfile

    out_dir.mkdir(parents=True, exist_ok=True)
    prof = cProfile.Profile()
    try:
        return prof.runcall(COMMANDS[args.command], args, argv)
    finally:
        prof.dump_stats(out_dir / f"{args.command}.prof")


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = build_parser()
    args = ap.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    if args.command in ("sim", "control", "record"):
        level = min(level, logging.INFO)
    logging.basicConfig(
        level=level, format="%(asctime)s %(name)s %(levelname)s: %(message)s", stream=sys.stderr
    )
    if args.command in ("sim", "control", "record") and not args.realtime:
        _lockstep_scheduling(args.command)
    try:
        profile_dir = os.environ.get("WHEELCHAIR_HIL_PROFILE")
        if profile_dir and args.command in ("sim", "control", "record"):
            return _profiled(args, argv, Path(profile_dir))
        return COMMANDS[args.command](args, argv)
    except WheelchairError as err:
        print(f"wheelchair-hil: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
