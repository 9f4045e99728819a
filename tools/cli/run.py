"""Arguments of ``wheelchair-hil run`` and its action: bench, controller and recorder on one bus."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from dbc.runtime import jsonsafe, stopping
from dbc.runtime.errors import BusError
from tools.cli.options import bus_options, controller_option, live_option

if TYPE_CHECKING:
    from tools.bus.transport import BusSpec

#: Set for the run re-executed in a private namespace: why its parent chose udp_multicast.
_CHOSEN_ENV = "WHEELCHAIR_HIL_BUS_CHOSEN"


def add_arguments(p: argparse.ArgumentParser) -> None:
    bus_options(p)
    controller_option(p)
    p.add_argument(
        "--out",
        required=True,
        help="output directory: run.mcap (the whole run, docs/logs.md), summary.json",
    )
    live_option(p, "the run's channels (those of run.mcap)")
    # the live view run started before it re-executed itself in a private namespace
    p.add_argument("--live-feed", default=None, help=argparse.SUPPRESS)
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="real time over separate processes: the controller asks for SCHED_FIFO with this "
        "priority and locked memory, the bench (standing in for the drives' own hardware) "
        "for one above it (the summary and bench_stats.json say what was granted)",
    )


def choose_bus(interface: str | None) -> tuple[str, str]:
    """Pick the transport for ``run`` and say why: as requested, or ``chosen: ...``.

    Without ``--bus`` python-can's own configuration decides, as for ``control``
    (``CAN_INTERFACE``, can.conf); otherwise udp_multicast in a private namespace.
    """
    from tools.bus import transport  # lazy: python-can

    if interface:
        # the re-executed run inside the namespace its parent chose says the parent's reason
        chosen = os.environ.pop(_CHOSEN_ENV, "")
        if chosen and interface == "udp_multicast" and transport.in_private_namespace():
            return interface, chosen
        return interface, "as requested"
    configured = transport.python_can_config().get("interface")
    if configured:
        source = (
            f"CAN_INTERFACE={os.environ['CAN_INTERFACE']}"
            if os.environ.get("CAN_INTERFACE")
            else "python-can's can.conf"
        )
        return str(configured), f"chosen: from {source}"
    if transport.in_private_namespace():
        return "udp_multicast", "chosen: inside a private network namespace"
    ok, why = transport.sandbox_supported()
    if ok:
        return "udp_multicast", "chosen: in a new private network namespace (separate processes)"
    return (
        "virtual",
        f"chosen: one process on the virtual bus, no private namespace available ({why})",
    )


def without_live(argv: list[str]) -> list[str]:
    """``argv`` without its ``--live ADDRESS`` / ``--live=ADDRESS``."""
    out: list[str] = []
    skip = False
    for a in argv:
        if skip:
            skip = False
        elif a == "--live":
            skip = True
        elif not a.startswith("--live="):
            out.append(a)
    return out


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Where the run happens is decided before anything heavy.

    For udp_multicast outside a private network namespace, ``run`` re-executes itself inside
    one (``unshare -rn``).  It does so first, having imported only the bus layer: the run
    inside validates every input (scenario, route, controller, DBC) before a part starts, and
    names what is wrong in one line, as a run here would.  (Importing and validating twice
    cost a run 2 s of start-up on a 2-core machine.)  Otherwise the run happens here: its
    parts as threads on a one-process bus (:mod:`tools.run.in_process`), else as OS processes
    (:mod:`tools.run.cross_process`); then the summary (:mod:`tools.run.summary`).
    """
    from tools.bus import transport  # lazy: python-can; only the bus layer before the namespace

    # nothing is written here: the run (here or inside the namespace) validates every input,
    # --out included, before it makes a directory or starts a part
    iface, why = choose_bus(args.bus)
    spec = transport.resolve(
        iface,
        args.channel,
        allow_network_multicast=args.allow_network_multicast,
        bitrate=args.bitrate,
        options=transport.bus_options_of(args.bus_option),
    )
    if (
        transport.profile(spec.interface).private_namespace
        and not spec.allow_network_multicast
        and not transport.in_private_namespace()
    ):
        if os.environ.get(transport.SANDBOX_ENV) == "1":
            raise BusError(
                "inside the sandbox but the namespace is not private; refusing udp_multicast"
            )
        rest = list(argv)
        if "--bus" not in rest:
            rest += ["--bus", "udp_multicast"]
            os.environ[_CHOSEN_ENV] = why
        print(f"bus: udp_multicast {why}", file=sys.stderr)
        if args.live is None:
            return transport.exec_in_sandbox(transport.python_argv(*rest))
        # the view serves from out here: inside the namespace nobody outside could reach it
        from tools.live.server import LiveServer, format_live_stats  # lazy: with --live only

        with LiveServer(args.live) as view:
            print(f"live: {view.url} (open it in Foxglove)", file=sys.stderr, flush=True)
            code = transport.exec_in_sandbox(
                transport.python_argv(*without_live(rest), "--live-feed", view.socket_path)
            )
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)  # the run may have refused its input
        jsonsafe.write(out / "live_stats.json", view.stats, indent=2)
        print(f"live: {format_live_stats(view.stats)}", file=sys.stderr)
        return code
    return _run_here(args, spec, why)


def _run_here(args: argparse.Namespace, spec: BusSpec, why: str) -> int:
    """The run in this process, on ``spec`` (chosen for ``why``): validates every input before
    any part starts, runs, then writes and prints the summary."""
    from tools.bus import transport  # lazy: python-can
    from tools.bus.rxloss import LOSS_EXIT  # lazy
    from tools.cli import from_args  # lazy: the stack
    from tools.live.server import LiveServer, format_live_stats  # lazy
    from tools.logs.runlog import loss_message  # lazy
    from tools.run import cross_process, in_process  # lazy
    from tools.run.summary import build_summary, format_summary  # lazy

    codec = from_args.codec_for(args)
    plan_ = from_args.run_plan(args, args.controller)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    transport.profile(spec.interface).check(spec)  # socketcan without AF_CAN: said here
    print(
        f"bus: {spec.describe()} ({why}); controller {plan_.controller}; scenario "
        f"{plan_.scenario.name}; {'real time' if plan_.realtime else 'lock-step'}; "
        f"{plan_.duration_s:.1f} s simulated",
        file=sys.stderr,
    )
    with contextlib.ExitStack() as stack:
        live = None
        if args.live_feed:
            live = LiveServer.attached(args.live_feed)
        elif args.live is not None:
            live = stack.enter_context(LiveServer(args.live))
            print(f"live: {live.url} (open it in Foxglove)", file=sys.stderr, flush=True)
        t0 = time.monotonic()
        stop = stopping.stop_event()
        if not transport.profile(spec.interface).between_processes:  # one process's bus
            in_process.run_threads(spec, plan_, out, codec, live=live, stop_event=stop)
        else:
            cross_process.run_processes(
                spec, plan_, out, args.dbc, rt_priority=args.rt_priority, live=live, stop_event=stop
            )
        wall = time.monotonic() - t0
    if live is not None and not args.live_feed:
        jsonsafe.write(out / "live_stats.json", live.stats, indent=2)
        print(f"live: {format_live_stats(live.stats)}", file=sys.stderr)
    summary = build_summary(out, plan_, spec, wall)
    if stopping.received():  # ended early on request: the log is what the parts recorded
        summary["stopped_by"] = stopping.received()[0]
    jsonsafe.write(out / "summary.json", summary, indent=2, default=str)
    print(format_summary(summary))
    if not summary["complete"]:
        print(f"wheelchair-hil: error: {loss_message(summary['lost_frames'])}", file=sys.stderr)
        return LOSS_EXIT
    return 0
