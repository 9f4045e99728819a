"""Arguments of ``wheelchair-hil summarize``: summary.json recomputed from a run's MCAP alone."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="run.mcap")
    p.add_argument("--out", default=None, help="write the summary to this JSON file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument(
        "--partial",
        action="store_true",
        help="a log that is damaged, truncated or lacks records still exits 0 (the summary "
        "says what is missing)",
    )
    p.add_argument(
        "--scenario",
        default=None,
        help="scenario name or file, for a log whose scenario/route attachments were lost",
    )
