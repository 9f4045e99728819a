"""``wheelchair-hil bench``: the stack's speed, measured in one run on this machine.

Every figure comes from this module, printed as a table and, with ``--json``, written
with the keys below.  Absolute times depend on the machine and its load; compare
ratios and medians taken in the same run.

* ``controller_step_us[name]``: p50/p99 of ``step()`` for every controller, in an
  offline closed loop over the paper route (ideal wheels, the node's limiter applied),
  so that only the law itself is timed;
* ``adaptive_vs_cvxpy_ratio``: the same MPC problem (``adaptive.qp_data``) formulated in
  cvxpy with parameters (a sparse parameter for the constraint matrix, DPP), solved by
  OSQP through cvxpy over the same states, median time divided by ours;
  ``adaptive_vs_osqp_floor``: our median ``step()`` over OSQP's own solve time;
* ``codec_us[message]`` (encode, decode) and ``telemetry_log_us`` (in_loop, forked): what a
  frame costs the codec and a tick record the controller's log (:func:`loop_costs`);
* ``lockstep_rtf[name]``: simulated seconds per wall second of the paper route through
  the full stack (bench, controller, recorder) on the virtual bus, and over
  udp_multicast with three processes (``lockstep_rtf_udp``);
  ``lockstep_budget_us[name]``: where a step of that run went (physics, controller
  tick, rest, in us) and ``rtf_ceiling``, the factor the physics and the ticks alone
  would allow (``tools.logs.runlog.lockstep_budget``);
* ``rt_lateness_us`` (p50, p99, p999, max) and ``rt_missed_cycles``: the controller's
  100 Hz loop against its absolute schedule in a real-time run of ``--rt-seconds``
  over udp_multicast (three processes), with SCHED_FIFO and locked memory where the
  system permits (``rt_notes`` says what was granted);
* ``e2e_latency_us`` (p50, p99): a setpoint sent -> the drive applies it -> feedback
  received, across processes over udp_multicast (the drive answers an RTR that follows
  the setpoint, so the answer proves the setpoint was taken);
* ``bus_load_pct``: the stack's own frames (drives, host, localizer) at 500 kbit/s with
  worst-case bit stuffing, and with the bench's frames (``bus_load_pct_with_bench``);
* ``live_tick_us`` (``bench --case live``): the controller's tick (p50, p99) and lateness
  in real-time runs without the live view, with it and no client, with a client on
  every channel and with a slow one, and what the view served and the client got
  (:func:`live_cost`);
* ``controller_rss_mb``: peak resident memory of the controller process (real-time
  run), and ``allocations_per_tick``: net allocated blocks per control step (a leak
  would show as a positive number) in the offline loop.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import math
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from controller.config import load_config
from controller.limits import CommandLimiter
from controller.planner import load_route, plan
from controller.telemetry import TICK_TOPIC, ForkedTelemetry, McapTelemetry
from controller.tracking import registry
from controller.tracking.adaptive import AdaptiveMPC
from controller.types import StateEstimate
from dbc.codec import (
    AxisState,
    Codec,
    ControlMode,
    EncoderCount,
    EncoderEstimates,
    Heartbeat,
    InputMode,
    Node,
    SetAxisState,
    SetControllerMode,
    SetInputVel,
    SetInputVelAuth,
    TruthPose,
)
from dbc.runtime import jsonsafe
from dbc.runtime.busio import recv_dropping
from tools.bus import transport
from tools.bus.busload import frame_bits, load_pct
from tools.bus.transport import open_bus, resolve
from tools.live.address import LiveAddress
from tools.live.server import LiveServer
from tools.logs.runlog import summarize  # noqa: F401  (the log is finalized by run_experiment)
from tools.run.experiment import run_experiment
from tools.run.scenario import route_file

PAPER = "fault-free"


# ------------------------------------------------------------------ offline loop


def _offline_loop(name: str, *, steps: int | None = None) -> dict[str, Any]:
    """Run controller ``name`` on the paper route with ideal wheels; time every step()."""

    cfg = load_config()
    traj = plan(load_route(route_file("paper")))
    ctl = registry.create(name, cfg.geometry, traj, motor=cfg.motor, body=cfg.body)
    lim = CommandLimiter(cfg.limits, cfg.geometry.half_track_m, cfg.geometry.wheel_radius_m)
    dt = cfg.loop.period_s
    n = steps or int(traj.duration_s / dt)
    s0 = traj.sample(0.0)
    x, y, phi, v, w = s0.x_m, s0.y_m, s0.heading_rad, 0.0, 0.0
    ctl.reset(StateEstimate(0.0, x, y, phi, 0.0, 0.0), 0.0)

    times = np.zeros(n, dtype=np.int64)  # preallocated: storing must not allocate
    blocks = np.zeros(n, dtype=np.int64)
    gc.collect()
    gc.disable()
    try:
        for k in range(n):
            t = k * dt
            ref = traj.sample(t)
            est = StateEstimate(t, x, y, phi, v, w)
            b0 = sys.getallocatedblocks()
            t0 = time.perf_counter_ns()
            cmd = ctl.step(t, dt, ref, est)
            times[k] = time.perf_counter_ns() - t0
            out = lim.apply(cmd, dt)
            blocks[k] = sys.getallocatedblocks() - b0
            v, w = out.v_mps, out.omega_radps
            x += v * math.cos(phi) * dt
            y += v * math.sin(phi) * dt
            phi += w * dt
    finally:
        gc.enable()
    us = sorted((times / 1000.0).tolist())
    warm = blocks[n // 10 :]
    return {
        "p50": _pct(us, 50),
        "p99": _pct(us, 99),
        "steps": n,
        "net_blocks_per_step": float(warm.mean()) if warm.size else math.nan,
        "internals": dict(ctl.internals()),
    }


def _pct(sorted_values: list[float], q: float) -> float:
    if not sorted_values:
        return math.nan
    k = (len(sorted_values) - 1) * q / 100.0
    i = int(k)
    j = min(i + 1, len(sorted_values) - 1)
    return sorted_values[i] + (sorted_values[j] - sorted_values[i]) * (k - i)


# ------------------------------------------------------- per frame and per tick


def _per_call_us(fn: Any, calls: int, rounds: int = 7, clock: Any = time.perf_counter_ns) -> float:
    """Median over ``rounds`` of the mean time of ``fn()`` over ``calls`` calls (µs)."""
    means = []
    for _ in range(rounds):
        t0 = clock()
        for _ in range(calls):
            fn()
        means.append((clock() - t0) / calls / 1000.0)
    return statistics.median(means)


def loop_costs(calls: int) -> dict[str, Any]:
    """What a frame costs the codec, and what a tick's record costs the loop to log.

    ``codec_us[message]``: encode and decode of one frame (``Get_Encoder_Estimates`` takes
    the whole-byte ``struct`` path, the authenticated setpoint the same path, the
    ground-truth pose scaled 24-bit signals); ``telemetry_log_us``: the CPU time of
    ``log()`` of a tick record in the loop (``McapTelemetry``) and shipped to a forked
    writer (``ForkedTelemetry``), the mean over all calls, shipping included.  CPU time,
    because called back to back the writer cannot keep up and the pipe makes the loop
    wait (flow control); at one record per tick it keeps up.
    """

    codec = Codec.default()
    codec_us: dict[str, dict[str, float]] = {}
    for name, payload, node in (
        ("Get_Encoder_Estimates", EncoderEstimates(12.5, -0.75), Node.LEFT),
        ("Set_Input_Vel_Auth", SetInputVelAuth(1.25, 1.5, 3, 0xDEADBEEF), Node.LEFT),
        ("Bench_Truth_Pose", TruthPose(12.345, -6.789, 1.2345), None),
    ):
        msg = codec.encode(payload, node)
        codec_us[name] = {
            "encode": _per_call_us(lambda p=payload, n=node: codec.encode(p, n), calls),
            "decode": _per_call_us(lambda m=msg: codec.decode(m), calls),
        }
    record = {
        "route_time_s": 12.34,
        "ref": {k: 0.1 * i for i, k in enumerate(("x", "y", "heading", "v", "omega", "a"))},
        "est": {k: 0.2 * i for i, k in enumerate(("x", "y", "heading", "v", "omega"))},
        "err": {"x_e": 0.01, "y_e": -0.02, "phi_e": 0.003},
        "cmd_raw": {"v": 0.5, "omega": 0.1},
        "cmd": {"v": 0.45, "omega": 0.1, "wheel_left_radps": 1.4, "wheel_right_radps": 1.6},
        "step_us": 8.2,
        "internals": {"s1": 0.3, "bank.p_nominal": 0.9},
        "diagnosis": {"hypothesis": "NOMINAL", "probability": 0.97, "radius_left": 0.3},
    }
    tel_us: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="whil-bench-tel-") as tmp:
        for label, cls in (("in_loop", McapTelemetry), ("forked", ForkedTelemetry)):
            tel: Any = cls(Path(tmp) / f"{label}.mcap")
            k = iter(range(10**9))
            tel_us[label] = _per_call_us(
                lambda t=tel, k=k: t.log(TICK_TOPIC, next(k) * 10_000_000, record),
                calls // 4,
                clock=time.thread_time_ns,
            )
            tel.close()
    return {"codec_us": codec_us, "telemetry_log_us": tel_us}


def _tick_record() -> dict[str, Any]:
    return {
        "route_time_s": 12.34,
        "ref": {k: 0.1 * i for i, k in enumerate(("x", "y", "heading", "v", "omega", "a"))},
        "est": {k: 0.2 * i for i, k in enumerate(("x", "y", "heading", "v", "omega"))},
        "err": {"x_e": 0.01, "y_e": -0.02, "phi_e": 0.003},
        "cmd": {"v": 0.45, "omega": 0.1, "wheel_left_radps": 1.4, "wheel_right_radps": 1.6},
        "internals": {"s1": 0.3, "bank.p_nominal": 0.9},
    }


def feed_costs(calls: int) -> dict[str, Any]:
    """What the live view's mirror costs a log writer (``live_feed_us``, wall time).

    ``message``: one :meth:`LiveFeed.message` (the append to the bounded queue);
    ``tick_record``: a tick record written by :class:`McapTelemetry` in this thread,
    without a mirror and with a feed to a real view process (its sender thread running:
    wall time, so that the interpreter lock it takes is counted).  In a run the
    telemetry writes from a forked process, not in the loop; this is the worst case,
    where it could not fork.
    """
    out: dict[str, float] = {}
    with (
        tempfile.TemporaryDirectory(prefix="whil-bench-feed-") as tmp,
        LiveServer(LiveAddress("127.0.0.1", 0)) as view,
    ):
        feed = view.feed()
        feed.schema(1, "T", "jsonschema", b"{}")
        feed.channel(1, "/t", "json", 1)
        payload = b'{"x":1.0}' * 20
        out["message"] = _per_call_us(lambda: feed.message(1, 0, payload), calls)
        feed.close()
        record = _tick_record()
        for label, mirror in (("tick_record", None), ("tick_record_with_feed", view.feed())):
            tel = McapTelemetry(Path(tmp) / f"{label}.mcap", mirror=mirror)
            k = iter(range(10**9))
            out[label] = _per_call_us(
                lambda t=tel, k=k: t.log(TICK_TOPIC, next(k) * 10_000_000, record), calls // 4
            )
            tel.close()
    return {"live_feed_us": out}


# ----------------------------------------------------------------- MPC vs cvxpy


def adaptive_vs_cvxpy(n_windows: int = 4, window: int = 25) -> dict[str, Any]:
    """Our ADAPTIVE step vs the same QP through cvxpy (with parameters), on the same states.

    The controller runs along the paper route in an offline closed loop (warm-started as
    in operation).  In ``n_windows`` windows of ``window`` consecutive ticks, the QP it is
    about to solve is also handed to cvxpy (warm-started across the window's ticks).
    """

    try:
        import cvxpy as cp  # lazy: the optional [cvxpy] extra
    except ImportError as err:
        return {"error": f"cvxpy not installed ({err}); pip install -e '.[cvxpy]'"}
    cfg = load_config()
    traj = plan(load_route(route_file("paper")))

    ours = registry.create("adaptive", cfg.geometry, traj, body=cfg.body)
    assert isinstance(ours, AdaptiveMPC)
    lim = CommandLimiter(cfg.limits, cfg.geometry.half_track_m, cfg.geometry.wheel_radius_m)
    dt = cfg.loop.period_s
    n_steps = int(traj.duration_s / dt)
    starts = {int(n_steps * (i + 1) / (n_windows + 1)) for i in range(n_windows)}
    sampled = {k for s0 in starts for k in range(s0, s0 + window)}
    s0 = traj.sample(0.0)
    x, y, phi, v, w = s0.x_m, s0.y_m, s0.heading_rad, 0.0, 0.0
    ours.reset(StateEstimate(0.0, x, y, phi, 0.0, 0.0), 0.0)
    prob = None
    big = 1e9
    ours_us, cvx_us, osqp_us, diff = [], [], [], []
    for k in range(n_steps):
        t = k * dt
        ref = traj.sample(t)
        est = StateEstimate(t, x, y, phi, v, w)
        d = ours.qp_data(t, dt, ref, est) if k in sampled else None
        t0 = time.perf_counter_ns()
        cmd = ours.step(t, dt, ref, est)
        step_us = (time.perf_counter_ns() - t0) / 1000.0
        if d is not None:
            if prob is None:
                n, m = d.A.shape[1], d.A.shape[0]
                coo = d.A.tocoo()
                xv = cp.Variable(n)
                p_ = cp.Parameter(n, nonneg=True)
                q_ = cp.Parameter(n)
                a_ = cp.Parameter((m, n), sparsity=(coo.row, coo.col))
                lo = cp.Parameter(m)
                hi = cp.Parameter(m)
                prob = cp.Problem(
                    cp.Minimize(0.5 * cp.sum(cp.multiply(p_, cp.square(xv))) + q_ @ xv),
                    [a_ @ xv >= lo, a_ @ xv <= hi],
                )
            t1 = time.perf_counter_ns()
            p_.value = d.P.diagonal()
            q_.value = d.q
            a_.value_sparse = d.A.tocoo()
            lo.value = np.clip(d.l, -big, big)
            hi.value = np.clip(d.u, -big, big)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                prob.solve(solver=cp.OSQP, warm_start=True)
            cvx_us.append((time.perf_counter_ns() - t1) / 1000.0)
            ours_us.append(step_us)
            osqp_us.append(float(ours.internals().get("qp.solve_us", math.nan)))
            if xv.value is not None:
                first = ours.command_from_solution(np.asarray(xv.value))
                diff.append(abs(first.v_mps - cmd.v_mps) + abs(first.omega_radps - cmd.omega_radps))
        out = lim.apply(cmd, dt)
        v, w = out.v_mps, out.omega_radps
        x += v * math.cos(phi) * dt
        y += v * math.sin(phi) * dt
        phi += w * dt
    ours_med = statistics.median(ours_us)
    cvx_med = statistics.median(cvx_us)
    good = [u for u in osqp_us if u == u]
    osqp_med = statistics.median(good) if good else math.nan
    return {
        "states": len(ours_us),
        "adaptive_step_us_p50": ours_med,
        "cvxpy_solve_us_p50": cvx_med,
        "osqp_own_solve_us_p50": osqp_med,
        "adaptive_vs_cvxpy_ratio": cvx_med / ours_med,
        "adaptive_vs_osqp_floor": ours_med / osqp_med if osqp_med == osqp_med else math.nan,
        "first_move_median_difference": statistics.median(diff) if diff else math.nan,
    }


# --------------------------------------------------------------------- full stack


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


def _cli_run(args: list[str], timeout: float) -> dict[str, Any]:
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


def udp_rtf(work: Path) -> dict[str, Any]:
    out = work / "rtf-udp"
    err = _cli_run(
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
    err = _cli_run(
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


#: The live view's cases: (name, serve the view, run a client, the client's delay per message).
LIVE_CASES = (
    ("no view", False, False, 0.0),
    ("view, no client", True, False, 0.0),
    ("view, client on every channel", True, True, 0.0),
    ("view, slow client (2 ms per message)", True, True, 0.002),
)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def live_cost(work: Path, seconds: float, rounds: int = 2) -> dict[str, Any]:
    """The controller's tick with and without the live view (``live_tick_us``).

    One real-time run of ``seconds`` on the virtual bus per case of :data:`LIVE_CASES`
    (``run --realtime --bus virtual [--live 127.0.0.1:PORT]``), ``rounds`` times, the
    order reversed every other round (so that a machine getting busier does not favour
    one case); the client is :mod:`tools.live.client` in a process of its own, connected
    before the run starts, subscribed to every channel as it is advertised.  The tick
    figures are the controller's own (``tick_us_*``: a tick's work from its clock's
    wake-up to its ack; ``lateness_us_p99``: against its absolute schedule), the mean over
    the rounds; ``rounds`` keeps each run's figures.
    """
    per_case: dict[str, list[dict[str, Any]]] = {name: [] for name, *_ in LIVE_CASES}
    k = 0
    for r in range(rounds):
        order = LIVE_CASES if r % 2 == 0 else tuple(reversed(LIVE_CASES))
        for name, view, with_client, delay in order:
            k += 1
            per_case[name].append(_live_run(work / f"live-{k}", seconds, view, with_client, delay))
    out: dict[str, Any] = {}
    for name, runs in per_case.items():
        errors = [r for r in runs if "error" in r]
        if errors:
            out[name] = errors[0]
            continue
        mean = {
            key: statistics.fmean(float(r[key]) for r in runs)
            for key in ("tick_us_p50", "tick_us_p99", "lateness_us_p99")
            if all(r.get(key) is not None for r in runs)
        }
        out[name] = {
            **runs[-1],
            **mean,
            "missed_ticks": sum(r.get("missed_ticks") or 0 for r in runs),
        }
        out[name]["rounds"] = runs
    return {"live_tick_us": out, "live_seconds": seconds, "live_rounds": rounds}


def _live_run(
    run_dir: Path, seconds: float, view: bool, with_client: bool, delay: float
) -> dict[str, Any]:
    """One real-time run of :func:`live_cost`."""
    port = _free_port()
    extra = ["--live", f"127.0.0.1:{port}"] if view else []
    client = None
    counts = run_dir / "client.json"
    run_dir.mkdir(parents=True, exist_ok=True)
    if with_client:
        client = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tools.live.client",
                f"ws://127.0.0.1:{port}",
                "--delay-s",
                repr(delay),
                "--json",
                str(counts),
            ]
        )
    err = _cli_run(
        [
            "run",
            "--realtime",
            "--bus",
            "virtual",
            "--controller",
            "baseline",
            "--scenario",
            PAPER,
            "--duration",
            str(seconds),
            *extra,
            "--out",
            str(run_dir),
        ],
        timeout=seconds * 3 + 120,
    )
    got: dict[str, Any] = {}
    if client is not None:
        try:
            client.wait(30)
        except subprocess.TimeoutExpired:
            client.kill()
            client.wait()
        with contextlib.suppress(OSError, ValueError):
            got = json.loads(counts.read_text())
    if err:
        return err
    s = json.loads((run_dir / "summary.json").read_text())
    served: dict[str, Any] = {}
    with contextlib.suppress(OSError, ValueError):
        served = json.loads((run_dir / "live_stats.json").read_text())
    return {
        "tick_us_p50": s.get("tick_us_p50"),
        "tick_us_p99": s.get("tick_us_p99"),
        "lateness_us_p99": s.get("lateness_us_p99"),
        "missed_ticks": s.get("missed_ticks"),
        "view_messages": served.get("messages"),
        "feed_dropped": served.get("feed_dropped"),
        "client_messages": got.get("messages"),
        "client_channels": got.get("channels"),
        "client_by_topic": got.get("by_topic"),
    }


def format_live(r: dict[str, Any]) -> str:
    """The live view's cases as a table."""

    def f(v: Any, fmt: str = ".1f") -> str:
        return "n/a" if v is None or (isinstance(v, float) and v != v) else format(v, fmt)

    lines = [
        f"| live view, {f(r.get('live_seconds'), 'g')} s real-time runs (mean of "
        f"{r.get('live_rounds', 1)}) | tick p50 / p99 | "
        "lateness p99 | missed ticks | served / dropped by the feeds | client got (channels) |",
        "|---|---|---|---|---|---|",
    ]
    fc = r.get("live_feed_us") or {}
    if fc:
        lines.append(
            f"| a log writer's mirror: one message / a tick record without / with it "
            f"(in one thread) | {f(fc.get('message'), '.2f')} us / {f(fc.get('tick_record'))} "
            f"/ {f(fc.get('tick_record_with_feed'))} us | | | | |"
        )
    for name, c in (r.get("live_tick_us") or {}).items():
        if "error" in c:
            lines.append(f"| {name} | {c['error']} | | | | |")
            continue
        got = (
            f"{c['client_messages']} ({c['client_channels']})"
            if c.get("client_messages") is not None
            else "-"
        )
        served = (
            f"{c['view_messages']} / {c['feed_dropped']}"
            if c.get("view_messages") is not None
            else "-"
        )
        lines.append(
            f"| {name} | {f(c['tick_us_p50'])} / {f(c['tick_us_p99'])} us | "
            f"{f(c['lateness_us_p99'])} us | {c.get('missed_ticks')} | {served} | {got} |"
        )
    return "\n".join(lines)


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
    return {"e2e_latency_us": {"p50": _pct(lat, 50), "p99": _pct(lat, 99)}, "e2e_samples": len(lat)}


def e2e_latency(samples: int) -> dict[str, Any]:

    argv = transport.sandbox_argv(
        [sys.executable, "-m", "tools.perf.bench", "--e2e-probe", str(samples)]
    )
    res = subprocess.run(
        argv, capture_output=True, text=True, timeout=samples * 0.6 + 120, check=False
    )
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
    if res.returncode != 0 or not lines:
        return {"error": (res.stderr.strip().splitlines() or ["probe failed"])[-1]}
    return json.loads(lines[-1])


# ------------------------------------------------------------------------ report


def run(args: argparse.Namespace) -> dict[str, Any]:

    names = registry.names()
    chosen = getattr(args, "controllers", None)
    if chosen:
        names = [n.strip() for n in chosen.split(",") if n.strip()]
        for n in names:
            registry.controller_class(n)  # an unknown name is a ConfigError naming the choices
    result: dict[str, Any] = {
        "machine": _machine(),
        "command": " ".join(["wheelchair-hil", "bench", *args.argv]),
    }
    steps = 1500 if args.quick else None
    _progress("controller step() in an offline closed loop")
    loops = {n: _offline_loop(n, steps=steps) for n in names}
    result["controller_step_us"] = {n: {"p50": r["p50"], "p99": r["p99"]} for n, r in loops.items()}
    result["allocations_per_tick"] = {n: r["net_blocks_per_step"] for n, r in loops.items()}
    if getattr(args, "steps_only", False):
        return result
    _progress("ADAPTIVE vs the same QP through cvxpy")
    mpc = adaptive_vs_cvxpy(2 if args.quick else 4)
    result["adaptive_vs_cvxpy"] = mpc
    result["adaptive_vs_cvxpy_ratio"] = mpc.get("adaptive_vs_cvxpy_ratio")
    result["adaptive_vs_osqp_floor"] = mpc.get("adaptive_vs_osqp_floor")
    _progress("codec per frame, telemetry per tick")
    result.update(loop_costs(2000 if args.quick else 20000))
    with tempfile.TemporaryDirectory(prefix="whil-bench-") as tmp:
        work = Path(tmp)
        _progress("lock-step real-time factor per controller (virtual bus)")
        rtf = lockstep_rtf(["baseline"] if args.quick else names, work)
        result["lockstep_rtf"] = {n: r["rtf"] for n, r in rtf.items()}
        result["lockstep_detail"] = rtf
        result["lockstep_budget_us"] = {n: r["budget_us"] for n, r in rtf.items()}
        result.update(bus_load(work))
        if not args.quick:
            _progress("lock-step over udp_multicast, three processes")
            result["lockstep_rtf_udp"] = udp_rtf(work)
        _progress(f"real-time loop for {args.rt_seconds:g} s over udp_multicast")
        rt = realtime(work, args.rt_seconds, args.rt_priority)
        result.update(rt)
        _progress("end-to-end latency across processes")
        result.update(e2e_latency(50 if args.quick else 400))
    return result


def _machine() -> dict[str, Any]:

    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "loadavg_at_start": [round(x, 2) for x in load],
        "date": time.strftime("%Y-%m-%d"),
    }


def _progress(msg: str) -> None:
    print(f"[bench] {msg} ...", file=sys.stderr, flush=True)


def format_table(r: dict[str, Any]) -> str:
    def f(v: Any, fmt: str = ".1f") -> str:
        return "n/a" if v is None or (isinstance(v, float) and v != v) else format(v, fmt)

    lines = ["| figure | value | target |", "|---|---|---|"]
    for n, st in r["controller_step_us"].items():
        target = "<= 300 us median" if n.startswith("adaptive") else "<= 50 us"
        lines.append(f"| step() {n}, p50 / p99 | {f(st['p50'])} / {f(st['p99'])} us | {target} |")
    if "lockstep_rtf" not in r:  # --steps-only
        return "\n".join(lines)
    m = r.get("adaptive_vs_cvxpy", {})
    if "error" in m:
        lines.append(f"| ADAPTIVE vs cvxpy | {m['error']} | >= 15x |")
    else:
        lines.append(
            f"| ADAPTIVE vs cvxpy with parameters (median over {m['states']} states) | "
            f"{f(m['cvxpy_solve_us_p50'], '.0f')} us / {f(m['adaptive_step_us_p50'], '.0f')} us = "
            f"{f(m['adaptive_vs_cvxpy_ratio'])}x | >= 15x |"
        )
        lines.append(
            f"| ADAPTIVE step over OSQP's own solve (distance to the floor) | "
            f"{f(m['adaptive_vs_osqp_floor'], '.2f')}x | |"
        )
    for n, c in (r.get("codec_us") or {}).items():
        lines.append(
            f"| codec, {n}: encode / decode one frame | {f(c['encode'], '.2f')} / "
            f"{f(c['decode'], '.2f')} us | |"
        )
    tl = r.get("telemetry_log_us") or {}
    if tl:
        lines.append(
            f"| controller log of a tick record: in the loop / to a forked writer | "
            f"{f(tl.get('in_loop'))} / {f(tl.get('forked'))} us | |"
        )
    for n, v in r.get("lockstep_rtf", {}).items():
        target = "" if n.startswith("adaptive") else ">= 50x"
        lines.append(f"| lock-step real-time factor, {n}, virtual bus | {f(v)}x | {target} |")
    for n, b in (r.get("lockstep_budget_us") or {}).items():
        if isinstance(b, dict):
            lines.append(
                f"| lock-step step, {n}: physics / controller tick / rest | "
                f"{f(b.get('physics'), '.0f')} / {f(b.get('controller_tick'), '.0f')} / "
                f"{f(b.get('rest'), '.0f')} us (physics and ticks alone: "
                f"{f(b.get('rtf_ceiling'))}x) | |"
            )
    udp = r.get("lockstep_rtf_udp")
    if isinstance(udp, dict) and "rtf" in udp:
        lines.append(
            f"| lock-step real-time factor, baseline, udp_multicast, 3 processes | {f(udp['rtf'])}x | |"
        )
    lat = r.get("rt_lateness_us") or {}
    lines.append(
        f"| 100 Hz loop lateness p50 / p99 / p99.9 / max ({f(r.get('rt_seconds'), '.0f')} s) | "
        f"{f(lat.get('p50'), '.0f')} / {f(lat.get('p99'), '.0f')} / {f(lat.get('p999'), '.0f')} / "
        f"{f(lat.get('max'), '.0f')} us | p99 <= 500 us |"
    )
    lines.append(f"| missed 100 Hz cycles | {r.get('rt_missed_cycles')} | 0 |")
    lines.append(f"| real-time scheduling | {'; '.join(r.get('rt_notes') or [])} | |")
    e2e = r.get("e2e_latency_us") or {}
    lines.append(
        f"| setpoint -> drive -> feedback, p50 / p99 | {f(e2e.get('p50'), '.0f')} / "
        f"{f(e2e.get('p99'), '.0f')} us | |"
    )
    lines.append(
        f"| bus load, stack frames / with bench frames | {f(r.get('bus_load_pct'))} % / "
        f"{f(r.get('bus_load_pct_with_bench'))} % | <= 25 % |"
    )
    lines.append(f"| controller peak RSS | {f(r.get('controller_rss_mb'))} MB | <= 150 MB |")
    alloc = r.get("allocations_per_tick") or {}
    lines.append(
        "| net allocated blocks per step | "
        + ", ".join(f"{n} {f(v, '.2f')}" for n, v in alloc.items())
        + " | 0 (no leak) |"
    )
    return "\n".join(lines)


def main(args: argparse.Namespace, argv: list[str]) -> int:
    args.argv = argv[1:]
    if args.quick:
        args.rt_seconds = min(args.rt_seconds, 10.0)
    if args.case == "live":
        _progress(f"the live view's cost per tick, {args.rt_seconds:g} s real-time runs")
        with tempfile.TemporaryDirectory(prefix="whil-bench-") as tmp:
            r = {
                "machine": _machine(),
                **feed_costs(2000 if args.quick else 20000),
                **live_cost(Path(tmp), args.rt_seconds, args.rounds),
            }
        print(format_live(r))
        if args.json:
            Path(args.json).write_text(jsonsafe.dumps(r, indent=2, default=str) + "\n")
        return 0
    r = run(args)
    print(format_table(r))
    if args.json:
        Path(args.json).write_text(jsonsafe.dumps(r, indent=2, default=str) + "\n")
    return 0


if __name__ == "__main__":  # the e2e probe runs inside a private namespace
    if len(sys.argv) == 3 and sys.argv[1] == "--e2e-probe":
        print(json.dumps(e2e_probe(int(sys.argv[2]))))
        sys.exit(0)
    sys.exit(2)
