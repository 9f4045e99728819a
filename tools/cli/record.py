"""Arguments of ``wheelchair-hil record`` and its action: every frame on the bus to MCAP."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
from pathlib import Path

from dbc.runtime import jsonsafe
from tools.cli.options import bus_options, live_option

log = logging.getLogger("wheelchair-hil")


def add_arguments(p: argparse.ArgumentParser) -> None:
    bus_options(p, scenario_required=False)
    p.add_argument("--ready", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--out", required=True, help="MCAP file to write")
    live_option(p, "the recording's channels")
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        metavar="N",
        help="with --realtime: SCHED_FIFO at N and locked memory, so that a loaded machine "
        "cannot starve the recorder until the kernel drops frames (run and attack give it one "
        "below the controller's); 0: niced, the default",
    )
    # run's live view: the Unix socket its view process reads (run passes it to its parts)
    p.add_argument("--live-feed", default=None, help=argparse.SUPPRESS)


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """The recorder part (:func:`tools.run.parts.run_recorder`) in this process until the run
    ends, its statistics next to its log; 0, or the status of a part that lost frames."""
    from controller.clock import try_realtime  # lazy: the stack
    from tools.cli import from_args  # lazy
    from tools.run import scenario as scenario_mod  # lazy
    from tools.run.parts import part_scheduling, run_recorder  # lazy

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
        live = from_args.live_view(args, stack)
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
    return from_args.loss_status(
        "record", stats.rx_dropped, stats.rx_buffer_bytes, stats.missed_steps
    )
