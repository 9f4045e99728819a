"""``wheelchair-hil evaluate``: the paper's experiments as a campaign of lock-step runs.

This module owns the campaign: which runs make up the paper's table, the figures, the
Monte-Carlo cells, the amplitude sweeps of the fragility spectrum and the repeated-exposure
study (:func:`plan_campaign`); how they are executed (in this process, in a pool of worker
processes, or on a Dask cluster: :func:`execute`); what one run yields beyond its summary
(:func:`run_task`: ground-truth time series, ISO 2631 comfort, per-fault windows); and how the
runs become ``results.json`` (:func:`build_results`: table, rank, Monte-Carlo statistics,
convexity and class per controller and fault, gain from exposure).  ``tools.evaluation.report`` writes
``report.md`` and ``tools.evaluation.figures`` the PNGs from the same data.  docs/evaluation.md states the
method (rank, estimator, thresholds, variations).

Everything but the ``timing`` section of ``results.json`` is a function of the options and
the seeds: a campaign run twice gives the same file, whatever the number of workers.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import logging
import math
import multiprocessing
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from controller import comfort as iso
from controller.tracking import registry
from dbc.runtime import jsonsafe
from dbc.runtime import params as params_mod
from dbc.runtime.errors import WheelchairError
from firmware_sim.config import load_bench_config
from firmware_sim.faults import FaultSpec
from tools.console.progress import Progress
from tools.evaluation import figures as figures_mod
from tools.evaluation import report as report_mod
from tools.evaluation.plan import (
    _SCALABLE,
    CASCADED,
    CELL_METRICS,
    COMFORT_K_HORIZONTAL,
    DEFAULT_CONTROLLERS,
    EXPOSURE_SCENARIO,
    FAULT_FREE,
    FAULT_SETTINGS,
    MC_AMPLITUDE_SPREAD,
    MC_CASCADE_FACTOR,
    MC_CASCADE_LAST_S,
    MC_CASCADE_WINDOW_S,
    MC_MASS_SPREAD,
    MC_NOISE_RANGE,
    MC_OFFSET_M,
    MC_OFFSET_RAD,
    MC_ONSET_SHIFT_S,
    PAPER_SCENARIOS,
    RANK_METRICS,
    REFERENCE_CONTROLLER,
    REFERENCE_CONTROLLERS,
    SPECTRUM_FACTORS,
    SPECTRUM_FAULTS,
    SPECTRUM_METRIC,
    SPECTRUM_TOLERANCE,
    TIMING_FIELDS,
    VARIANT_SCENARIOS,
    VARIANTS,
)
from tools.evaluation.results import (
    FAMILY_ALPHA,
    ci95,
    classify,
    convexity,
    count_pairs,
    judge_pairs,
    pair_tests,
    rank,
    rank_verdicts,
    replicate_table,
    variant_effect,
)
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
from tools.run.runner import planned
from tools.tuning import gainsfile

if TYPE_CHECKING:
    from tools.metrics.tracking import BusCollector

log = logging.getLogger(__name__)


class EvaluationError(WheelchairError):
    """A campaign cannot be set up or executed (bad option, missing optional dependency)."""


# ------------------------------------------------------------------ variations


@dataclass(frozen=True)
class Variation:
    """How one run departs from its scenario file.  The default is the nominal run.

    ``replicate`` 0 is the nominal condition; replicates >= 1 are Monte-Carlo draws
    (:func:`draw_variation`).  ``seed`` None keeps the campaign's base seed.
    """

    replicate: int = 0
    seed: int | None = None
    amplitude_factor: float = 1.0
    onset_shift_s: float = 0.0
    mass_factor: float = 1.0
    noise_factor: float = 1.0
    initial_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    only_fault: int | None = None
    #: per fault of the schedule: (onset_s, duration_s, amplitude factor), replacing the
    #: schedule's timing and the common onset shift and amplitude (:func:`draw_cascade`)
    cascade: tuple[tuple[float, float, float], ...] | None = None

    def tag(self) -> str:
        """A short, content-derived name for the run's directory."""
        parts = []
        if self.cascade is not None:
            parts.append("random")
        if self.replicate:
            parts.append(f"r{self.replicate:02d}")
        if self.amplitude_factor != 1.0:
            parts.append(f"x{self.amplitude_factor:g}")
        if self.only_fault is not None:
            parts.append(f"only{self.only_fault + 1}")
        return "-".join(parts) or "nominal"


def draw_variation(base_seed: int, replicate: int, *, vary_amplitude: bool = True) -> Variation:
    """Monte-Carlo replicate ``replicate`` (>= 1) of a campaign seeded with ``base_seed``.

    Every draw is made in a fixed order whatever is used, so replicate ``r`` has the same
    mass, noise, onset, initial pose and seed in every scenario and for every controller
    (common random numbers), with or without the amplitude draw.
    """
    if replicate < 1:
        raise ValueError(f"Monte-Carlo replicates start at 1, got {replicate}")
    rng = np.random.default_rng([base_seed, replicate])
    seed = int(rng.integers(1, 2**31 - 1))
    noise = float(rng.uniform(*MC_NOISE_RANGE))
    onset = float(rng.uniform(-MC_ONSET_SHIFT_S, MC_ONSET_SHIFT_S))
    amplitude = float(rng.uniform(1.0 - MC_AMPLITUDE_SPREAD, 1.0 + MC_AMPLITUDE_SPREAD))
    along, left = (float(v) for v in rng.uniform(-MC_OFFSET_M, MC_OFFSET_M, size=2))
    heading = float(rng.uniform(-MC_OFFSET_RAD, MC_OFFSET_RAD))
    mass = float(rng.uniform(1.0 - MC_MASS_SPREAD, 1.0 + MC_MASS_SPREAD))
    return Variation(
        replicate=replicate,
        seed=seed,
        amplitude_factor=amplitude if vary_amplitude else 1.0,
        onset_shift_s=onset,
        mass_factor=mass,
        noise_factor=noise,
        initial_offset=(along, left, heading),
    )


def draw_cascade(base_seed: int, replicate: int, n_faults: int) -> Variation:
    """Monte-Carlo replicate ``replicate`` of the cascaded run: :func:`draw_variation`'s
    draws (noise, mass, initial pose, seed), and faults at random moments with random
    magnitudes, in the schedule's order (plan.MC_CASCADE_*)."""
    base = draw_variation(base_seed, replicate, vary_amplitude=False)
    rng = np.random.default_rng([base_seed, replicate, 13])
    onsets = np.sort(rng.uniform(*MC_CASCADE_WINDOW_S, size=n_faults))
    last = float(rng.uniform(*MC_CASCADE_LAST_S))
    factors = rng.uniform(*MC_CASCADE_FACTOR, size=n_faults)
    ends = [*onsets[1:], onsets[-1] + last] if n_faults else []
    cascade = tuple(
        (float(t0), float(t1 - t0), float(k))
        for t0, t1, k in zip(onsets, ends, factors, strict=True)
    )
    return dataclasses.replace(base, onset_shift_s=0.0, cascade=cascade)


def stress_of(spec: Any, nominal_radius_m: float) -> float:
    """The amplitude of a fault in its natural unit: radius lost (m), eccentricity (m), ratio."""
    p = spec.params
    if spec.kind == "flat-tire":
        return float(nominal_radius_m - p.to_radius_m)
    if spec.kind == "shaft-bump":
        return float(p.amplitude_m)
    if spec.kind == "slip":
        return float(p.ratio)
    raise EvaluationError(f"fault {spec.kind!r} has no amplitude the evaluation can scale")


def _scaled_fault(
    spec: Any,
    factor: float,
    shift_s: float,
    r0: float,
    source: str,
    duration_s: float | None = None,
) -> Any:

    changes: dict[str, Any] = {"onset_s": max(0.0, spec.params.onset_s + shift_s)}
    if duration_s is not None:
        changes["duration_s"] = duration_s
    if factor != 1.0:
        p = spec.params
        if spec.kind == "flat-tire":
            changes["to_radius_m"] = r0 - factor * (r0 - p.to_radius_m)
        elif spec.kind == "shaft-bump":
            changes["amplitude_m"] = factor * p.amplitude_m
        elif spec.kind == "slip":
            changes["ratio"] = factor * p.ratio
        else:
            raise EvaluationError(f"{source}: fault {spec.kind!r} has no amplitude to scale")
    return FaultSpec(
        spec.kind, params_mod.replace(spec.params, changes, source=source, prefix="faults")
    )


def _merge(base: Mapping[str, Any], extra: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in extra.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def apply_variation(scenario: Any, var: Variation) -> Any:
    """The scenario as the run sees it: faults scaled and shifted, bench and start changed."""

    source = f"{scenario.path} (evaluation variation {var.tag()})"
    bench_cfg = load_bench_config(scenario.bench, source=str(scenario.path), prefix="bench")
    r0 = bench_cfg.chair.wheel_radius_m
    faults = scenario.faults
    if var.only_fault is not None:
        if not 0 <= var.only_fault < len(faults):
            raise EvaluationError(f"{source}: no fault number {var.only_fault + 1}")
        faults = (faults[var.only_fault],)
    if var.amplitude_factor == 0.0:
        faults = ()
    if var.cascade is not None:
        if len(var.cascade) != len(faults):
            raise EvaluationError(
                f"{source}: {len(var.cascade)} random fault times for {len(faults)} faults"
            )
        faults = tuple(
            _scaled_fault(f, k, t0 - f.params.onset_s, r0, source, duration_s=dur)
            for f, (t0, dur, k) in zip(faults, var.cascade, strict=True)
        )
    else:
        faults = tuple(
            _scaled_fault(f, var.amplitude_factor, var.onset_shift_s, r0, source) for f in faults
        )
    bench = dict(scenario.bench)
    if var.mass_factor != 1.0:
        chair = bench_cfg.chair
        bench = _merge(
            bench,
            {
                "chair": {
                    "mass_kg": chair.mass_kg * var.mass_factor,
                    "yaw_inertia_kgm2": chair.yaw_inertia_kgm2 * var.mass_factor,
                }
            },
        )
    if var.noise_factor != 1.0:
        loc = bench_cfg.localizer
        bench = _merge(
            bench,
            {
                "localizer": {
                    "sigma_xy_m": loc.sigma_xy_m * var.noise_factor,
                    "sigma_heading_rad": loc.sigma_heading_rad * var.noise_factor,
                }
            },
        )
    load_bench_config(bench, source=source, prefix="bench")  # fail here, naming the variation
    offset = tuple(
        a + b for a, b in zip(scenario.params.initial_offset, var.initial_offset, strict=True)
    )
    sp = params_mod.replace(
        scenario.params, {"initial_offset": list(offset)}, source=source, prefix="scenario"
    )
    return dataclasses.replace(scenario, params=sp, bench=bench, faults=faults)


# ------------------------------------------------------------------------ tasks


@dataclass(frozen=True)
class Task:
    """One experiment of a campaign: a controller on a (varied) scenario."""

    controller: str
    scenario: str
    variation: Variation = Variation()
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


def _jsonable(x: Any) -> Any:
    """``x`` with numpy scalars as Python numbers and non-finite floats as None."""
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
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


def _series(collector: BusCollector) -> dict[str, dict[str, np.ndarray]]:
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
    series = _series(collector)
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
    for k in (*CELL_METRICS, "stop_reason", "final_state", "tracking_ended_early_s"):
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
    record = {"task": _task_record(task), "result": _jsonable(result), "timing": _jsonable(timing)}
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


# ------------------------------------------------------------------- campaign


#: --logs: which runs of a campaign keep their MCAP log (Options.logs)
LOG_CHOICES = ("nominal", "all")


@dataclass(frozen=True)
class Options:
    """What a campaign runs (the command line's options)."""

    controllers: tuple[str, ...] = DEFAULT_CONTROLLERS
    scenarios: tuple[str, ...] = PAPER_SCENARIOS
    seed: int = 1
    seeds: int = 1
    cascaded: bool = True
    spectrum: bool = False
    spectrum_faults: tuple[str, ...] = SPECTRUM_FAULTS
    spectrum_seeds: int = 3
    exposure: bool = False
    duration_s: float | None = None
    #: fault settings (plan.FAULT_SETTINGS); the first is the primary one
    settings: tuple[str, ...] = FAULT_SETTINGS
    #: tuned gains file (tools.tuning.gainsfile); None: controller/gains.toml as it is
    gains: str | None = None
    #: which runs keep their MCAP log and time series: "nominal" (the primary setting's
    #: nominal runs: every run the figures draw, one logged run per cell of the paper's
    #: table), "all"
    logs: str = "nominal"
    #: Monte-Carlo replicates for the reference row (BASELINE) too, not only for the ranked
    #: controllers and the variants
    reference_mc: bool = False
    #: replicates of the cascaded run with faults at random moments (0: the fixed schedule only)
    cascade_seeds: int = 0


@dataclass
class Campaign:
    """The tasks of a campaign (deduplicated) and the role each plays in the results."""

    options: Options
    tasks: dict[str, Task] = field(default_factory=dict)
    #: (setting, controller, scenario) -> key
    table: dict[tuple[str, str, str], str] = field(default_factory=dict)
    monte_carlo: dict[tuple[str, str, str], list[str]] = field(default_factory=dict)
    #: (setting, controller) -> key; and the random cascades (Monte-Carlo)
    cascaded: dict[tuple[str, str], str] = field(default_factory=dict)
    cascaded_mc: dict[tuple[str, str], list[str]] = field(default_factory=dict)
    #: controller -> its tuned gains and their provenance (empty: controller/gains.toml)
    gains: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: (controller, fault) -> replicate -> factor -> key
    spectrum: dict[tuple[str, str], list[dict[float, str]]] = field(default_factory=dict)
    #: controller -> {"repeated": key, "single": [key or None per exposure]}
    exposure: dict[str, dict[str, Any]] = field(default_factory=dict)

    def add(self, task: Task) -> str:
        """Add ``task`` once (the same experiment asked for twice is one run, logged if either
        asks for a log)."""
        old = self.tasks.get(task.key)
        if old is None or (task.log and not old.log):
            self.tasks[task.key] = task
        return task.key


def plan_campaign(opt: Options) -> Campaign:
    """Every run the options ask for, each once (see the module doc and docs/evaluation.md)."""

    if not opt.controllers:
        raise EvaluationError("--controllers: at least one controller is needed")
    for c in opt.controllers:
        if c not in registry.names():
            raise EvaluationError(
                f"--controllers: unknown controller {c!r}; known: {', '.join(registry.names())}"
            )
    if opt.seeds < 1 or opt.spectrum_seeds < 1 or opt.cascade_seeds < 0:
        raise EvaluationError(
            "--seeds and --spectrum-seeds must be at least 1, --cascade-seeds at least 0"
        )
    if opt.logs not in LOG_CHOICES:
        raise EvaluationError(f"--logs: choose one of {', '.join(LOG_CHOICES)}, got {opt.logs!r}")
    scenario_mod.check_seed(opt.seed)
    for s in opt.scenarios:
        scenario_mod.find(s)  # ConfigError naming the scenario
    if not opt.settings:
        raise EvaluationError("--settings: at least one fault setting is needed")
    for st in opt.settings:
        if st not in FAULT_SETTINGS:
            raise EvaluationError(
                f"--settings: unknown fault setting {st!r}; known: {', '.join(FAULT_SETTINGS)}"
            )
    camp = Campaign(opt)
    if opt.gains is not None:
        tuned = gainsfile.load(Path(opt.gains))
        # a variant runs with the tuned gains of the controller it varies
        camp.gains = {
            c: tuned[VARIANTS.get(c, c)] for c in opt.controllers if VARIANTS.get(c, c) in tuned
        }
    gains_json = {c: json.dumps(e["gains"], sort_keys=True) for c, e in camp.gains.items()}
    scenarios: dict[str, Any] = {}

    def task(c: str, s: str, var: Variation = Variation(), setting: str | None = None) -> str:
        # runs that are the same experiment in two settings are made once
        scen = scenarios.get(s)
        if scen is None:
            scen = scenarios[s] = scenario_mod.load(s)
        eff = scenario_mod.effective_setting(scen, setting or opt.settings[0])
        logged = opt.logs == "all" or (
            var.replicate == 0 and (setting or opt.settings[0]) == opt.settings[0]
        )
        return camp.add(
            Task(
                c,
                s,
                var,
                opt.duration_s,
                opt.seed,
                setting=eff,
                gains=gains_json.get(c, ""),
                log=logged,
            )
        )

    for st in opt.settings:
        for c in opt.controllers:
            # a variant answers one question: what it changes in the cells it concerns, in the
            # primary setting (the paper's, where the question arose)
            if c in VARIANTS and st != opt.settings[0]:
                continue
            cells = [s for s in opt.scenarios if c not in VARIANTS or s in VARIANT_SCENARIOS]
            replicated = opt.seeds > 1 and (c != REFERENCE_CONTROLLER or opt.reference_mc)
            for s in cells:
                camp.table[(st, c, s)] = task(c, s, setting=st)
                if replicated:
                    camp.monte_carlo[(st, c, s)] = [
                        task(c, s, draw_variation(opt.seed, r), st) for r in range(1, opt.seeds + 1)
                    ]
            if opt.cascaded and c not in VARIANTS:
                camp.cascaded[(st, c)] = task(c, CASCADED, setting=st)
                if opt.cascade_seeds > 0:
                    n = len(scenario_mod.load(CASCADED).faults)
                    camp.cascaded_mc[(st, c)] = [
                        task(c, CASCADED, draw_cascade(opt.seed, r, n), st)
                        for r in range(1, opt.cascade_seeds + 1)
                    ]
    if opt.spectrum:
        unknown = sorted(set(opt.spectrum_faults) - set(SPECTRUM_FAULTS))
        if unknown:
            raise EvaluationError(
                f"--spectrum-faults: unknown fault {unknown[0]!r}; known: {', '.join(SPECTRUM_FAULTS)}"
            )
        for c in opt.controllers:
            for fault in opt.spectrum_faults:
                reps: list[dict[float, str]] = []
                for r in range(opt.spectrum_seeds):
                    base = draw_variation(opt.seed, r, vary_amplitude=False) if r else Variation()
                    grid = {}
                    for f in SPECTRUM_FACTORS:
                        if f == 0.0:  # no fault at all: the fault-free run of that replicate
                            grid[f] = task(c, FAULT_FREE, base)
                        else:
                            grid[f] = task(c, fault, dataclasses.replace(base, amplitude_factor=f))
                    reps.append(grid)
                camp.spectrum[(c, fault)] = reps
    if opt.exposure:
        n = len(scenario_mod.load(EXPOSURE_SCENARIO).faults)
        for c in opt.controllers:
            camp.exposure[c] = {
                "repeated": task(c, EXPOSURE_SCENARIO),
                # the first exposure alone is the repeated run up to its end: no extra run
                "single": [None]
                + [task(c, EXPOSURE_SCENARIO, Variation(only_fault=k)) for k in range(1, n)],
            }
    return camp


def _cost(task: Task) -> float:
    """Rough relative cost, to start the longest runs first."""
    c = {"adaptive": 1.4}.get(task.controller, 1.0)
    d = task.duration_s if task.duration_s is not None else 90.0
    return c * d


# ----------------------------------------------------------------- executors


ProgressFn = Callable[[dict[str, Any]], None]


def execute(
    tasks: Sequence[Task],
    root: Path,
    *,
    workers: int = 1,
    scheduler: Any = None,
    progress: bool = True,
    table: Sequence[str] = (),
) -> dict[str, dict[str, Any]]:
    """Run ``tasks``; return each one's :func:`run_task` output by key.

    ``scheduler`` (a Dask scheduler address, or a ``distributed`` cluster object) runs
    them on a Dask cluster; otherwise ``workers`` > 1 uses a pool of that many worker
    processes (spawned: no state is inherited) and 1 runs them here, one after the other.
    In the pool, the runs without a log on the ``table``'s scenarios share their start
    (:func:`groups`, :func:`run_group`): the same figures as run one by one.
    """

    order = sorted(tasks, key=lambda t: (-_cost(t), t.key))
    out: dict[str, dict[str, Any]] = {}
    # a bar on a terminal; elsewhere (a CI log) a plain line per tenth of the runs
    bar = Progress(len(order), "evaluate", "run", enabled=progress)

    def done(res: dict[str, Any]) -> None:
        out[res["key"]] = res
        if res.get("error"):
            bar.write(f"run {res['key']} failed: {res['error']}")
        bar.update(1, note=f"last: {res['key']}")

    with bar:
        if scheduler is not None:
            _execute_dask(order, root, scheduler, done)
        elif workers > 1 and len(order) > 1:
            _execute_pool(order, root, workers, done, table)
        else:
            for t in order:
                done(run_task(t, str(root)))
    return out


def _worker_init() -> None:
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)


def groups(tasks: Sequence[Task], table: Sequence[str]) -> list[list[Task]]:
    """``tasks`` as units of work: the runs without a log of one controller, variation and
    fault setting on the ``table``'s scenarios (which differ only in their faults) form one
    group, run as branches of one run (:func:`run_group`); every other task is a unit of its
    own.  In the order of ``tasks``' first members."""
    units: dict[Any, list[Task]] = {}
    for t in tasks:
        shared = not t.log and t.scenario in table
        key: Any = (
            (t.controller, t.variation, t.setting, t.base_seed, t.duration_s, t.gains)
            if shared
            else t.key
        )
        units.setdefault(key, []).append(t)
    return list(units.values())


def _execute_pool(
    tasks: Sequence[Task],
    root: Path,
    workers: int,
    done: ProgressFn,
    table: Sequence[str] = (),
) -> None:
    ctx = multiprocessing.get_context("spawn")
    units = groups(tasks, table)
    with ProcessPoolExecutor(
        max_workers=min(workers, len(units)), mp_context=ctx, initializer=_worker_init
    ) as pool:
        futures = [pool.submit(run_group if len(u) > 1 else _run_unit, u, str(root)) for u in units]
        for fut in as_completed(futures):
            for r in fut.result():
                done(r)


def _run_unit(tasks: Sequence[Task], root: str) -> list[dict[str, Any]]:
    """:func:`run_task` of a unit of one task, as a list (the pool's other worker function)."""
    return [run_task(t, root) for t in tasks]


def _execute_dask(tasks: Sequence[Task], root: Path, scheduler: Any, done: ProgressFn) -> None:
    try:
        from distributed import Client, as_completed  # lazy: the optional [dask] extra
    except ImportError as err:
        raise EvaluationError(
            f"--scheduler needs dask.distributed ({err}); install the optional extra: "
            "pip install 'wheelchair-hil[dask]'"
        ) from err
    try:
        client = Client(scheduler, set_as_default=False)
    except OSError as err:
        raise EvaluationError(f"--scheduler {scheduler}: cannot reach it: {err}") from err
    with client:
        futures = [
            client.submit(run_task, t, str(root), key=f"evaluate-{t.key}", pure=False)
            for t in tasks
        ]
        for fut in as_completed(futures, loop=client.loop):
            done(fut.result())


# ----------------------------------------------------------------- statistics


# ------------------------------------------------------------------- results


def build_results(
    camp: Campaign,
    runs: Mapping[str, Mapping[str, Any]],
    wall_s: float,
    workers: str,
    n_workers: int = 1,
) -> dict[str, Any]:
    """``results.json``: everything but ``timing`` depends only on the options and seeds.

    ``settings[name]`` holds each fault setting's table, rank, Monte-Carlo bands, verdicts
    and cascaded runs; the top-level ``table``, ``rank``, ``monte_carlo``, ``verdicts`` and
    ``cascaded`` are the primary setting's (``meta.setting``), which the figures draw.
    """
    opt = camp.options
    ranked = [c for c in opt.controllers if c not in REFERENCE_CONTROLLERS] or list(opt.controllers)
    blocks = {st: _setting_block(camp, runs, st, ranked) for st in opt.settings}
    _judge(blocks)
    primary = opt.settings[0]
    out: dict[str, Any] = {
        "meta": {
            "controllers": list(opt.controllers),
            "ranked_controllers": ranked,
            "scenarios": list(opt.scenarios),
            "seed": opt.seed,
            "seeds": opt.seeds,
            "duration_s": opt.duration_s,
            "runs": len(camp.tasks),
            "failed_runs": sorted(k for k, v in runs.items() if v.get("error")),
            "rank_definition": "per metric: mean over the table's scenarios, ascending; 1 = best",
            "setting": primary,
            "setting_label": scenario_mod.FAULT_SETTINGS[primary],
            "settings": list(opt.settings),
            "setting_labels": {st: scenario_mod.FAULT_SETTINGS[st] for st in opt.settings},
            "verdict_definition": (
                "per pair of ranked controllers and component: the paired differences of "
                "their scenario-averaged RMSE over the Monte-Carlo replicates (common random "
                "numbers; a failed run counts as its replicate's worst result), a two-sided "
                "t test with n - 1 degrees of freedom, p-values Holm-adjusted over every pair "
                f"of every component and setting of the campaign (family-wise alpha "
                f"{FAMILY_ALPHA}): borne out if significant in the paper's order, refuted if "
                "significant in the other, undecided otherwise; a controller's rank is "
                "reproduced if all its pairs are borne out, contradicted if any is refuted, "
                "not resolved otherwise"
            ),
            "gains": {
                c: {"source": opt.gains, **e["provenance"]} for c, e in sorted(camp.gains.items())
            },
        },
        "settings": {st: {k: v for k, v in b.items() if k != "timing"} for st, b in blocks.items()},
    }
    for k in (
        "table",
        "rank",
        "monte_carlo",
        "verdicts",
        "pair_tests",
        "pair_counts",
        "cascaded",
        "cascaded_mc",
    ):
        if k in blocks[primary]:
            out[k] = blocks[primary][k]
    if camp.spectrum:
        out["meta"]["spectrum"] = _spectrum_method(camp)
        out["spectrum"] = _spectrum(camp, runs)
    if camp.exposure:
        out["exposure"] = _exposure(camp, runs)
    sim_s = sum(
        float((v.get("timing") or {}).get("sim_duration_s") or 0.0)
        for v in runs.values()
        if not (v.get("timing") or {}).get("resumed")
    )
    n_workers = max(1, n_workers)
    out["timing"] = {
        "campaign_wall_s": wall_s,
        "executor": workers,
        # simulated seconds per second of each worker: the campaign's real-time factor
        "sim_s": sim_s,
        "workers": n_workers,
        "real_time_factor_per_worker": sim_s / (wall_s * n_workers) if wall_s > 0 else None,
        "table": blocks[primary]["timing"],
        "settings": {st: b["timing"] for st, b in blocks.items()},
        "runs": {k: v.get("timing") for k, v in sorted(runs.items())},
    }
    return _jsonable(out)


def _judge(blocks: Mapping[str, dict[str, Any]]) -> None:
    """The verdicts of every setting's pairs as one family (Holm over all of them), then each
    setting's rank verdicts and pair counts (in place)."""
    family = {
        (st, m, k): t
        for st, b in blocks.items()
        for m, tests in (b.get("pair_tests") or {}).items()
        for k, t in tests.items()
    }
    judge_pairs(family)
    for b in blocks.values():
        if "pair_tests" not in b:
            continue
        tables = b["monte_carlo"]["replicate_means"]
        b["verdicts"] = {
            m: rank_verdicts(tests, tables[m], report_mod.PAPER_RANK.get(m, {}))
            for m, tests in b["pair_tests"].items()
        }
        b["pair_counts"] = {m: count_pairs(tests) for m, tests in b["pair_tests"].items()}


def _setting_block(
    camp: Campaign, runs: Mapping[str, Mapping[str, Any]], st: str, ranked: Sequence[str]
) -> dict[str, Any]:
    """One fault setting's part of ``results.json`` (and its ``timing`` table)."""
    opt = camp.options

    def res(key: str | None) -> dict[str, Any]:
        return dict(runs.get(key, {}).get("result") or {}) if key else {}

    def metric(key: str | None, m: str) -> float:
        v = res(key).get(m)
        return float(v) if v is not None else math.nan

    table: dict[str, dict[str, Any]] = {}
    timing_table: dict[str, dict[str, Any]] = {}
    for (s_, c, s), key in camp.table.items():
        if s_ != st:
            continue
        r = res(key)
        cell = {m: r.get(m) for m in CELL_METRICS}
        cell.update(
            stop_reason=r.get("stop_reason"),
            fault_diagnosis=r.get("fault_diagnosis"),
            log=r.get("log"),
            fault_setting=camp.tasks[key].setting,
        )
        if runs.get(key, {}).get("error"):
            cell["error"] = runs[key]["error"]
        table.setdefault(c, {})[s] = cell
        timing_table.setdefault(c, {})[s] = runs.get(key, {}).get("timing")
    block: dict[str, Any] = {
        "label": scenario_mod.FAULT_SETTINGS[st],
        "table": table,
        "rank": {m: rank(table, ranked, opt.scenarios, m) for m in (*RANK_METRICS, "rmse_pos_m")},
        "timing": timing_table,
    }
    mc_keys = {(c, s): keys for (s_, c, s), keys in camp.monte_carlo.items() if s_ == st}
    if mc_keys:
        mc: dict[str, dict[str, Any]] = {}
        samples: dict[str, dict[str, dict[str, list[float]]]] = {}
        for (c, s), keys in mc_keys.items():
            for m in (*RANK_METRICS, *CELL_METRICS[3:]):
                samples.setdefault(m, {}).setdefault(c, {})[s] = [metric(k, m) for k in keys]
            mc.setdefault(c, {})[s] = {
                m: ci95(samples[m][c][s]) for m in (*RANK_METRICS, *CELL_METRICS[3:])
            }
        # per replicate, each controller's scenario mean (None: a run failed); paired by
        # replicate, since every controller saw the same draws
        tables = {m: replicate_table(samples[m], ranked, opt.scenarios) for m in RANK_METRICS}
        bands = {
            m: {c: ci95([v for v in tables[m][c] if v is not None]) for c in ranked}
            for m in RANK_METRICS
        }
        block["monte_carlo"] = {
            "replicates": opt.seeds,
            "variations": _mc_description(),
            "table": mc,
            "rank": {
                m: rank(
                    {c: {s: {m: mc[c][s][m]["mean"]} for s in mc[c]} for c in mc},
                    ranked,
                    opt.scenarios,
                    m,
                )
                for m in RANK_METRICS
            },
            "rank_bands": bands,
            # every replicate's figures, per metric, controller and scenario (None: failed),
            # and their scenario means: anyone can recompute a verdict from these
            "samples": samples,
            "replicate_means": tables,
        }
        # judged with the campaign's whole family of pairs in build_results
        block["pair_tests"] = {
            m: pair_tests(tables[m], report_mod.PAPER_RANK.get(m, {})) for m in RANK_METRICS
        }
        variants = {v: of for v, of in VARIANTS.items() if v in samples[RANK_METRICS[0]]}
        variants = {v: of for v, of in variants.items() if of in samples[RANK_METRICS[0]]}
        if variants:
            block["variants"] = {
                v: variant_effect(samples, v, of, opt.scenarios) for v, of in variants.items()
            }
    casc = {c: k for (s_, c), k in camp.cascaded.items() if s_ == st}
    if casc:
        block["cascaded"] = {c: _cascaded_cell(res(k)) for c, k in casc.items()}
    casc_mc = {c: keys for (s_, c), keys in camp.cascaded_mc.items() if s_ == st}
    if casc_mc:
        block["cascaded_mc"] = {
            "replicates": opt.seeds,
            "variations": {
                **_mc_description(),
                "fault_onset": f"sorted U{MC_CASCADE_WINDOW_S} s, each to the next onset, the "
                f"last for U{MC_CASCADE_LAST_S} s",
                "fault_amplitude": f"each fault x U{MC_CASCADE_FACTOR}",
            },
            "table": {
                c: {m: ci95([metric(k, m) for k in keys]) for m in (*RANK_METRICS, "rmse_pos_m")}
                for c, keys in casc_mc.items()
            },
            "draws": {
                c: [res(k).get("faults") for k in keys] for c, keys in list(casc_mc.items())[:1]
            },
        }
    return block


def _cascaded_cell(r: Mapping[str, Any]) -> dict[str, Any]:
    cell = {m: r.get(m) for m in CELL_METRICS}
    cell["windows"] = r.get("windows")
    cell["log"] = r.get("log")
    return cell


def _mc_description() -> dict[str, str]:
    return {
        "seed": "every random process of the bench (localizer noise, fault draws)",
        "sensor_noise": f"localizer sigma_xy and sigma_heading x U{MC_NOISE_RANGE}",
        "fault_onset": f"every fault's onset + U(-{MC_ONSET_SHIFT_S}, {MC_ONSET_SHIFT_S}) s",
        "fault_amplitude": f"x U(1 - {MC_AMPLITUDE_SPREAD}, 1 + {MC_AMPLITUDE_SPREAD})",
        "initial_pose": f"along, left U(-{MC_OFFSET_M}, {MC_OFFSET_M}) m; heading U(+-3 deg)",
        "mass": f"chair mass and yaw inertia x U(1 - {MC_MASS_SPREAD}, 1 + {MC_MASS_SPREAD})",
    }


def _spectrum_method(camp: Campaign) -> dict[str, Any]:
    return {
        "metric": SPECTRUM_METRIC,
        "factors": list(SPECTRUM_FACTORS),
        "tolerance": SPECTRUM_TOLERANCE,
        "replicates": camp.options.spectrum_seeds,
        "faults": list(camp.options.spectrum_faults),
        "estimator": "kappa = mean_k((E(c-k) + E(c+k))/2 - E(c)) / E(c), c = paper amplitude",
    }


def _spectrum(camp: Campaign, runs: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """spectrum[controller][fault]: class, convexity, band and the evidence."""
    out: dict[str, Any] = {}
    for (c, fault), reps in camp.spectrum.items():
        stress_axis: list[float] = []
        responses: list[list[float]] = []
        kappas: list[float] = []
        evidence: list[dict[str, Any] | None] = []
        for grid in reps:
            row = []
            for f in SPECTRUM_FACTORS:
                r = runs.get(grid[f], {}).get("result") or {}
                v = r.get(SPECTRUM_METRIC)
                row.append(math.nan if v is None else float(v))
            responses.append(row)
        nominal = runs.get(reps[0][1.0], {}).get("result") or {}
        unit_stress = next((f["stress"] for f in nominal.get("faults", []) if f["stress"]), None)
        if unit_stress is not None:
            stress_axis = [f * unit_stress for f in SPECTRUM_FACTORS]
        for row in responses:
            if all(math.isfinite(v) for v in row):
                est = convexity(list(SPECTRUM_FACTORS), row)
                kappas.append(est["kappa"])
                evidence.append(est)
            else:
                evidence.append(None)
        cls = classify(kappas)
        out.setdefault(c, {})[fault] = {
            **cls,
            "stress": stress_axis,
            "stress_unit": "1" if fault == "slip" else "m",
            "response": responses,
            "estimates": evidence,
            "logs": [[res_log(runs, grid[f]) for f in SPECTRUM_FACTORS] for grid in reps],
        }
    return out


def res_log(runs: Mapping[str, Mapping[str, Any]], key: str) -> str | None:
    return (runs.get(key, {}).get("result") or {}).get("log")


def _exposure(camp: Campaign, runs: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for c, roles in camp.exposure.items():
        rep = runs.get(roles["repeated"], {}).get("result") or {}
        windows = rep.get("windows") or []
        delays = [
            f.get("detection_delay_s") for f in rep.get("fault_diagnosis", {}).get("faults", [])
        ]
        rows = []
        for k, w in enumerate(windows):
            single_key = roles["single"][k] if k < len(roles["single"]) else None
            if single_key is None:
                single = w
                single_delay = delays[k] if k < len(delays) else None
            else:
                sr = runs.get(single_key, {}).get("result") or {}
                single = (sr.get("windows") or [{}])[0]
                sf = sr.get("fault_diagnosis", {}).get("faults", [])
                single_delay = sf[0].get("detection_delay_s") if sf else None
            e_rep, e_single = w.get("rmse_pos_m"), single.get("rmse_pos_m")
            rows.append(
                {
                    "exposure": k + 1,
                    "onset_s": w.get("onset_s"),
                    "end_s": w.get("end_s"),
                    "rmse_pos_m": e_rep,
                    "max_pos_err_m": w.get("max_pos_err_m"),
                    "rmse_pos_m_first_time": e_single,
                    "gain_m": None if e_rep is None or e_single is None else e_single - e_rep,
                    "detection_delay_s": delays[k] if k < len(delays) else None,
                    "detection_delay_s_first_time": single_delay,
                }
            )
        out[c] = {"exposures": rows, "log": rep.get("log")}
    return out


# ------------------------------------------------------------------- the command


def evaluate(
    opt: Options,
    out: str | Path,
    *,
    workers: int = 1,
    scheduler: Any = None,
    progress: bool = True,
    figures: bool = True,
    report: bool = True,
    resume: bool = False,
) -> dict[str, Any]:
    """Plan, run and write a campaign into ``out``; return ``results.json``'s content.

    ``resume``: reuse the runs already in ``out`` whose ``result.json`` records the same task
    (an interrupted campaign goes on where it stopped; their timing says ``resumed``).
    """
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    camp = plan_campaign(opt)
    t0 = time.monotonic()
    runs: dict[str, dict[str, Any]] = {}
    if resume:
        for key, task in camp.tasks.items():
            if (cached := load_cached(out_dir, task)) is not None:
                runs[key] = cached
    todo = [t for k, t in camp.tasks.items() if k not in runs]
    runs.update(
        execute(
            todo,
            out_dir,
            workers=workers,
            scheduler=scheduler,
            progress=progress,
            table=opt.scenarios,
        )
    )
    shutil.rmtree(out_dir / "runs" / ".branches", ignore_errors=True)
    for k, r in runs.items():  # a remote worker's series reach this machine here
        path = out_dir / "runs" / k / "series.npz"
        if r.get("series") and not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            savez: Any = np.savez_compressed
            savez(path, **r["series"])
    executor = (
        f"dask {scheduler}"
        if isinstance(scheduler, str)
        else ("dask cluster" if scheduler is not None else f"{workers} worker process(es)")
    )
    results = build_results(
        camp, runs, time.monotonic() - t0, executor, workers if scheduler is None else 1
    )
    made: list[str] = []
    if figures:
        made = figures_mod.make_all(results, out_dir)
    results["timing"]["total_wall_s"] = time.monotonic() - t0
    write_results(results, out_dir / "results.json")
    if report:
        report_mod.write_report(results, out_dir, made)
    return results


def write_results(results: Mapping[str, Any], path: Path) -> None:
    """``results.json`` with sorted keys, so that equal campaigns give equal files."""
    path.write_text(
        json.dumps(_jsonable(results), indent=1, sort_keys=True, allow_nan=False) + "\n"
    )


def deterministic_part(results: Mapping[str, Any]) -> dict[str, Any]:
    """``results`` without its wall-clock ``timing`` section."""
    return {k: v for k, v in results.items() if k != "timing"}


def _repo_path(p: str) -> Path:
    """A relative path as given if it exists here, else among the packaged scenarios (for
    ``scenarios/...``) or relative to the repository."""
    path = Path(p)
    if path.is_absolute() or path.exists():
        return path
    if path.parts and path.parts[0] == "scenarios":
        return scenario_mod.SCENARIO_DIR.joinpath(*path.parts[1:])
    return scenario_mod.REPO_ROOT / path


def run(args: argparse.Namespace, argv: list[str]) -> int:
    opt = Options(
        controllers=tuple(args.controllers),
        scenarios=tuple(args.scenarios),
        seed=args.seed,
        seeds=args.seeds,
        cascaded=not args.no_cascaded,
        spectrum=args.spectrum,
        spectrum_faults=tuple(args.spectrum_faults),
        spectrum_seeds=args.spectrum_seeds,
        exposure=args.exposure,
        duration_s=args.duration,
        settings=tuple(args.settings),
        gains=None if args.gains == "none" else str(_repo_path(args.gains)),
        logs=args.logs,
        reference_mc=args.reference_mc,
        cascade_seeds=args.cascade_seeds,
    )
    if args.workers < 1:
        raise EvaluationError(f"--workers {args.workers}: must be at least 1")
    results = evaluate(
        opt,
        args.out,
        workers=args.workers,
        scheduler=args.scheduler,
        progress=not args.no_progress,
        figures=not args.no_figures,
        resume=args.resume,
    )

    print(report_mod.console_summary(results, Path(args.out)))
    return 1 if results["meta"]["failed_runs"] else 0
