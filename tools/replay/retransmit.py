"""Re-transmission of a recorded log: its frames (``/can/raw``, in bus order) sent on a bus with
their original timing, or K times faster (``replay --bus``): to drive a bench (the bench
ignores its own frames and acts on the host's) or a viewer."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from pathlib import Path

import can

from tools.logs.mcap_io import iter_frames
from tools.replay import ReplayError


def retransmit(
    path: str | Path,
    bus: can.BusABC,
    *,
    speed: float = 1.0,
    stop_event: threading.Event | None = None,
    on_frame: Callable[[can.Message], None] | None = None,
) -> int:
    """Send the recorded frames on ``bus`` at their log times divided by ``speed``.

    Frames whose log time is earlier than an already sent one (lock-step ground
    truth) go out at once.  Returns the number of frames sent.
    """

    if not (speed > 0 and math.isfinite(speed)):
        raise ReplayError(f"--speed {speed}: must be a finite number > 0")
    stop = stop_event or threading.Event()
    sent = 0
    first: int | None = None
    start = time.monotonic()
    for log_ns, msg in iter_frames(path):
        if stop.is_set():
            break
        if first is None:
            first = log_ns
        delay = start + (log_ns - first) * 1e-9 / speed - time.monotonic()
        if delay > 0 and stop.wait(delay):
            break
        bus.send(msg)
        sent += 1
        if on_frame is not None:
            on_frame(msg)
    return sent
