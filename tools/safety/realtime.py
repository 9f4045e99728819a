"""The safety suite's real-time runs: the controller as a real process, killed or stopped.

:func:`realtime_signal_run` runs bench, controller (safety profile) and recorder as processes
over udp_multicast in a private namespace, in real time, and signals the controller (SIGKILL,
or SIGSTOP then SIGCONT); :func:`analyse_realtime_log` checks the stop from the recorder's log
in simulation time, by the criteria of :mod:`tools.safety.criteria`.
"""

from __future__ import annotations

import json
import math
import signal as signal_mod
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dbc.codec import (
    AxisError,
    BenchStep,
    Codec,
    EncoderEstimates,
    Heartbeat,
    SetInputVelAuth,
)
from dbc.errors import DecodeError
from firmware_sim.config import load_bench_config
from tools.logs.mcap_io import iter_frames
from tools.run.processes import PartFailedError, SandboxedParts, realtime_parts, signal_part
from tools.safety.cases import PERIOD_S, SAFETY_PROFILE, WATCHDOG_S
from tools.safety.criteria import (
    A_STOP_MPS2,
    HEADING_TOL_DEG,
    STANDSTILL_MPS,
    YAW_TOL_RADPS,
    heading_deviation,
    standstill_limit_s,
    yaw_excess,
)
from tools.safety.verdict import Verdict


@dataclass
class RealtimeResult(Verdict):
    """A real-time run whose controller process got a signal, analysed in simulation time.

    ``last_setpoint_s``: simulation time of the controller's last setpoint before the drives
    tripped; every figure below is relative to it.
    """

    signal: str
    scenario: str
    last_setpoint_s: float | None = None
    v0_mps: float | None = None
    stop_ref_mps: float | None = None
    watchdog_in_heartbeat_s: float | None = None
    detection_limit_s: float = WATCHDOG_S + 2 * PERIOD_S
    standstill_s: float | None = None
    standstill_limit_s: float | None = None
    stop_distance_m: float | None = None
    stop_distance_limit_m: float | None = None
    dw_at_trip_radps: float | None = None
    dw_max_radps: float | None = None
    dw_excess_radps: float | None = None
    heading_deviation_deg: float | None = None
    still_to_end_s: float | None = None
    drives_idle_with_error_at_end: bool = False
    controller_final_state: str = ""
    #: False if the controller had already stopped by itself (its own safety monitors, or
    #: starved of CPU long enough for the drives' watchdogs) before the signal
    signalled: bool = True
    failures: list[str] = field(default_factory=list)


def _safety_toml(path: Path) -> Path:
    lines = ["# The safety profile (docs/safety.md) on top of controller/controller.toml", ""]
    for section, values in SAFETY_PROFILE.items():
        lines.append(f"[{section}]")
        lines += [
            f"{k} = {str(v).lower() if isinstance(v, bool) else v}" for k, v in values.items()
        ]
    lines.append("watchdog_timeout_ms = 100")
    path.write_text("\n".join(lines) + "\n")
    return path


def realtime_signal_run(
    out: Path,
    *,
    sig: str = "SIGKILL",
    scenario: str = "short",
    at_s: float = 5.0,
    stop_s: float = 1.5,
    duration_s: float = 9.0,
    rt_priority: int = 0,
) -> RealtimeResult:
    """Bench, controller (safety profile) and recorder as processes over udp_multicast in a
    private namespace (:class:`~tools.run.processes.SandboxedParts`), in real time; ``at_s``
    wall seconds after all are up the controller gets ``sig`` (SIGKILL, or SIGSTOP and
    ``stop_s`` later SIGCONT).  ``rt_priority`` > 0: the parts on SCHED_FIFO, as
    :func:`~tools.run.processes.realtime_parts` gives it.  Raises :class:`RuntimeError` if
    the processes fail."""

    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    cfg = _safety_toml(out / "safety.toml")
    parts = realtime_parts(
        out, scenario, duration_s, control=("--config", str(cfg)), rt_priority=rt_priority
    )
    try:
        with SandboxedParts(parts, out, timeout_s=duration_s * 4 + 60) as run:
            run.wait_started()
            time.sleep(at_s)
            pid = run.pid("control")
            if pid is None:
                raise PartFailedError("the controller never started")
            signalled = signal_part(
                pid, signal_mod.SIGKILL if sig == "SIGKILL" else signal_mod.SIGSTOP, *_CONTROL
            )
            if signalled and sig != "SIGKILL":
                time.sleep(stop_s)
                signal_part(pid, signal_mod.SIGCONT, *_CONTROL)
            run.wait()
    except PartFailedError as err:
        raise RuntimeError(f"real-time run failed: {err}") from err
    res = analyse_realtime_log(out / "run.mcap", sig=sig, scenario=scenario)
    res.signalled = signalled
    stats = out / "ctl" / "controller_stats.json"
    if stats.exists():
        res.controller_final_state = json.loads(stats.read_text()).get("final_state", "")
    if sig != "SIGKILL" and res.controller_final_state not in ("FAULT", ""):
        res.failures.append(f"the controller resumed into {res.controller_final_state}")
    return res


#: What the command line of the real-time runs' controller holds (:func:`signal_part`).
_CONTROL = (b"tools.cli", b"control")


def analyse_realtime_log(
    path: Path, *, sig: str = "SIGKILL", scenario: str = "short"
) -> RealtimeResult:
    """The figures of a real-time signal run from its recorder log, in simulation time."""

    codec = Codec.default()
    bcfg = load_bench_config({}, source="defaults")
    r_m = bcfg.chair.wheel_radius_m
    res = RealtimeResult(sig, scenario)
    t_sim = 0
    enc: dict[int, list[tuple[int, float]]] = {1: [], 2: []}
    hbs: list[tuple[int, int, int, int]] = []  # t, node, error, state
    sps: list[tuple[int, float]] = []  # t, stop ref rev/s
    for _t, msg in iter_frames(path):
        try:
            node, p = codec.decode(msg)
        except DecodeError:
            continue
        kind = type(p)
        if kind is BenchStep:
            t_sim = p.sim_time_ns
        elif kind is EncoderEstimates and node is not None:
            enc[int(node)].append((t_sim, p.vel_revps))
        elif kind is Heartbeat and node is not None:
            hbs.append((t_sim, int(node), p.axis_error, int(p.axis_state)))
        elif kind is SetInputVelAuth:
            sps.append((t_sim, p.stop_ref_revps))
    fail = res.failures
    trips = [h for h in hbs if h[2] & AxisError.WATCHDOG_TIMER_EXPIRED]
    if not trips or not sps:
        fail.append("no watchdog error in any drive heartbeat" if not trips else "no setpoints")
        return res
    t_trip = trips[0][0]
    before = [s for s in sps if s[0] <= t_trip]
    if not before:
        fail.append("no setpoint before the trip")
        return res
    t_last, ref = before[-1]
    res.last_setpoint_s = round(t_last * 1e-9, 3)
    res.watchdog_in_heartbeat_s = round((t_trip - t_last) * 1e-9, 3)
    if res.watchdog_in_heartbeat_s > res.detection_limit_s + 1e-9:
        fail.append(f"watchdog reported {res.watchdog_in_heartbeat_s} s after the last setpoint")
    # wheel rim speeds on a common time base (every Encoder_Estimates step)
    tl = np.array([t for t, _ in enc[1]], dtype=np.int64)
    vl = np.abs([v for _, v in enc[1]]) * 2 * math.pi * r_m
    tr_ = np.array([t for t, _ in enc[2]], dtype=np.int64)
    vr = np.abs([v for _, v in enc[2]]) * 2 * math.pi * r_m
    grid = np.intersect1d(tl, tr_)
    wl = np.interp(grid, tl, vl)
    wr = np.interp(grid, tr_, vr)
    sl = np.interp(grid, tl, [v for _, v in enc[1]])
    sr = np.interp(grid, tr_, [v for _, v in enc[2]])
    vmax = np.maximum(wl, wr)
    i0 = int(np.searchsorted(grid, t_last))
    v0 = float(vmax[i0])
    res.v0_mps = round(v0, 4)
    res.stop_ref_mps = round(ref * 2 * math.pi * r_m, 4)
    moving = np.flatnonzero(vmax >= STANDSTILL_MPS)
    j = int(moving[-1]) + 1 if moving.size else 0
    if j >= len(grid) or j <= i0:
        fail.append("the wheels were not at standstill at the end of the run")
        return res
    res.standstill_s = round(float(grid[j] - t_last) * 1e-9, 3)
    res.standstill_limit_s = round(standstill_limit_s(WATCHDOG_S, v0, res.stop_ref_mps), 3)
    if res.standstill_s > res.standstill_limit_s:
        fail.append(f"standstill after {res.standstill_s} s > {res.standstill_limit_s} s")
    dt = np.diff(grid[i0 : j + 1]) * 1e-9
    dist = float(max((wl[i0:j] * dt).sum(), (wr[i0:j] * dt).sum()))
    res.stop_distance_m = round(dist, 4)
    res.stop_distance_limit_m = round(
        1.05 * (v0 * (WATCHDOG_S + 2 * PERIOD_S) + v0 * v0 / (2 * A_STOP_MPS2)), 4
    )
    if dist > res.stop_distance_limit_m:
        fail.append(f"stop distance {dist:.3f} m > {res.stop_distance_limit_m} m")
    dw = np.abs(sl - sr) * 2 * math.pi  # wheel rad/s
    it = int(np.searchsorted(grid, t_trip))
    res.dw_at_trip_radps = round(float(dw[it]), 3)
    res.dw_max_radps = round(float(dw[it:j].max()) if j > it else float(dw[it]), 3)
    res.dw_excess_radps = round(yaw_excess(dw[it:j], vmax[it:j]), 3)
    if res.dw_excess_radps > YAW_TOL_RADPS:
        fail.append(
            f"|wL - wR| exceeded the curvature-keeping profile by {res.dw_excess_radps} rad/s"
        )
    yaw_rate = (sr - sl) * 2 * math.pi * r_m / bcfg.chair.wheel_separation_m
    seg = slice(it, max(j, it + 1))
    dt_grid = float(np.median(np.diff(grid))) * 1e-9 if len(grid) > 1 else PERIOD_S
    res.heading_deviation_deg = round(
        math.degrees(heading_deviation(yaw_rate[seg], vmax[seg], dt_grid)), 2
    )
    if abs(res.heading_deviation_deg) > HEADING_TOL_DEG:
        fail.append(f"the heading left the arc by {res.heading_deviation_deg} deg")
    res.still_to_end_s = round(float(grid[-1] - grid[j]) * 1e-9, 3)
    if res.still_to_end_s < 1.0:
        fail.append(f"standstill observed for only {res.still_to_end_s} s")
    last = {n: h for h in hbs for n in (h[1],)}
    res.drives_idle_with_error_at_end = all(
        n in last and last[n][3] == 1 and last[n][2] & AxisError.WATCHDOG_TIMER_EXPIRED
        for n in (1, 2)
    )
    if not res.drives_idle_with_error_at_end:
        fail.append("the drives are not idle with the watchdog error latched at the end")
    return res
