"""Fault-free real-time runs on a loaded machine: N runs under a CPU load.

    python -m tests.repro.realtime_loaded --runs 30 --duration 30 --out /tmp/rt30

Each run is ``wheelchair-hil run --realtime --bus udp_multicast`` (three processes in a
private namespace), fault-free, with its own seed, while ``tests.repro.loadgen`` keeps
``--load-procs`` spinning processes (default: one per core) busy for the whole series.
Prints one line per run (stop reason, tick max, deadline misses, the worst encoder
feedback age the controller saw while armed against its stale limit) and a total, and
writes ``DIR/series.json``.  Exit 1 if any run made a safe stop.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from tests.repro.loadgen import cpu_load

_AGE = re.compile(
    r"worst encoder feedback age while armed: ([0-9.]+) ms \(stale above ([0-9.]+) ms\)"
)


def one_run(
    out: Path, seed: int, duration: float, controller: str, rt_priority: int = 0
) -> dict[str, Any]:
    out.mkdir(parents=True, exist_ok=True)
    argv = [
        sys.executable, "-m", "tools.cli", "run", "--realtime", "--bus", "udp_multicast",
        "--scenario", "fault-free", "--controller", controller, "--duration", str(duration),
        "--seed", str(seed), "--out", str(out),
    ]  # fmt: skip
    if rt_priority:
        argv += ["--rt-priority", str(rt_priority)]
    t0 = time.monotonic()
    res = subprocess.run(
        argv, capture_output=True, text=True, check=False, timeout=duration * 6 + 120
    )
    row: dict[str, Any] = {"seed": seed, "exit": res.returncode, "wall_s": time.monotonic() - t0}
    try:
        ctl = json.loads((out / "controller_stats.json").read_text())
    except (OSError, ValueError) as err:
        row.update(error=f"no controller_stats.json: {err}", stderr=res.stderr[-2000:])
        return row
    row.update(
        stop_reason=ctl.get("stop_reason"),
        stop_detail=ctl.get("stop_detail"),
        final_state=ctl.get("final_state"),
        tick_us_max=ctl.get("tick_us_max"),
        deadline_misses=ctl.get("deadline_misses"),
        lateness_us_max=ctl.get("lateness_us_max"),
        encoder_age_max_ms=ctl.get("encoder_age_max_ms"),
        encoder_stale_limit_ms=ctl.get("encoder_stale_limit_ms"),
        controller_sched=ctl.get("realtime_notes"),
    )
    try:
        row["bench_sched"] = json.loads((out / "bench_stats.json").read_text()).get(
            "realtime_notes"
        )
    except (OSError, ValueError):
        row["bench_sched"] = None
    log = out / "logs" / "control.log"
    if row["encoder_age_max_ms"] is None and log.exists():
        m = _AGE.search(log.read_text(errors="replace"))
        if m:
            row["encoder_age_max_ms"], row["encoder_stale_limit_ms"] = float(m[1]), float(m[2])
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--controller", default="baseline")
    ap.add_argument("--load-procs", type=int, default=os.cpu_count() or 2)
    ap.add_argument("--load-nice", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="run as a chair's service does: the controller at SCHED_FIFO PRIO, the bench "
        "(standing in for the drives' own hardware) at PRIO+1 (0: both SCHED_OTHER)",
    )
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    rows = []
    with cpu_load(a.load_procs, seconds=a.runs * (a.duration * 6 + 180), nice=a.load_nice):
        for i in range(a.runs):
            seed = a.first_seed + i
            row = one_run(a.out / f"run{seed:02d}", seed, a.duration, a.controller, a.rt_priority)
            rows.append(row)
            print(json.dumps(row), flush=True)
            (a.out / "series.json").write_text(json.dumps(rows, indent=1))
    stops = [r for r in rows if r.get("stop_reason") not in ("NONE", "ROUTE_DONE")]
    ages = [r["encoder_age_max_ms"] for r in rows if r.get("encoder_age_max_ms") is not None]
    lim = next((r["encoder_stale_limit_ms"] for r in rows if r.get("encoder_stale_limit_ms")), None)
    print(
        f"{len(rows)} runs under {a.load_procs} spinning processes (nice {a.load_nice}), "
        f"{'SCHED_FIFO ' + str(a.rt_priority) if a.rt_priority else 'SCHED_OTHER'}: {len(stops)} safe stops "
        f"({', '.join(str(r.get('stop_reason')) + ' ' + str(r.get('stop_detail')) for r in stops) or 'none'}); "
        f"worst encoder age {max(ages) if ages else 'n/a'} ms against a limit of {lim} ms; "
        f"worst tick {max((r.get('tick_us_max') or 0) for r in rows) / 1000:.1f} ms; "
        f"deadline misses {sum((r.get('deadline_misses') or 0) for r in rows)}"
    )
    return 1 if stops or any(r.get("error") for r in rows) else 0


if __name__ == "__main__":
    raise SystemExit(main())
