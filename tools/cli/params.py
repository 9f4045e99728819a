"""Arguments of ``wheelchair-hil params``: every parameter with unit, default and bounds."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--markdown", action="store_true", help="as a Markdown table")
