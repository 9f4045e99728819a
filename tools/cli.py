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
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from dbc import jsonsafe
from dbc.errors import WheelchairError
from tools import cliutil

log = logging.getLogger("wheelchair-hil")


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
    cliutil.bus_options(p)
    p.add_argument(
        "--controller", default=None, help="baseline, antifragile, robust, adaptive, resilient"
    )
    p.add_argument(
        "--out",
        required=True,
        help="output directory: run.mcap (the whole run, docs/logs.md), summary.json",
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="real time over separate processes: the controller asks for SCHED_FIFO with this "
        "priority and locked memory (the summary says what was granted)",
    )

    p = sub.add_parser(
        "sim", help="the bench alone (drives, physics, localizer) for a controller elsewhere"
    )
    cliutil.bus_options(p)
    cliutil.child_options(p)
    p.add_argument(
        "--recorder-window",
        type=int,
        default=0,
        metavar="STEPS",
        help="lock-step: stay at most STEPS steps ahead of a recorder's Bench_Record_Ack "
        "(0: do not wait; 'run' uses 100 so that no frame is lost)",
    )

    p = sub.add_parser(
        "control", help="the controller alone, for the bench or a real chair's drives"
    )
    cliutil.bus_options(p)
    cliutil.child_options(p)
    p.add_argument(
        "--controller", default=None, help="baseline, antifragile, robust, adaptive, resilient"
    )
    p.add_argument(
        "--config",
        default=None,
        help="controller deployment TOML (default controller/controller.toml)",
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="real time: run the loop under SCHED_FIFO with this priority and lock memory, "
        "where the system permits (controller_stats.json says what was granted)",
    )

    p = sub.add_parser("record", help="record every frame on the bus to MCAP")
    cliutil.bus_options(p, scenario_required=False)
    p.add_argument("--ready", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--out", required=True, help="MCAP file to write")

    p = sub.add_parser(
        "sandbox", help="run CMD in a private network namespace prepared for udp_multicast"
    )
    p.add_argument("cmd", nargs=argparse.REMAINDER, help="command (after --); default: $SHELL")

    p = sub.add_parser("params", help="list every parameter with unit, default and bounds")
    p.add_argument("--markdown", action="store_true", help="as a Markdown table")

    for module in EXTENSION_MODULES:
        _register_extension(sub, module)
    return ap


#: Modules that add subcommands.  Each defines ``COMMANDS = {name: (add_parser, run)}``
#: with ``add_parser(subparsers) -> None`` and ``run(args, argv) -> int``, and keeps
#: heavy imports inside ``run`` so that ``--help`` stays fast.
EXTENSION_MODULES: tuple[str, ...] = (
    "tools.replay",
    "tools.inject",
    "tools.benchmark",
    "tools.evaluate",
    "tools.safety_report",
)

_EXTENSIONS: dict[str, Callable[[argparse.Namespace, list[str]], int]] = {}


def _register_extension(sub: Any, module: str) -> None:
    import importlib

    try:
        mod = importlib.import_module(module)
    except ImportError as err:
        name = module.rsplit(".", 1)[-1].replace("_", "-")
        p = sub.add_parser(name, help=f"unavailable: {err}")
        reason = str(err)

        def unavailable(args: argparse.Namespace, argv: list[str]) -> int:
            raise WheelchairError(f"{name} is unavailable: {reason}")

        p.set_defaults(_run=unavailable)
        return
    for name, (add_parser, run) in mod.COMMANDS.items():
        add_parser(sub)
        _EXTENSIONS[name] = run


# ---------------------------------------------------------------------- commands


def cmd_run(args: argparse.Namespace, argv: list[str]) -> int:
    from tools import launcher

    return launcher.run(args, argv)


def cmd_sim(args: argparse.Namespace, argv: list[str]) -> int:
    from tools.runner import run_bench

    codec = cliutil.codec_for(args)
    plan_ = cliutil.run_plan(args)
    spec = cliutil.bus_spec(args)
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    stats = run_bench(
        spec,
        plan_,
        out_dir=out,
        stop_event=cliutil.stop_on_signals(),
        on_ready=cliutil.ready_callback(args),
        codec=codec,
        recorder_window_steps=args.recorder_window,
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

    codec = cliutil.codec_for(args)
    cfg = load_config(args.config)
    plan_ = cliutil.run_plan(args, args.controller)
    spec = cliutil.bus_spec(args)
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    res = run_controller(
        spec,
        plan_,
        config=cfg,
        rt_priority=args.rt_priority,
        out_dir=out,
        stop_event=cliutil.stop_on_signals(),
        on_ready=cliutil.ready_callback(args),
        codec=codec,
    )
    log.info("controller %s: %s (%s)", res["controller"], res["final_state"], res["stop_reason"])
    ended_by = str(res.get("clock_ended_by", ""))
    if ended_by.startswith("no Bench_Step"):
        # lock-step without a bench (or the bench vanished): the run did not happen as asked
        print(
            f"wheelchair-hil: error: control on {spec.describe()}: {ended_by} after "
            f"{res['ticks']} ticks; is the bench (wheelchair-hil sim) running on this bus?",
            file=sys.stderr,
        )
        return 1
    return 0


def cmd_record(args: argparse.Namespace, argv: list[str]) -> int:

    from tools import scenario as scenario_mod
    from tools.runner import run_recorder

    codec = cliutil.codec_for(args)
    scen = scenario_mod.load(args.scenario) if args.scenario else None
    spec = cliutil.bus_spec(args)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    stats = run_recorder(
        spec,
        out,
        lockstep=not args.realtime,
        scenario=scen,
        stop_event=cliutil.stop_on_signals(),
        on_ready=cliutil.ready_callback(args),
        codec=codec,
        run_info={"bus": spec.describe()},
    )
    jsonsafe.write(out.parent / "recorder_stats.json", stats.as_dict(), indent=2)
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


def _part_scheduling(part: str, realtime: bool) -> None:
    """Scheduling of the parts of a run on a shared machine.

    The recorder is always niced (it buffers; the loops must not wait for it).  In
    lock-step the bench and the controller are throughput jobs: SCHED_BATCH stops each
    frame's wake-up from preempting its sender (~100 us per multicast frame on two cores).
    In real time the controller may ask for SCHED_FIFO with ``--rt-priority``.
    """
    try:
        if part == "record":
            os.nice(10)
        elif not realtime:
            os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    except (AttributeError, OSError) as err:
        log.debug("scheduling policy not available: %s", err)


def _profiled(args: argparse.Namespace, argv: list[str], out_dir: Path) -> int:
    """Run one part under cProfile (WHEELCHAIR_HIL_PROFILE=DIR) and dump DIR/<part>.prof."""
    import cProfile

    out_dir.mkdir(parents=True, exist_ok=True)
    prof = cProfile.Profile()
    try:
        return prof.runcall(COMMANDS[args.command], args, argv)  # only core parts are profiled
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
    if args.command in ("sim", "control", "record"):
        _part_scheduling(args.command, args.realtime)
    try:
        profile_dir = os.environ.get("WHEELCHAIR_HIL_PROFILE")
        if profile_dir and args.command in ("sim", "control", "record"):
            return _profiled(args, argv, Path(profile_dir))
        run = COMMANDS.get(args.command) or _EXTENSIONS.get(args.command) or args._run
        return run(args, argv)
    except WheelchairError as err:
        print(f"wheelchair-hil: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        # a fault of the machine (disk full, read-only, a file where a directory must be):
        # one line with the path and the OS's reason, not a traceback
        print(f"wheelchair-hil: error: {os_reason(err)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


def os_reason(err: OSError) -> str:
    """``PATH: ENOSPC (No space left on device)`` for an OS error (the path if it has one)."""
    import errno as errno_mod

    name = errno_mod.errorcode.get(err.errno or 0, "") if err.errno else ""
    where = " -> ".join(str(p) for p in (err.filename, err.filename2) if p is not None)
    why = f"{name} ({err.strerror})" if name else (err.strerror or str(err))
    return f"{where}: {why}" if where else why


if __name__ == "__main__":
    sys.exit(main())
