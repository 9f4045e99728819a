"""Arguments of ``wheelchair-hil replay`` and its action.

replay has four modes:

* ``--bus ... [--speed K]``: re-transmit the recorded frames (``/can/raw``, in bus
  order) with their original timing, or K times faster: to drive a bench (the
  bench ignores its own frames and acts on the host's) or a viewer.  Lock-step
  recordings replay on simulation time.
* ``--verify``: feed the recorded drive feedback to a fresh controller of the
  recorded kind, offline, and check that every frame it sends equals the recorded
  one.  Exits 1 and names the first differing frame if any differs.  Needs a
  lock-step recording.
* ``--controller NAME``: what-if.  Open loop: NAME's response to the same recorded
  inputs (setpoint differences per wheel; ``--out`` keeps its frames and internals
  in an MCAP).  Closed loop: the recorded scenario (from the log's attachments)
  re-run with NAME on the virtual bus, summaries side by side.
* ``--live [HOST:]PORT [--speed K]``: serve the log's channels to Foxglove over its
  WebSocket protocol at the recorded pace, or K times faster, from when the first
  client subscribes (``--no-wait``: at once); with ``--bus`` the frames are
  re-transmitted at the same time.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from dbc.runtime import stopping
from dbc.runtime.errors import WheelchairError
from tools import extras
from tools.cli.options import bus_arguments, controller_name, live_option
from tools.replay import ReplayError

if TYPE_CHECKING:
    from tools.live.view import LiveView


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="run.mcap (or any recorder MCAP)")
    bus_arguments(p, what="re-transmit the log on it (default: CAN_INTERFACE / can.conf)")
    p.add_argument(
        "--speed", type=float, default=1.0, metavar="K", help="K times faster than recorded"
    )
    p.add_argument(
        "--no-progress",
        action="store_true",
        help="--bus: no progress on stderr (a bar on a terminal, else a line per 10 %% of the frames)",
    )
    p.add_argument(
        "--verify",
        action="store_true",
        help="offline: a fresh controller of the recorded kind must send exactly the recorded frames",
    )
    p.add_argument(
        "--controller",
        type=controller_name,
        default=None,
        metavar="NAME",
        help="what-if: NAME's open-loop response to the recorded inputs and a closed-loop re-run",
    )
    p.add_argument("--out", default=None, help="directory for the what-if outputs")
    live_option(p, "the log's channels at the recorded pace (or --speed K times faster)")
    p.add_argument(
        "--no-wait",
        action="store_true",
        help="with --live: start at once instead of when the first client subscribes",
    )


def existing_log(p: str) -> Path:
    """``p`` as a path, ReplayError unless it is a file (replay's and summarize's log)."""
    path = Path(p)
    if not path.is_file():
        raise ReplayError(f"{path}: no such log file")
    return path


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Replay the log in the mode the arguments choose: verify, what-if, live, or
    re-transmission; print what was done and return the exit status."""
    from tools.bus import transport  # lazy: python-can
    from tools.cli import from_args  # lazy: the stack
    from tools.console.progress import Progress  # lazy
    from tools.logs import mcap_io  # lazy
    from tools.replay.retransmit import retransmit  # lazy

    path = existing_log(args.log)
    if args.live is not None and (args.verify or args.controller):
        raise WheelchairError(
            "replay --live serves a log; it does not go with --verify or --controller"
        )
    if args.verify or args.controller:
        stopping.raise_on_stop()  # a computation, no loop to end: a stop signal interrupts it
    if args.verify:
        return _verify(path, args)
    if args.controller:
        return _what_if(path, args)
    if args.live is not None:
        return _serve_live(path, args)

    spec = from_args.bus_spec(args)
    stop = from_args.stop_on_signals()
    t0 = time.monotonic()
    total = mcap_io.raw_frame_count(path)
    bus = transport.open_bus(spec)
    try:
        with Progress(total, "replay", "frame", enabled=not args.no_progress) as bar:
            n = retransmit(
                path, bus, speed=args.speed, stop_event=stop, on_frame=lambda _m: bar.update()
            )
    finally:
        bus.shutdown()
    print(f"replayed {n} frames on {spec.describe()} in {time.monotonic() - t0:.1f} s")
    return 0


def _serve_live(path: Path, args: argparse.Namespace) -> int:
    """``replay LOG --live [HOST:]PORT [--bus ...]``: serve the log, re-transmit it too if asked."""
    extras.require("replay --live", "live")
    from tools.bus import transport  # lazy: python-can
    from tools.cli import from_args  # lazy: the stack
    from tools.replay.serve import serve  # lazy

    stop = from_args.stop_on_signals()
    bus = None
    if args.bus is not None:
        bus = transport.open_bus(from_args.bus_spec(args))

    def ready(view: LiveView) -> None:
        print(f"live: {view.url} (open it in Foxglove)", file=sys.stderr, flush=True)

    t0 = time.monotonic()
    try:
        counts, sent = serve(
            path,
            args.live,
            speed=args.speed,
            wait_for_client=not args.no_wait,
            stop_event=stop,
            bus=bus,
            on_ready=ready,
        )
    finally:
        if bus is not None:
            bus.shutdown()
    print(
        f"served {sum(counts.values())} messages on {len(counts)} channels in "
        f"{time.monotonic() - t0:.1f} s"
        + (f"; replayed {sent} frames on {args.bus}" if sent is not None else "")
    )
    return 0


def _verify(path: Path, args: argparse.Namespace) -> int:
    """Exit 0 only if every tick the log says was recorded was replayed and matched."""
    from dbc.codec import Codec  # lazy: the codec
    from tools.replay.verify import verify  # lazy: the stack

    codec = Codec.default()
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    found = verify(path, args.controller, frames_path=out / "verify.mcap" if out else None)
    res, expected, source, damage = (
        found.result,
        found.expected_ticks,
        found.expected_from,
        found.damage,
    )
    print(
        f"{res.controller}: {res.ticks} ticks, {res.frames_compared} frames compared "
        f"({res.setpoints_compared} setpoints), {res.steps_skipped} unacknowledged steps skipped"
    )
    if res.first_mismatch is not None:
        if damage:  # say first that the log itself is damaged: differences may be its holes
            print(f"verify: the log is damaged: {'; '.join(damage)}", file=sys.stderr)
        print(
            f"verify: FAILED in {res.mismatched_ticks} ticks"
            + (
                " (the log is damaged: a difference may be a frame it could not read)"
                if damage
                else ""
            )
            + f"; first difference: {res.first_mismatch.describe(codec)}",
            file=sys.stderr,
        )
        return 1
    why = list(damage)
    if expected is None:
        why.append(
            "the log has no record of how many ticks were recorded (no controller_stats or "
            "recorder metadata: the run did not end cleanly)"
        )
    elif res.ticks < expected:
        why.append(f"{expected - res.ticks} recorded ticks are not in the readable part of the log")
    if res.ticks == 0:
        why.append("no tick was replayed")
    if why:
        total = "?" if expected is None else str(expected)
        print(
            f"verify: INCOMPLETE: {res.ticks} of {total} ticks verified"
            + (f" ({total} from {source})" if source else "")
            + "; the rest were not: "
            + "; ".join(why),
            file=sys.stderr,
        )
        return 1
    print(
        f"verify: OK, all {res.ticks} of {expected} ticks ({source}): every frame equals the recorded one"
    )
    return 0


def _what_if(path: Path, args: argparse.Namespace) -> int:
    """NAME's open-loop response to the recorded inputs, then the closed-loop re-run beside
    the recorded run."""
    from tools.logs import runlog  # lazy: the stack
    from tools.replay.whatif import closed_loop, open_loop, setpoint_difference  # lazy
    from tools.run.summary import format_summary  # lazy

    name = args.controller
    out = Path(args.out) if args.out else Path(f"whatif-{name}")
    out.mkdir(parents=True, exist_ok=True)
    res, frames = open_loop(path, name, out)
    print(f"open loop: {name} on the recorded inputs ({res.ticks} ticks) -> {frames}")
    for wheel, rows in sorted(res.setpoints.items()):
        rms, big = setpoint_difference(rows)
        print(f"  {wheel:<5} setpoint difference: RMS {rms:.4f} rev/s, max {big:.4f} rev/s")
    recorded = runlog.summarize(path)
    new = closed_loop(path, name, out / f"closed-loop-{name}")
    print("closed loop, recorded run:")
    print(format_summary(recorded))
    print(f"closed loop, re-run with {name} -> {out / f'closed-loop-{name}'}:")
    print(format_summary(new))
    return 0
