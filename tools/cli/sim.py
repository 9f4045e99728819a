"""Arguments of ``wheelchair-hil sim`` and its action: the bench alone, for a controller elsewhere."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from tools.cli.options import bus_options, child_options

log = logging.getLogger("wheelchair-hil")


def add_arguments(p: argparse.ArgumentParser) -> None:
    bus_options(p)
    child_options(p)
    p.add_argument(
        "--recorder-window",
        type=int,
        default=0,
        metavar="STEPS",
        help="lock-step: stay at most STEPS steps ahead of a recorder's Bench_Record_Ack "
        "(0: do not wait; 'run' uses 100 so that no frame is lost)",
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        metavar="PRIO",
        help="real time: the bench asks for SCHED_FIFO with this priority and locked memory; "
        "it stands in for the drives, which on a chair no load on the host can starve "
        "(bench_stats.json says what was granted)",
    )


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """The bench part (:func:`tools.run.parts.run_bench`) in this process until the run ends,
    its statistics next to its output; 0, or the status of a part that lost frames."""
    from tools.cli import from_args  # lazy: the stack
    from tools.run.parts import part_scheduling, run_bench  # lazy

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
    return from_args.loss_status("sim", stats.rx_dropped, stats.rx_buffer_bytes)
