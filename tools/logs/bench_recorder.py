"""Benchmark of the recorder's per-frame cost: ``python -m tools.logs.bench_recorder LOG.mcap``.

Replays the frames of a recorded run (``/can/raw``) through :class:`FrameLog` into a
fresh MCAP (raw, decoded and Foxglove channels, lock-step stamping, default chunking)
and prints the best of ``--repeat`` runs in µs per frame.  The recorder must keep up
with about 9 frames per 10 ms control period at 10-20x real time.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from dbc.runtime.mcapwriter import LogWriter
from tools.logs.mcap_io import iter_frames
from tools.logs.recorder import FrameLog


def per_frame_us(log: Path, repeat: int = 5) -> tuple[int, float]:
    """(frames, best µs per frame) of recording ``log``'s frames again."""
    frames = [m for _t, m in iter_frames(log, timestamps="receive")]
    best = float("inf")
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeat):
            rec = FrameLog(LogWriter(Path(tmp) / "bench.mcap"), lockstep=True)
            record = rec.record
            t0 = time.perf_counter()
            for m in frames:
                record(m)
            rec.close()
            best = min(best, time.perf_counter() - t0)
    return len(frames), best / max(1, len(frames)) * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("log", type=Path, help="a recorded run.mcap")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    n, us = per_frame_us(args.log, args.repeat)
    print(f"recorder: {us:.1f} us/frame over {n} frames (best of {args.repeat})")


if __name__ == "__main__":
    main()
