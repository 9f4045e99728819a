"""Arguments of ``wheelchair-hil sandbox`` and its action: a command in a namespace prepared for
udp_multicast, or with ``--socketcan`` where SocketCAN vcan0 is up."""

from __future__ import annotations

import argparse
import os


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--socketcan",
        action="store_true",
        help="run CMD where SocketCAN vcan0 is up: the host's if its kernel has CAN, else in a "
        "user-mode Linux guest (packages user-mode-linux, kmod)",
    )
    p.add_argument("cmd", nargs=argparse.REMAINDER, help="command (after --); default: $SHELL")


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Run CMD (default ``$SHELL``) and return its exit status.

    Without ``--socketcan``: in a private network namespace prepared for udp_multicast
    (:func:`tools.bus.transport.exec_in_sandbox`).  With it: where SocketCAN vcan0 is up, the
    host's if its kernel has CAN, else in a user-mode Linux guest (:mod:`tools.bus.umlguest`).
    """
    from tools.bus import umlguest  # lazy: python-can
    from tools.bus.transport import exec_in_sandbox  # lazy

    cmd = list(args.cmd)
    if cmd and cmd[0] == "--":
        cmd = cmd[1:]
    if not cmd:
        cmd = [os.environ.get("SHELL", "/bin/sh")]
    if args.socketcan:
        return umlguest.run_with_vcan(cmd)
    return exec_in_sandbox(cmd)
