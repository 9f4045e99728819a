"""The full stack's speed: lock-step real-time factors (virtual bus, and udp_multicast across three
processes), the real-time loop's lateness, the bus load, and the end-to-end latency of a
setpoint across processes (``lockstep_rtf``, ``lockstep_budget_us``, ``rt_lateness_us``,
``bus_load_pct``, ``e2e_latency_us``).  ``python -m tools.perf.stack --e2e-probe N`` is the
latency probe, run inside a private network namespace."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from dbc.codec import (
    AxisState,
    Codec,
    ControlMode,
    EncoderCount,
    Heartbeat,
    InputMode,
    Node,
    SetAxisState,
    SetControllerMode,
    SetInputVel,
)
from dbc.runtime.busio import recv_dropping
from tools.bus import transport
from tools.bus.busload import frame_bits, load_pct
from tools.bus.transport import open_bus, resolve
from tools.logs.runlog import summarize  # noqa: F401  (the log is finalized by run_experiment)
from tools.perf.common import PAPER, cli_run, pct
from tools.run.experiment import run_experiment


def lockstep_rtf(names: list[str], work: Path) -> dict[str, Any]:

    out: dict[str, Any] = {}
    for name in names:
        s = run_experiment(work / f"rtf-{name}", PAPER, name)
        out[name] = {
            "rtf": s["real_time_factor"],
            "wall_s": s["wall_s"],
            "frames": s["frames_total"],
            "bus_load_pct": s.get("bus_load_pct"),
            "step_us_in_stack_p50": s.get("controller_step_us_p50"),
            "budget_us": s.get("lockstep_budget_us"),
        }
    return out


def udp_rtf(work: Path) -> dict[str, Any]:
    out = work / "rtf-udp"
    err = cli_run(
        [
            "run",
            "--controller",
            "baseline",
            "--scenario",
            PAPER,
            "--bus",
            "udp_multicast",
            "--out",
            str(out),
        ],
        timeout=600,
    )
    if err:
        return err
    s = json.loads((out / "summary.json").read_text())
    return {"rtf": s["real_time_factor"], "wall_s": s["wall_s"], "frames": s["frames_total"]}


def realtime(work: Path, seconds: float, rt_priority: int) -> dict[str, Any]:
    out = work / "realtime"
    err = cli_run(
        [
            "run",
            "--realtime",
            "--controller",
            "baseline",
            "--scenario",
            PAPER,
            "--duration",
            str(seconds),
            "--bus",
            "udp_multicast",
            "--rt-priority",
            str(rt_priority),
            "--out",
            str(out),
        ],
        timeout=seconds * 3 + 120,
    )
    if err:
        return err
    s = json.loads((out / "summary.json").read_text())
    return {
        "rt_lateness_us": {k: s.get(f"lateness_us_{k}") for k in ("p50", "p99", "p999", "max")},
        "rt_missed_cycles": s.get("missed_ticks"),
        "rt_notes": s.get("realtime_notes") or ["no SCHED_FIFO requested"],
        "rt_seconds": seconds,
        "controller_rss_mb": s.get("controller_peak_rss_mb"),
        "rt_tracking_rmse_pos_m": s.get("rmse_pos_m"),
    }


def bus_load(work: Path) -> dict[str, Any]:
    """The stack's own frames vs everything on the bus, from a lock-step run's log."""

    run = work / "rtf-baseline"
    if not (run / "recorder_stats.json").exists():
        return {"error": "no baseline run to read"}
    rec = json.loads((run / "recorder_stats.json").read_text())
    summ = json.loads((run / "summary.json").read_text())
    codec = Codec.default()
    sim_s = float(summ["sim_duration_s"])
    stack_bits = all_bits = 0
    for name, count in rec.get("by_name", {}).items():
        msg = codec.db.get_message_by_name(name)
        bits = frame_bits(msg.length, msg.is_extended_frame) * int(count)
        all_bits += bits
        if not msg.is_extended_frame:  # bench frames are 29-bit and absent on a real chair
            stack_bits += bits
    return {
        "bus_load_pct": load_pct(stack_bits, sim_s),
        "bus_load_pct_with_bench": load_pct(all_bits, sim_s),
    }


# ------------------------------------------------------------------ e2e latency


def e2e_probe(samples: int) -> dict[str, Any]:
    """Inside a private namespace: a real-time bench in a child process, this process as host."""

    codec = Codec.default()
    spec = resolve("udp_multicast", None)
    sim = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tools.cli",
            "sim",
            "--bus",
            "udp_multicast",
            "--realtime",
            "--scenario",
            "short",
            "--duration",
            str(samples * 0.05 + 30),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    bus = open_bus(spec)
    dropped: dict[str, int] = {}  # what the bus carried that was no frame
    lat: list[float] = []
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:  # wait for the left drive's heartbeat
            m = recv_dropping(bus, 0.5, dropped)
            if m is not None and codec.is_known(m) and not m.is_extended_id:
                try:
                    f = codec.decode(m)
                except Exception:
                    continue
                if f.node == Node.LEFT and isinstance(f.payload, Heartbeat):
                    break
        else:
            return {"error": "bench did not come up"}
        send = bus.send
        send(codec.encode(SetInputVel(0.0), Node.LEFT))
        send(
            codec.encode(
                SetControllerMode(ControlMode.VELOCITY_CONTROL, InputMode.PASSTHROUGH), Node.LEFT
            )
        )
        send(codec.encode(SetAxisState(AxisState.CLOSED_LOOP_CONTROL), Node.LEFT))
        time.sleep(0.3)
        count_id = codec.frame_id(EncoderCount, Node.LEFT)
        rtr = codec.request(EncoderCount, Node.LEFT)
        for i in range(samples):
            v = 0.05 if i % 2 else 0.0
            t0 = time.perf_counter_ns()
            send(codec.encode(SetInputVel(v), Node.LEFT))
            send(rtr)
            t_end = time.monotonic() + 0.5
            while time.monotonic() < t_end:
                m = recv_dropping(bus, 0.5, dropped)
                if m is not None and m.arbitration_id == count_id and not m.is_remote_frame:
                    lat.append((time.perf_counter_ns() - t0) / 1000.0)
                    break
            time.sleep(0.02)
        send(codec.encode(SetInputVel(0.0), Node.LEFT))
        send(codec.encode(SetAxisState(AxisState.IDLE), Node.LEFT))
    finally:
        bus.shutdown()
        sim.terminate()
        try:
            sim.wait(10)
        except subprocess.TimeoutExpired:
            sim.kill()
    lat.sort()
    return {"e2e_latency_us": {"p50": pct(lat, 50), "p99": pct(lat, 99)}, "e2e_samples": len(lat)}


def e2e_latency(samples: int) -> dict[str, Any]:

    argv = transport.sandbox_argv(
        [sys.executable, "-m", "tools.perf.stack", "--e2e-probe", str(samples)]
    )
    res = subprocess.run(
        argv, capture_output=True, text=True, timeout=samples * 0.6 + 120, check=False
    )
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
    if res.returncode != 0 or not lines:
        return {"error": (res.stderr.strip().splitlines() or ["probe failed"])[-1]}
    return json.loads(lines[-1])


if __name__ == "__main__":  # the e2e probe runs inside a private namespace
    if len(sys.argv) == 3 and sys.argv[1] == "--e2e-probe":
        print(json.dumps(e2e_probe(int(sys.argv[2]))))
        sys.exit(0)
    sys.exit(2)
