"""Arguments of ``wheelchair-hil sandbox``: a command in a namespace prepared for udp_multicast,
or with ``--socketcan`` where SocketCAN vcan0 is up."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--socketcan",
        action="store_true",
        help="run CMD where SocketCAN vcan0 is up: the host's if its kernel has CAN, else in a "
        "user-mode Linux guest (packages user-mode-linux, kmod)",
    )
    p.add_argument("cmd", nargs=argparse.REMAINDER, help="command (after --); default: $SHELL")
