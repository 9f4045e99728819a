"""One run of a campaign: what it is (:class:`Task`), running it, and what it yields.

:func:`run_task` is the worker function of every executor (:mod:`tools.evaluation.execute`):
it runs one experiment into ``runs/<task.key>`` and returns its result beyond the run's
summary (ground-truth time series for the figures, ISO 2631 comfort (:func:`comfort`), the
position errors per fault window (:func:`window_errors`)); :func:`run_group` runs the tasks
that differ only in their faults as branches of one run (:mod:`tools.run.branches`), with the
same figures.  :func:`load_cached` finds an earlier run's result for ``--resume``.
"""

from __future__ import annotations

import dataclasses
import io
import json
import logging
import math
import os
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controller import comfort as iso
from dbc.runtime import jsonsafe
from firmware_sim.config import load_bench_config
from tools.evaluation.plan import (
    _SCALABLE,
    CELL_METRICS,
    COMFORT_K_HORIZONTAL,
    SHARE_FIELDS,
    TIMING_FIELDS,
)
from tools.evaluation.variation import NOMINAL, Variation, apply_variation, stress_of
from tools.metrics.tracking import (
    BusCollector,
    BusSeries,
    last_tracking_ns,
    tracking_errors,
    tracking_window,
)
from tools.run import scenario as scenario_mod
from tools.run.branches import BranchError, run_branches
from tools.run.experiment import run_experiment
from tools.run.plan import planned

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Task:
    """One experiment of a campaign: a controller on a (varied) scenario."""

    controller: str
    scenario: str
    variation: Variation = NOMINAL
    duration_s: float | None = None
    base_seed: int = 1
    #: the fault setting the run is made in (the effective one: see plan_campaign)
    setting: str = "diagnosed"
    #: overrides of the controller's gains, as JSON ("" = controller/gains.toml as it is)
    gains: str = ""
    #: write the run's MCAP log and time series (figures, replay); without, only its figures
    #: (tools.logs.collect: the same numbers, a third of the time)
    log: bool = True

    @property
    def seed(self) -> int:
        return self.base_seed if self.variation.seed is None else self.variation.seed

    @property
    def key(self) -> str:
        """Identity of the run (equal keys are the same experiment); also its directory."""
        tag = self.variation.tag()
        if self.variation.replicate == 0 and self.variation.seed is None and self.base_seed != 1:
            tag += f"-s{self.base_seed}"
        return f"{self.setting}/{self.scenario}/{tag}/{self.controller}"


def jsonable(x: Any) -> Any:
    """``x`` with numpy scalars as Python numbers and non-finite floats as None."""
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [jsonable(v) for v in x]
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, float | np.floating):
        v = float(x)
        return v if math.isfinite(v) else None
    return x


# ----------------------------------------------------------------- one run


_SERIES_TOPICS: dict[str, tuple[str, tuple[str, ...]]] = {
    "/can/Bench_Truth_Pose": ("Bench_Truth_Pose", ("X", "Y", "Heading")),
    "/can/Bench_Truth_Twist": ("Bench_Truth_Twist", ("V", "Omega")),
    "/can/Host_Heartbeat": ("Host_Heartbeat", ("Host_State", "Route_Time")),
    "/controller/reference": ("reference", ("v", "omega", "a", "alpha")),
    "/controller/command": ("command", ("v", "omega")),
}


def _series_collector() -> BusCollector:
    """Collects, while the run's log is merged, every bus channel (the run's summary needs
    them all) and the controller channels of the evaluation's series."""

    return BusCollector(extra_topics=[t for t in _SERIES_TOPICS if not t.startswith("/can/")])


def collected_series(collector: BusCollector) -> dict[str, dict[str, np.ndarray]]:
    """The collected channels as arrays: int64 times, float signals (NaN for null)."""
    out = {}
    for topic, (name, sigs) in _SERIES_TOPICS.items():
        col = collector.columns.get(topic[5:] if topic.startswith("/can/") else topic, {})
        t = col.get("t", [])
        arrays = {"t": np.asarray(t, dtype=np.int64)}
        for s_ in sigs:
            vals = col.get(s_, [])
            if len(vals) != len(t):  # a signal missing from some records
                vals = [math.nan] * len(t)
            arrays[s_] = np.asarray([math.nan if v is None else v for v in vals], dtype=float)
        out[name] = arrays
    return out


def comfort(t_ns: np.ndarray, v_mps: np.ndarray, omega_radps: np.ndarray) -> dict[str, float]:
    """ISO 2631-1 Wd-weighted rms of the chair's real horizontal accelerations.

    Longitudinal ``dv/dt`` and lateral ``v omega`` of the ground-truth twist, sampled
    uniformly; the vector value uses ``k = 1.4`` on both axes (as the planner's bound).
    """

    nan = math.nan
    out = {"comfort_awx_mps2": nan, "comfort_awy_mps2": nan, "comfort_av_mps2": nan}
    if t_ns.size < 8:
        return out
    t = (t_ns - t_ns[0]) * 1e-9
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        return out
    ok = np.isfinite(v_mps) & np.isfinite(omega_radps)
    v = np.interp(t, t[ok], v_mps[ok]) if not ok.all() else v_mps
    w = np.interp(t, t[ok], omega_radps[ok]) if not ok.all() else omega_radps
    ax = np.gradient(v, t)
    ay = v * w
    fs = 1.0 / dt
    awx = iso.weighted_rms(ax, fs, "x")
    awy = iso.weighted_rms(ay, fs, "y")
    out.update(
        comfort_awx_mps2=awx,
        comfort_awy_mps2=awy,
        comfort_av_mps2=iso.vector_value(
            awx, awy, kx=COMFORT_K_HORIZONTAL, ky=COMFORT_K_HORIZONTAL
        ),
    )
    return out


def window_errors(
    t_ns: np.ndarray, pos_err_m: np.ndarray, windows: Iterable[tuple[float, float | None]]
) -> list[dict[str, Any]]:
    """Position RMSE and maximum inside each ``(onset_s, end_s)`` window (end None: to the end)."""
    out = []
    t = t_ns.astype(np.int64)
    for onset_s, end_s in windows:
        sel = t >= round(onset_s * 1e9)
        if end_s is not None:
            sel &= t < round(end_s * 1e9)
        e = pos_err_m[sel]
        out.append(
            {
                "onset_s": onset_s,
                "end_s": end_s,
                "samples": int(e.size),
                "rmse_pos_m": float(np.sqrt(np.mean(e * e))) if e.size else math.nan,
                "max_pos_err_m": float(np.max(e)) if e.size else math.nan,
            }
        )
    return out


def run_task(task: Task, root: str) -> dict[str, Any]:
    """Run one experiment into ``root/<task.key>``; return its results and time series.

    The worker function of every executor (inline, process pool, Dask): it imports
    what it needs, never raises (a failure is returned as ``error``), and returns plain
    data: ``result`` (deterministic), ``timing`` (wall clock) and ``series`` (numpy
    arrays for the figures, also written to ``series.npz`` next to the log).
    """
    t_start = time.monotonic()
    out_dir = Path(root) / "runs" / task.key
    try:
        return _run_task(task, out_dir, t_start)
    except Exception as err:  # one failed run must not end a campaign
        log.exception("run %s failed", task.key)
        return {
            "key": task.key,
            "error": f"{type(err).__name__}: {err}",
            "result": {},
            "timing": {"worker_wall_s": time.monotonic() - t_start},
            "series": {},
        }


def run_group(tasks: Sequence[Task], root: str) -> list[dict[str, Any]]:
    """Run tasks without a log that differ only in their scenario's faults, sharing their
    run up to the first fault (:mod:`tools.run.branches`); each one's :func:`run_task`
    output, in order.  The worker function of a process pool."""
    t_start = time.monotonic()
    scens = [_task_scenario(t) for t in tasks]
    out_dirs = [Path(root) / "runs" / t.key for t in tasks]

    def finish(i: int, summary: dict[str, Any], frames: Any, started: float) -> dict[str, Any]:
        collector = _series_collector()
        collector.columns.update(frames.series.columns)
        out_dirs[i].mkdir(parents=True, exist_ok=True)
        (out_dirs[i] / "summary.json").write_text(
            jsonsafe.dumps(summary, indent=2, default=str) + "\n"
        )
        return _task_result(tasks[i], scens[i], summary, collector, out_dirs[i], started)

    first = tasks[0]
    outcomes = run_branches(
        scens,
        first.controller,
        Path(root) / "runs" / ".branches" / f"{os.getpid()}",
        finish,
        seed=first.seed,
        duration_s=first.duration_s,
    )
    results = []
    for task, o in zip(tasks, outcomes, strict=True):
        if isinstance(o, BranchError):
            log.error("run %s failed: %s\n%s", task.key, o.error, o.traceback)
            o = {
                "key": task.key,
                "error": o.error,
                "result": {},
                "timing": {"worker_wall_s": time.monotonic() - t_start},
                "series": {},
            }
        results.append(o)
    return results


def _task_scenario(task: Task) -> Any:
    """The scenario ``task`` runs: its file, varied, in its fault setting, with its gains."""
    scen = apply_variation(scenario_mod.load(task.scenario), task.variation)
    scen = scenario_mod.with_setting(scen, task.setting)
    if task.gains:
        scen = dataclasses.replace(
            scen, gains={**scen.gains, task.controller: json.loads(task.gains)}
        )
    return scen


def _run_task(task: Task, out_dir: Path, t_start: float) -> dict[str, Any]:
    scen = _task_scenario(task)
    collector = _series_collector()
    summary = run_experiment(
        out_dir,
        scen,
        task.controller,
        seed=task.seed,
        duration_s=task.duration_s,
        collector=collector,
        log=task.log,
    )
    return _task_result(task, scen, summary, collector, out_dir, t_start)


def _task_result(
    task: Task,
    scen: Any,
    summary: dict[str, Any],
    collector: BusCollector,
    out_dir: Path,
    t_start: float,
) -> dict[str, Any]:
    """A run's :func:`run_task` output from its summary and collected channels (also written
    to ``out_dir/result.json``, with ``series.npz`` for a logged run)."""
    series = collected_series(collector)
    traj = planned(scen.route, str(scen.route_path))
    bus = BusSeries(
        {
            "Host_Heartbeat": series["Host_Heartbeat"],
            "Bench_Truth_Pose": series["Bench_Truth_Pose"],
        },
        {},
        {},
    )
    result: dict[str, Any] = {
        "controller": task.controller,
        "scenario": task.scenario,
        "seed": task.seed,
        "fault_setting": task.setting,
        "variation": dataclasses.asdict(task.variation),
        "log": f"runs/{task.key}/run.mcap" if task.log else None,
    }
    for k in (*CELL_METRICS, "stop_reason", "final_state", "tracking_ended_early_s", *SHARE_FIELDS):
        if k in summary:
            result[k] = summary[k]
    # the estimate's largest per-tick step beyond odometry (m, rad; docs/planner.md)
    for k in ("estimate_step_max_m", "estimate_step_max_rad"):
        if k in summary:
            result[k] = summary[k]
    diag = summary.get("fault_diagnosis") or {}
    result["fault_diagnosis"] = {
        k: diag.get(k)
        for k in ("injected", "identified", "detection_delay_s", "false_alarm_fraction")
    }
    result["fault_diagnosis"]["faults"] = [
        {k: f.get(k) for k in ("name", "onset_s", "end_s", "identified", "detection_delay_s")}
        for f in diag.get("faults", [])
    ]
    nominal_r = _nominal_radius(scen)
    result["faults"] = [
        {
            "type": f.kind,
            "side": f.side,
            "onset_s": f.params.onset_s,
            "end_s": None if f.end_ns is None else f.end_ns / 1e9,
            "stress": stress_of(f, nominal_r) if f.kind in _SCALABLE else None,
        }
        for f in scen.faults
    ]
    arrays: dict[str, np.ndarray] = {}
    t0 = tracking_window(bus)
    if t0 is not None:
        t1 = t0 + int(traj.duration_s * 1e9)
        last = last_tracking_ns(bus)
        if last is not None and last < t1:
            t1 = last
        e = tracking_errors(bus, traj, t0, t1)
        if e:
            pos = np.hypot(e["x_e"], e["y_e"])
            arrays.update(
                t_s=e["t_ns"] * 1e-9,
                tau_s=e["tau"],
                x=e["x"],
                y=e["y"],
                phi=e["phi"],
                ref_x=e["ref_x"],
                ref_y=e["ref_y"],
                x_e=e["x_e"],
                y_e=e["y_e"],
                phi_e=e["phi_e"],
                pos_err=pos,
            )
            result["windows"] = window_errors(
                e["t_ns"], pos, [(f["onset_s"], f["end_s"]) for f in result["faults"]]
            )
        tw = series["Bench_Truth_Twist"]
        sel = (tw["t"] >= t0) & (tw["t"] <= t1)
        result.update(comfort(tw["t"][sel], tw["V"][sel], tw["Omega"][sel]))
        arrays.update(twist_t_s=tw["t"][sel] * 1e-9, twist_v=tw["V"][sel], twist_w=tw["Omega"][sel])
        for name, prefix in (("reference", "ref"), ("command", "cmd")):
            s = series[name]
            sel = (s["t"] >= t0) & (s["t"] <= t1)
            arrays[f"{prefix}_t_s"] = s["t"][sel] * 1e-9
            for sig in _SERIES_TOPICS[f"/controller/{name}"][1]:
                arrays[f"{prefix}_{sig}"] = s[sig][sel]
        arrays["t0_s"] = np.array([t0 * 1e-9])
    if not task.log:  # the figures draw logged runs only
        arrays = {}
    else:
        buf = io.BytesIO()
        savez: Any = np.savez_compressed  # numpy's stub types **kwds as bool
        savez(buf, **arrays)
        (out_dir / "series.npz").write_bytes(buf.getvalue())
    timing = {k: summary.get(k) for k in TIMING_FIELDS}
    timing["worker_wall_s"] = time.monotonic() - t_start
    record = {"task": _task_record(task), "result": jsonable(result), "timing": jsonable(timing)}
    (out_dir / "result.json").write_text(jsonsafe.dumps(record, indent=1, sort_keys=True) + "\n")
    return {"key": task.key, "error": None, **record, "series": arrays}


def _task_record(task: Task) -> dict[str, Any]:
    return dict(json.loads(json.dumps(dataclasses.asdict(task))))


def load_cached(root: Path, task: Task) -> dict[str, Any] | None:
    """The earlier result of ``task`` in ``root`` (``result.json`` of the same task), or None."""
    path = root / "runs" / task.key / "result.json"
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if record.get("task") != _task_record(task):
        return None
    if task.log and not (path.parent / "series.npz").exists():
        return None
    timing = dict(record.get("timing") or {})
    timing["resumed"] = True
    return {"key": task.key, "error": None, "result": record["result"], "timing": timing}


def _nominal_radius(scen: Any) -> float:

    return float(
        load_bench_config(scen.bench, source=str(scen.path), prefix="bench").chair.wheel_radius_m
    )
