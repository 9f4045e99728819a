"""The benchmark suite of ``wheelchair-hil bench``: the stack's speed, measured in one run on
this machine.

Every figure goes into one result (``bench`` prints it as a table, :func:`format_table`, and
with ``--json`` writes it with the keys below); this module runs the benchmarks, one module
per group: :mod:`~tools.perf.laws` (the tracking laws),
:mod:`~tools.perf.costs` (the codec and the log per frame and per tick),
:mod:`~tools.perf.stack` (the full stack: real-time factors, lateness, bus load, latency) and
:mod:`~tools.perf.live` (the live view); :mod:`~tools.perf.common` is what they share.
Absolute times depend on the machine and its load; compare ratios and medians taken in the
same run.

* ``controller_step_us[name]``: p50/p99 of ``step()`` for every controller, in an
  offline closed loop over the paper route (ideal wheels, the node's limiter applied),
  so that only the law itself is timed;
* ``adaptive_vs_cvxpy_ratio``: the same MPC problem (``adaptive.qp_data``) formulated in
  cvxpy with parameters (a sparse parameter for the constraint matrix, DPP), solved by
  OSQP through cvxpy over the same states, median time divided by ours;
  ``adaptive_vs_osqp_floor``: our median ``step()`` over OSQP's own solve time;
* ``codec_us[message]`` (encode, decode) and ``telemetry_log_us`` (in_loop, forked): what a
  frame costs the codec and a tick record the controller's log;
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
  (:func:`~tools.perf.live.live_cost`);
* ``breakdown`` (``bench --case breakdown``): a lock-step step of the paper route split by
  component (receive, decode, odometry, EKF, fault bank, safety checks, reference, law,
  limits, encode and MAC, send, telemetry, recorder and metrics, the drives' frames, the
  physics), host and bench apart, per controller (:mod:`~tools.perf.breakdown`);
* ``controller_rss_mb``: peak resident memory of the controller process (real-time
  run), and ``allocations_per_tick``: net allocated blocks per control step (a leak
  would show as a positive number) in the offline loop.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from controller.tracking import registry
from tools.perf.breakdown import breakdown
from tools.perf.common import PAPER, machine, progress
from tools.perf.costs import loop_costs
from tools.perf.laws import adaptive_vs_cvxpy, offline_loop
from tools.perf.live import feed_costs, live_cost
from tools.perf.stack import bus_load, e2e_latency, lockstep_rtf, realtime, udp_rtf


def chosen_controllers(text: str | None) -> list[str]:
    """The names of a comma-separated list (each checked: an unknown one names the
    choices), or [] for none."""
    names = [n.strip() for n in text.split(",") if n.strip()] if text else []
    for n in names:
        registry.controller_class(n)
    return names


def run(
    names: Sequence[str] | None = None,
    *,
    argv: Sequence[str] = (),
    quick: bool = False,
    steps_only: bool = False,
    rt_seconds: float = 60.0,
    rt_priority: int = 10,
) -> dict[str, Any]:
    """Every benchmark (``steps_only``: only the controllers' ``step()`` times) for the
    controllers ``names`` (default: every registered one); ``argv``, the command line after
    ``bench``, is recorded in the result."""

    names = list(names or registry.names())
    result: dict[str, Any] = {
        "machine": machine(),
        "command": " ".join(["wheelchair-hil", "bench", *argv]),
    }
    steps = 1500 if quick else None
    progress("controller step() in an offline closed loop")
    loops = {n: offline_loop(n, steps=steps) for n in names}
    result["controller_step_us"] = {n: {"p50": r["p50"], "p99": r["p99"]} for n, r in loops.items()}
    result["allocations_per_tick"] = {n: r["net_blocks_per_step"] for n, r in loops.items()}
    if steps_only:
        return result
    progress("ADAPTIVE vs the same QP through cvxpy")
    mpc = adaptive_vs_cvxpy(2 if quick else 4)
    result["adaptive_vs_cvxpy"] = mpc
    result["adaptive_vs_cvxpy_ratio"] = mpc.get("adaptive_vs_cvxpy_ratio")
    result["adaptive_vs_osqp_floor"] = mpc.get("adaptive_vs_osqp_floor")
    progress("codec per frame, telemetry per tick")
    result.update(loop_costs(2000 if quick else 20000))
    with tempfile.TemporaryDirectory(prefix="whil-bench-") as tmp:
        work = Path(tmp)
        progress("lock-step real-time factor per controller (virtual bus)")
        rtf = lockstep_rtf(["baseline"] if quick else names, work)
        result["lockstep_rtf"] = {n: r["rtf"] for n, r in rtf.items()}
        result["lockstep_detail"] = rtf
        result["lockstep_budget_us"] = {n: r["budget_us"] for n, r in rtf.items()}
        result.update(bus_load(work))
        if not quick:
            progress("lock-step over udp_multicast, three processes")
            result["lockstep_rtf_udp"] = udp_rtf(work)
        progress(f"real-time loop for {rt_seconds:g} s over udp_multicast")
        rt = realtime(work, rt_seconds, rt_priority)
        result.update(rt)
        progress("end-to-end latency across processes")
        result.update(e2e_latency(50 if quick else 400))
    return result


def live_case(rt_seconds: float, rounds: int, *, quick: bool = False) -> dict[str, Any]:
    """``bench --case live``: the live view's cost per tick (:func:`tools.perf.live.live_cost`)
    in real-time runs of ``rt_seconds``, ``rounds`` runs per case."""
    progress(f"the live view's cost per tick, {rt_seconds:g} s real-time runs")
    with tempfile.TemporaryDirectory(prefix="whil-bench-") as tmp:
        return {
            "machine": machine(),
            **feed_costs(2000 if quick else 20000),
            **live_cost(Path(tmp), rt_seconds, rounds),
        }


def breakdown_case(names: Sequence[str] | None = None) -> dict[str, Any]:
    """``bench --case breakdown``: where a lock-step step of the paper route goes, for each of
    the controllers ``names`` (default: every registered one)."""
    r: dict[str, Any] = {"machine": machine(), "breakdown": []}
    for n in names or registry.names():
        progress(f"where a lock-step step goes, {n}, the paper route")
        r["breakdown"].append(breakdown(n, PAPER))
    return r


def format_table(r: dict[str, Any]) -> str:
    """The result of :func:`run` as a Markdown table with the targets."""

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
