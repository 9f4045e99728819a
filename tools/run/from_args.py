"""From parsed command-line arguments to the run's objects: bus spec, codec, plan, signals.

The subcommands' entry points (``tools.run.runner``, ``tools.run.inject``, ``tools.replay.engine``)
share these, so that ``--bus``, ``--dbc`` and ``--scenario`` mean the same everywhere.
"""

from __future__ import annotations

import argparse
import threading
from collections.abc import Callable
from typing import Any

from controller.config import BusParams
from dbc.codec import Codec
from dbc.runtime import stopping
from tools.bus import transport
from tools.bus.transport import bus_options_of
from tools.run import scenario as scenario_mod
from tools.run.runner import RunPlan, make_plan


def stop_on_signals() -> threading.Event:
    """The process's stop event: SIGTERM or SIGINT set it, from the part's start to its exit
    (:mod:`dbc.runtime.stopping`)."""
    return stopping.stop_event()


def ready_callback(args: argparse.Namespace) -> Callable[[], None] | None:
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


def bus_argv(spec: Any) -> list[str]:
    """The flags that reopen ``spec`` in a child process (``run``'s parts)."""
    argv = ["--bus", spec.interface, "--channel", spec.channel, "--bitrate", str(spec.bitrate)]
    for key, value in spec.options:
        argv += ["--bus-option", f"{key}={value}"]
    if spec.allow_network_multicast:
        argv.append("--allow-network-multicast")
    return argv


def codec_for(args: argparse.Namespace) -> Codec:
    return Codec(args.dbc) if args.dbc else Codec.default()


def run_plan(args: argparse.Namespace, controller: str | None = None) -> RunPlan:
    scen = scenario_mod.load(args.scenario)
    return make_plan(
        scen, controller, realtime=args.realtime, duration_s=args.duration, seed=args.seed
    )
