"""The attacking node's process: ``python -m tools.safety.attacks attacker --attack X ...``, the
command line :func:`~tools.safety.attacks.attacker.attacker_part` gives it, parsed into
:class:`~tools.safety.attacks.attacker.AttackerOptions` for
:func:`~tools.safety.attacks.attacker.run_attacker`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tools.safety.attacks.attacker import ATTACKS, AttackerOptions, run_attacker


def main(argv: list[str]) -> int:
    """Parse the attacker's command line (after ``attacker``) and attack."""
    ap = argparse.ArgumentParser(prog="attacker")
    ap.add_argument("--attack", required=True, choices=ATTACKS)
    ap.add_argument("--at", type=float, required=True, help="onset, simulated s")
    ap.add_argument("--auth", choices=("on", "off"), required=True)
    ap.add_argument("--kill-pid-file", default=None)
    ap.add_argument("--out", required=True)
    ap.add_argument("--bus", default="udp_multicast", help="python-can interface of the run")
    ap.add_argument("--channel", default=None, help="its channel (default: the interface's)")
    ap.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority once started (0: none), as another node's own hardware has",
    )
    args = ap.parse_args(argv)
    return run_attacker(
        AttackerOptions(
            attack=args.attack,
            at_s=args.at,
            out=Path(args.out),
            kill_pid_file=Path(args.kill_pid_file) if args.kill_pid_file else None,
            bus=args.bus,
            channel=args.channel,
            rt_priority=args.rt_priority,
        )
    )


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "attacker":
        raise SystemExit(main(sys.argv[2:]))
    raise SystemExit("usage: python -m tools.safety.attacks attacker ...")
