"""Arguments of ``wheelchair-hil sandbox``: a command in a namespace prepared for udp_multicast."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("cmd", nargs=argparse.REMAINDER, help="command (after --); default: $SHELL")
