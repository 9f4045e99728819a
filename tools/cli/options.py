"""Options shared by the subcommands, so that every command takes ``--bus/--channel/--scenario/
--realtime`` and ``--controller`` the same way.  argparse only: turning them into buses, codecs
and plans is :mod:`tools.cli.from_args`.
"""

from __future__ import annotations

import argparse

from tools.live.address import LiveAddress


def bus_arguments(p: argparse.ArgumentParser, *, what: str = "") -> None:
    """``--bus/-i/--interface``, ``--channel/-c``, ``--bitrate/-b``, ``--bus-option`` and
    ``--allow-network-multicast``: python-can's own names and short flags (``can.logger``,
    ``can.player``) beside the stack's, for every command that opens a bus.  ``what`` ends the
    ``--bus`` help (what the command does on it, or where its default comes from)."""
    p.add_argument(
        "--bus",
        "-i",
        "--interface",
        dest="bus",
        default=None,
        metavar="INTERFACE",
        help="python-can interface: virtual, udp_multicast, socketcan, or any other python-can "
        "has (pcan, kvaser, slcan, gs_usb, seeedstudio, vector, ...); "
        + (what or "default: CAN_INTERFACE / can.conf"),
    )
    p.add_argument(
        "--channel",
        "-c",
        default=None,
        help="bus channel (udp_multicast: multicast group, default 239.74.163.2; socketcan: can0, "
        "vcan0)",
    )
    p.add_argument(
        "--bitrate",
        "-b",
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
        "--allow-network-multicast",
        action="store_true",
        help="open udp_multicast even where frames could leave the machine (not recommended)",
    )


def bus_options(p: argparse.ArgumentParser, *, scenario_required: bool = True) -> None:
    bus_arguments(p, what="default: CAN_INTERFACE / can.conf ('run' picks one itself)")
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
        metavar="S",
        help="simulated seconds (default: from the scenario)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        metavar="N",
        help="seed of every random process, 0 to 2147483647 as in a scenario file "
        "(default: the scenario's)",
    )
    p.add_argument(
        "--dbc", default=None, help="DBC file to use instead of the project's dbc/wheelchair.dbc"
    )


def child_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ready", action="store_true", help=argparse.SUPPRESS)
    # the scenario's route planned by the process that started this part (run over
    # udp_multicast or socketcan; controller.planner.save_plan), loaded instead of planned
    p.add_argument("--plan", default=None, metavar="FILE", help=argparse.SUPPRESS)
    p.add_argument("--out", default=None, help="output directory (stats, logs)")


def controller_name(value: str) -> str:
    """Controller names are case-insensitive: ``ANTIFRAGILE`` is ``antifragile``."""
    return value.strip().lower()


def controller_option(p: argparse.ArgumentParser) -> None:
    # the registry's names, the variants' and the installed plug-ins' included (imported
    # only when the command that takes a controller builds its parser)
    from controller.tracking import registry  # lazy: only the commands that take a controller

    p.add_argument(
        "--controller",
        type=controller_name,
        default=None,
        metavar="NAME",
        help=f"{', '.join(registry.names())} (any case)",
    )


def _live_address(text: str) -> LiveAddress:
    try:
        return LiveAddress.parse(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def live_option(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument(
        "--live",
        type=_live_address,
        default=None,
        metavar="[HOST:]PORT",
        help=f"serve {what} to Foxglove over its WebSocket protocol while it runs (open "
        "ws://HOST:PORT in Foxglove); binds 127.0.0.1 unless HOST is given; PORT 0 takes a "
        "free port (printed)",
    )
