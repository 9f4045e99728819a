"""Arguments of ``wheelchair-hil replay``.

replay has four modes:

* ``--bus ... [--speed K]``: re-transmit the recorded frames (``/can/raw``, in bus
  order) with their original timing, or K times faster: to drive a bench (the
  bench ignores its own frames and acts on the host's) or a viewer.  Lock-step
  recordings replay on simulation time.
* ``--verify``: feed the recorded drive feedback to a fresh controller of the
  recorded kind, offline, and check that every frame it sends equals the recorded
  one.  Exits 1 and names the first differing frame if any differs.  Needs a
  lock-step recording.
* ``--controller NAME``: what-if.  Open loop: NAME's response to the same recorded
  inputs (setpoint differences per wheel; ``--out`` keeps its frames and internals
  in an MCAP).  Closed loop: the recorded scenario (from the log's attachments)
  re-run with NAME on the virtual bus, summaries side by side.
* ``--live [HOST:]PORT [--speed K]``: serve the log's channels to Foxglove over its
  WebSocket protocol at the recorded pace, or K times faster, from when the first
  client subscribes (``--no-wait``: at once); with ``--bus`` the frames are
  re-transmitted at the same time.
"""

from __future__ import annotations

import argparse

from tools.cli.options import bus_arguments, controller_name, live_option


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="run.mcap (or any recorder MCAP)")
    bus_arguments(p, what="re-transmit the log on it (default: CAN_INTERFACE / can.conf)")
    p.add_argument(
        "--speed", type=float, default=1.0, metavar="K", help="K times faster than recorded"
    )
    p.add_argument(
        "--no-progress",
        action="store_true",
        help="--bus: no progress on stderr (a bar on a terminal, else a line per 10 %% of the frames)",
    )
    p.add_argument(
        "--verify",
        action="store_true",
        help="offline: a fresh controller of the recorded kind must send exactly the recorded frames",
    )
    p.add_argument(
        "--controller",
        type=controller_name,
        default=None,
        metavar="NAME",
        help="what-if: NAME's open-loop response to the recorded inputs and a closed-loop re-run",
    )
    p.add_argument("--out", default=None, help="directory for the what-if outputs")
    live_option(p, "the log's channels at the recorded pace (or --speed K times faster)")
    p.add_argument(
        "--no-wait",
        action="store_true",
        help="with --live: start at once instead of when the first client subscribes",
    )
