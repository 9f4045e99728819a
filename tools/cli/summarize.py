"""Arguments of ``wheelchair-hil summarize`` and its action: summary.json recomputed from a
run's MCAP alone."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dbc.runtime import jsonsafe
from tools.cli.replay import existing_log


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


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Summarize the log (:func:`tools.replay.summarize.summarize_log`), write and print the
    summary; 1 for a log that is not whole, unless ``--partial``."""
    from tools.replay.summarize import summarize_log  # lazy: the stack
    from tools.run.summary import format_summary  # lazy

    path = existing_log(args.log)
    summary = summarize_log(path, args.scenario)
    missing = summary["missing"]
    text = jsonsafe.dumps(summary, indent=2, default=str) + "\n"
    if args.out:
        Path(args.out).write_text(text)
    print(text if args.json else format_summary(summary), end="" if args.json else "\n")
    if missing and not args.partial:
        print(
            f"summarize: {path} is not whole ({len(missing)} gaps, listed above); the figures "
            "cover only what was readable. Pass --partial to accept that.",
            file=sys.stderr,
        )
        return 1
    return 0
