"""Arguments of ``wheelchair-hil control`` and its action: the controller alone, for the bench
or a chair."""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from dbc.runtime.errors import ConfigError
from tools.cli.options import bus_options, child_options, controller_option, live_option

if TYPE_CHECKING:
    from controller.config import ControllerConfig

log = logging.getLogger("wheelchair-hil")


def add_arguments(p: argparse.ArgumentParser) -> None:
    bus_options(p)
    child_options(p)
    controller_option(p)
    p.add_argument(
        "--config",
        default=None,
        help="controller deployment TOML (default controller/controller.toml; a chair's: "
        "install-service --chair-template writes its template); its [bus] is used where --bus is not given",
    )
    p.add_argument(
        "--lockstep",
        action="store_true",
        help="lock-step with a bench's Bench_Step frames even where the configuration's "
        "[loop] clock is realtime (--realtime: the wall clock where it is lockstep)",
    )
    p.add_argument(
        "--log-root",
        default=None,
        metavar="DIR",
        help="write this run's logs into a new directory DIR/<UTC start time> (a service keeps "
        "every start's logs; instead of --out)",
    )
    live_option(
        p, "the controller's channels (those of controller.mcap) and every frame on the bus"
    )
    # run's live view: the Unix socket its view process reads (run passes it to its parts)
    p.add_argument("--live-feed", default=None, help=argparse.SUPPRESS)
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="real time: run the loop under SCHED_FIFO with this priority and lock memory, "
        "where the system permits (controller_stats.json says what was granted)",
    )


def realtime_clock(cfg: ControllerConfig, *, realtime: bool, lockstep: bool) -> bool:
    """The controller's clock: ``--realtime`` or ``--lockstep``, else the configuration's
    ``[loop] clock`` (a chair's file says realtime: its drives send no Bench_Step to wait for)."""
    if lockstep:
        if realtime:
            raise ConfigError("control: --lockstep and --realtime exclude each other")
        return False
    return bool(realtime) or cfg.loop.clock == "realtime"


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """The controller part (:func:`tools.run.parts.run_controller`) in this process until the
    run ends, on the clock the arguments or the configuration choose (:func:`realtime_clock`);
    1 when the run did not happen as asked (no bench in lock-step, the bus went down), else 0
    or the status of a part that lost frames."""
    from controller.config import load_config  # lazy: the stack
    from tools.cli import from_args  # lazy
    from tools.run.parts import bus_feed, new_run_dir, part_scheduling, run_controller  # lazy

    cfg = load_config(args.config)
    args.realtime = realtime_clock(
        cfg, realtime=args.realtime, lockstep=getattr(args, "lockstep", False)
    )
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
        live = from_args.live_view(args, stack)
        if live is not None and args.live is not None:
            stack.enter_context(
                bus_feed(spec, live.socket_path, realtime=args.realtime, dbc=args.dbc)
            )
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
    return from_args.loss_status("control", res["rx_dropped"], res["rx_buffer_bytes"])
