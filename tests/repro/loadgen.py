"""A bounded CPU load generator: N busy processes for at most a given time.

``python -m tests.repro.loadgen --procs 2 --seconds 600`` keeps two cores busy (pure
Python spinning, no I/O, no memory growth) and stops on its own after ``--seconds``,
or when its parent dies, or on SIGTERM/SIGINT.  Used by the loaded real-time runs of
the loaded real-time runs (``tests/repro/realtime_loaded.py``).
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing as mp
import os
import signal
import time
from collections.abc import Iterator


def _spin(until: float, parent: int, nice: int) -> None:
    if nice:
        os.nice(nice)
    x = 0
    while time.monotonic() < until:
        for _ in range(20_000):
            x = (x * 1103515245 + 12345) & 0x7FFFFFFF
        if os.getppid() != parent:  # the parent died: stop
            return


@contextlib.contextmanager
def cpu_load(procs: int = 2, seconds: float = 600.0, nice: int = 10) -> Iterator[list[mp.Process]]:
    """Run ``procs`` spinning processes while the block runs (and at most ``seconds``).

    ``nice`` (0..19) is their niceness.  At the default 10, that of the recorder (the
    launcher nices it to 10), both cores stay busy: the spinners take every idle cycle
    and preempt the loops at each time slice; at 0 they starve the niced recorder, which
    then never reports ready.
    """
    if not 1 <= procs <= 64 or not 0 < seconds <= 24 * 3600 or not 0 <= nice <= 19:
        raise ValueError(
            f"load: procs {procs} (1..64), seconds {seconds} (0..86400), nice {nice} (0..19)"
        )
    until = time.monotonic() + seconds
    ctx = mp.get_context("fork")
    ps = [
        ctx.Process(target=_spin, args=(until, os.getpid(), nice), daemon=True)
        for _ in range(procs)
    ]
    for p in ps:
        p.start()
    try:
        yield ps
    finally:
        for p in ps:
            p.terminate()
        for p in ps:
            p.join(5)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--procs", type=int, default=os.cpu_count() or 2)
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--nice", type=int, default=10)
    a = ap.parse_args()
    stop = False

    def _stop(*_: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    with cpu_load(a.procs, a.seconds, a.nice) as ps:
        while not stop and any(p.is_alive() for p in ps):
            time.sleep(0.2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
