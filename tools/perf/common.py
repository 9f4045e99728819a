"""What every benchmark of ``wheelchair-hil bench`` shares: percentiles, timing a call, the
route the full-stack runs use, a run through the command line, progress lines, the machine."""

from __future__ import annotations

import math
import os
import platform
import statistics
import subprocess
import sys
import time
from typing import Any

PAPER = "fault-free"


def pct(sorted_values: list[float], q: float) -> float:
    if not sorted_values:
        return math.nan
    k = (len(sorted_values) - 1) * q / 100.0
    i = int(k)
    j = min(i + 1, len(sorted_values) - 1)
    return sorted_values[i] + (sorted_values[j] - sorted_values[i]) * (k - i)


def per_call_us(fn: Any, calls: int, rounds: int = 7, clock: Any = time.perf_counter_ns) -> float:
    """Median over ``rounds`` of the mean time of ``fn()`` over ``calls`` calls (µs)."""
    means = []
    for _ in range(rounds):
        t0 = clock()
        for _ in range(calls):
            fn()
        means.append((clock() - t0) / calls / 1000.0)
    return statistics.median(means)


def cli_run(args: list[str], timeout: float) -> dict[str, Any]:
    res = subprocess.run(
        [sys.executable, "-m", "tools.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )
    if res.returncode != 0:
        return {"error": (res.stderr.strip().splitlines() or ["failed"])[-1]}
    return {}


def machine() -> dict[str, Any]:

    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "loadavg_at_start": [round(x, 2) for x in load],
        "date": time.strftime("%Y-%m-%d"),
    }


def progress(msg: str) -> None:
    print(f"[bench] {msg} ...", file=sys.stderr, flush=True)
