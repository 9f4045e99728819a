"""Shared pieces of the command line: bus options, plan building, signals, readiness.

Subcommand modules (``tools.cli`` and the extension modules it lists) use these so
that every command takes ``--bus/--channel/--scenario/--realtime`` the same way.
"""

from __future__ import annotations

import argparse
import signal
import threading
from collections.abc import Callable
from typing import Any


def bus_options(p: argparse.ArgumentParser, *, scenario_required: bool = True) -> None:
    p.add_argument(
        "--bus",
        default=None,
        metavar="INTERFACE",
        help="python-can interface: virtual, udp_multicast, socketcan, or any other python-can "
        "has (pcan, kvaser, slcan, gs_usb, seeedstudio, vector, ...); default: CAN_INTERFACE / "
        "can.conf ('run' picks one itself)",
    )
    p.add_argument(
        "--bitrate",
        type=int,
        default=None,
        help="bit/s for interfaces python-can configures (default CAN_BITRATE / can.conf / 500000)",
    )
    p.add_argument(
        "--bus-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a python-can Bus keyword argument, passed through (repeatable; e.g. "
        "--bus-option fd=false, --bus-option serial=XYZ)",
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


def child_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ready", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--out", default=None, help="output directory (stats, logs)")


def stop_on_signals() -> threading.Event:
    stop = threading.Event()

    def handler(signum: int, _frame: Any) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)
    return stop


def ready_callback(args: argparse.Namespace) -> Callable[[], None] | None:
    if not getattr(args, "ready", False):
        return None

    def ready() -> None:
        print("READY", flush=True)

    return ready


def bus_spec(args: argparse.Namespace) -> Any:
    from tools import transport

    return transport.resolve(
        args.bus,
        args.channel,
        allow_network_multicast=args.allow_network_multicast,
        bitrate=getattr(args, "bitrate", None),
        options=bus_options_of(getattr(args, "bus_option", [])),
    )


def bus_options_of(items: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings to python-can keyword arguments (values as can.conf casts them)."""
    import can

    from dbc.errors import BusError

    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise BusError(f"--bus-option {item!r}: expected KEY=VALUE")
        out[key.strip()] = can.util.cast_from_string(value)
    return out


def bus_argv(spec: Any) -> list[str]:
    """The flags that reopen ``spec`` in a child process (``run``'s parts)."""
    argv = ["--bus", spec.interface, "--channel", spec.channel, "--bitrate", str(spec.bitrate)]
    for key, value in spec.options:
        argv += ["--bus-option", f"{key}={value}"]
    if spec.allow_network_multicast:
        argv.append("--allow-network-multicast")
    return argv


def codec_for(args: argparse.Namespace) -> Any:
    from dbc.codec import Codec

    return Codec(args.dbc) if args.dbc else Codec.default()


def run_plan(args: argparse.Namespace, controller: str | None = None) -> Any:
    from tools import scenario as scenario_mod
    from tools.runner import make_plan

    scen = scenario_mod.load(args.scenario)
    return make_plan(
        scen, controller, realtime=args.realtime, duration_s=args.duration, seed=args.seed
    )
