"""From parsed command-line arguments to the run's objects: bus spec, codec, plan, signals;
and what the commands that run a part share (its ``READY`` line, its live view, the exit
status of a part that lost frames).

The commands' actions (``tools/cli/<command>.py``) share these, so that ``--bus``, ``--dbc``,
``--scenario`` and ``--live`` mean the same everywhere.  It imports python-can and the stack:
an action imports it when it runs, never a command's parser.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import threading
from collections.abc import Callable

from controller.config import BusParams
from dbc.codec import Codec
from dbc.runtime import stopping
from tools.bus import transport
from tools.bus.rxloss import LOSS_EXIT
from tools.bus.transport import bus_options_of
from tools.live.server import LiveServer, format_live_stats
from tools.run import scenario as scenario_mod
from tools.run.plan import RunPlan, make_plan

log = logging.getLogger("wheelchair-hil")


def stop_on_signals() -> threading.Event:
    """The process's stop event: SIGTERM or SIGINT set it, from the part's start to its exit
    (:mod:`dbc.runtime.stopping`)."""
    return stopping.stop_event()


def ready_callback(args: argparse.Namespace) -> Callable[[], None] | None:
    """With ``--ready``: a callback that prints ``READY`` once the part can receive."""
    if not getattr(args, "ready", False):
        return None

    def ready() -> None:
        print("READY", flush=True)
        stopping.at("ready")

    return ready


def bus_spec(args: argparse.Namespace, config: BusParams | None = None) -> transport.BusSpec:
    """The bus the arguments name; what they leave open comes from ``config`` (a chair's
    ``[bus]``), then python-can's own configuration."""
    interface, channel, bitrate = args.bus, args.channel, getattr(args, "bitrate", None)
    if config is not None and config.interface and interface in (None, config.interface):
        interface = config.interface
        channel = channel or config.channel or None
        bitrate = bitrate or config.bitrate
    return transport.resolve(
        interface,
        channel,
        allow_network_multicast=args.allow_network_multicast,
        bitrate=bitrate,
        options=bus_options_of(getattr(args, "bus_option", [])),
    )


def codec_for(args: argparse.Namespace) -> Codec:
    """The codec of ``--dbc`` (default: the project's DBC)."""
    return Codec(args.dbc) if args.dbc else Codec.default()


def run_plan(args: argparse.Namespace, controller: str | None = None) -> RunPlan:
    """The plan of ``--scenario`` with ``--realtime``, ``--duration`` and ``--seed``; with
    ``--plan`` (a part that ``run`` started) its route's trajectory loaded, not planned."""
    scen = scenario_mod.load(args.scenario)
    saved = getattr(args, "plan", None)
    traj = None
    if saved:  # planned by the process that started this part (run): the same trajectory
        from controller.planner import load_plan  # lazy: the parts that plan nothing

        traj = load_plan(saved, scen.route, str(scen.route_path))
    return make_plan(
        scen,
        controller,
        realtime=args.realtime,
        duration_s=args.duration,
        seed=args.seed,
        trajectory=traj,
    )


def live_view(args: argparse.Namespace, stack: contextlib.ExitStack) -> LiveServer | None:
    """The live view of ``--live`` (started here, its address printed) or ``--live-feed``
    (run's), if any."""
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


def loss_status(part: str, dropped: int, buffer_bytes: int, missed_steps: int = 0) -> int:
    """A part's exit status from what it lost: 0, or :data:`LOSS_EXIT` with its one-line error."""
    if dropped == 0 and missed_steps == 0:
        return 0
    what = [f"the kernel dropped {dropped} frames from its full receive queue ({buffer_bytes} B)"]
    if missed_steps:
        what.append(f"{missed_steps} Bench_Step periods are missing from its log")
    print(f"wheelchair-hil: error: {part} lost frames: {'; '.join(what)}", file=sys.stderr)
    return LOSS_EXIT
