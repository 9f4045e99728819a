"""``wheelchair-hil sandbox -- CMD``: CMD where the bus is ready for it.

Without ``--socketcan``: in a private network namespace prepared for udp_multicast
(:func:`tools.bus.transport.exec_in_sandbox`).  With it: where SocketCAN vcan0 is up, the
host's if its kernel has CAN, else in a user-mode Linux guest (:mod:`tools.bus.umlguest`).
"""

from __future__ import annotations

import argparse
import os

from tools.bus import umlguest
from tools.bus.transport import exec_in_sandbox


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Run CMD (default ``$SHELL``) and return its exit status."""
    cmd = list(args.cmd)
    if cmd and cmd[0] == "--":
        cmd = cmd[1:]
    if not cmd:
        cmd = [os.environ.get("SHELL", "/bin/sh")]
    if args.socketcan:
        return umlguest.run_with_vcan(cmd)
    return exec_in_sandbox(cmd)
