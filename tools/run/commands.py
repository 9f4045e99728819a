"""The entry points of ``wheelchair-hil sim``, ``control``, ``record`` and ``params``.

Each runs one part of a run (:mod:`tools.run.runner`) in this process, from the parsed
arguments (:mod:`tools.run.from_args`), and writes its statistics next to its output.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from controller.clock import try_realtime
from controller.config import ControllerConfig, load_config
from controller.tracking import registry
from dbc.runtime import jsonsafe
from dbc.runtime.errors import ConfigError, WheelchairError
from dbc.runtime.params import describe
from firmware_sim.config import BenchConfig
from tools.bus import transport
from tools.bus.rxloss import LOSS_EXIT
from tools.bus.transport import BusSpec
from tools.live.server import LiveServer, format_live_stats
from tools.run import from_args
from tools.run import scenario as scenario_mod
from tools.run.runner import run_bench, run_controller, run_recorder
from tools.run.scenario import ScenarioParams

log = logging.getLogger("wheelchair-hil")


def sim(args: argparse.Namespace, argv: list[str]) -> int:
    part_scheduling("sim", args.realtime)

    spec = from_args.bus_spec(args)  # first: a bus it may not open is refused before the plan
    codec = from_args.codec_for(args)
    plan_ = from_args.run_plan(args)
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    stats = run_bench(
        spec,
        plan_,
        out_dir=out,
        stop_event=from_args.stop_on_signals(),
        on_ready=from_args.ready_callback(args),
        codec=codec,
        recorder_window_steps=args.recorder_window,
        rt_priority=args.rt_priority,
    )
    log.info(
        "bench: %.1f s simulated in %.2f s wall, %d missed acks",
        stats.sim_time_s,
        stats.wall_s,
        stats.missed_acks,
    )
    return _loss_status("sim", stats.rx_dropped, stats.rx_buffer_bytes)


def _loss_status(part: str, dropped: int, buffer_bytes: int, missed_steps: int = 0) -> int:
    if dropped == 0 and missed_steps == 0:
        return 0
    what = [f"the kernel dropped {dropped} frames from its full receive queue ({buffer_bytes} B)"]
    if missed_steps:
        what.append(f"{missed_steps} Bench_Step periods are missing from its log")
    print(f"wheelchair-hil: error: {part} lost frames: {'; '.join(what)}", file=sys.stderr)
    return LOSS_EXIT


def control(args: argparse.Namespace, argv: list[str]) -> int:
    cfg = load_config(args.config)
    args.realtime = realtime_clock(args, cfg)
    part_scheduling("control", args.realtime)
    spec = from_args.bus_spec(args, cfg.bus)  # first: a bus it may not open is refused early
    codec = from_args.codec_for(args)
    plan_ = from_args.run_plan(args, args.controller)
    out = Path(args.out) if args.out else None
    if getattr(args, "log_root", None):
        out = new_run_dir(Path(args.log_root))
        log.info("this run's logs: %s", out)
    if out:
        out.mkdir(parents=True, exist_ok=True)
    with contextlib.ExitStack() as stack:
        live = _live_view(args, stack)
        if live is not None and args.live is not None:
            stack.enter_context(_bus_feed(args, spec, live))
        res = run_controller(
            spec,
            plan_,
            config=cfg,
            rt_priority=args.rt_priority,
            out_dir=out,
            stop_event=from_args.stop_on_signals(),
            on_ready=from_args.ready_callback(args),
            codec=codec,
            live=live.feed() if live else None,
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
    if res["stop_reason"] == "BUS_DOWN":
        print(
            f"wheelchair-hil: error: control on {spec.describe()}: the bus went down: "
            f"{res['stop_detail']}; the host braked, the drives stop by their watchdog",
            file=sys.stderr,
        )
        return 1
    return _loss_status("control", res["rx_dropped"], res["rx_buffer_bytes"])


def realtime_clock(args: argparse.Namespace, cfg: ControllerConfig) -> bool:
    """The controller's clock: ``--realtime`` or ``--lockstep``, else the configuration's
    ``[loop] clock`` (a chair's file says realtime: its drives send no Bench_Step to wait for)."""
    if getattr(args, "lockstep", False):
        if args.realtime:
            raise ConfigError("control: --lockstep and --realtime exclude each other")
        return False
    return bool(args.realtime) or cfg.loop.clock == "realtime"


def new_run_dir(root: Path) -> Path:
    """A directory under ``root`` that no earlier run used, named by the UTC start time
    (``20260102T030405Z``, ``...Z-2`` for a second start in the same second), created."""
    root.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    for n in range(1, 1000):
        out = root / (stamp if n == 1 else f"{stamp}-{n}")
        try:
            out.mkdir()
        except FileExistsError:
            continue
        return out
    raise WheelchairError(f"{root}: 999 runs started in the second {stamp}")


def record(args: argparse.Namespace, argv: list[str]) -> int:
    prio = getattr(args, "rt_priority", 0)
    notes: list[str] = []
    if args.realtime and prio > 0:
        notes = try_realtime(prio)
        for note in notes:  # "... not permitted": the recorder may be starved and lose frames
            log.log(logging.WARNING if "not" in note else logging.INFO, "record: %s", note)
    else:
        part_scheduling("record", args.realtime)

    codec = from_args.codec_for(args)
    scen = scenario_mod.load(args.scenario) if args.scenario else None
    spec = from_args.bus_spec(args)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.ExitStack() as stack:
        live = _live_view(args, stack)
        stats = run_recorder(
            spec,
            out,
            lockstep=not args.realtime,
            scenario=scen,
            stop_event=from_args.stop_on_signals(),
            on_ready=from_args.ready_callback(args),
            codec=codec,
            run_info={"bus": spec.describe()},
            live=live.feed() if live else None,
        )
    if str(out) != os.devnull:  # a recording for the live view alone keeps no statistics
        # what the system granted, beside the figures it explains (as the bench and host do)
        jsonsafe.write(
            out.parent / "recorder_stats.json",
            {**stats.as_dict(), "realtime_notes": notes},
            indent=2,
        )
    log.info("recorded %d frames to %s (%s)", stats.frames, out, stats.ended_by)
    return _loss_status("record", stats.rx_dropped, stats.rx_buffer_bytes, stats.missed_steps)


def _live_view(args: argparse.Namespace, stack: contextlib.ExitStack) -> LiveServer | None:
    """The live view of ``--live`` (started here) or ``--live-feed`` (run's), if any."""
    if getattr(args, "live_feed", None):
        return LiveServer.attached(args.live_feed)
    if getattr(args, "live", None) is None:
        return None
    if transport.in_private_namespace():
        log.warning(
            "live: this is a private network namespace; the view is reachable only from "
            "inside it (wheelchair-hil run --live serves from outside)"
        )
    view = LiveServer(args.live)
    stack.callback(lambda: log.info("live: %s", format_live_stats(view.stats)))  # after stop
    stack.enter_context(view)
    print(f"live: {view.url} (open it in Foxglove)", file=sys.stderr, flush=True)
    return view


#: How long ``control --live`` waits for its bus recorder to listen.
_RECORDER_START_S = 30.0


@contextlib.contextmanager
def _bus_feed(args: argparse.Namespace, spec: BusSpec, live: LiveServer) -> Iterator[None]:
    """``control --live``: every frame on the bus for the view, recorded by a ``record``
    process of its own (its log goes to the null device), so that decoding the bus costs
    the controller's process nothing."""
    if not transport.profile(spec.interface).between_processes:
        log.warning("live: a virtual bus is private to this process; the view shows no frames")
        yield
        return
    argv = [*from_args.bus_argv(spec), "--out", os.devnull, "--live-feed", live.socket_path]
    if args.realtime:
        argv.append("--realtime")
    if args.dbc:
        argv += ["--dbc", args.dbc]
    proc = subprocess.Popen(
        transport.python_argv("record", *argv, "--ready"), stdout=subprocess.PIPE, text=True
    )
    try:
        # the controller starts once the recorder listens, so that the view has every frame
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], _RECORDER_START_S)
        line = proc.stdout.readline() if ready else ""
        if line.strip() != "READY":
            log.warning(
                "live: the bus recorder did not start within %.0f s; the view may lack frames",
                _RECORDER_START_S,
            )
        yield
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def part_scheduling(part: str, realtime: bool) -> None:
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


def params(args: argparse.Namespace, argv: list[str]) -> int:

    tables: list[tuple[str, Any]] = [
        ("controller/controller.toml", ControllerConfig),
        ("firmware_sim/chair.toml", BenchConfig),
        ("<scenario>.toml [scenario]", ScenarioParams),
    ]
    for name in registry.names():
        if registry.gains_section(name) != name:  # a variant: its law's section and keys
            continue
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
            print(f"\n{title}")
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
