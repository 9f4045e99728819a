"""A run's log after the run: one ``run.mcap``, and the summary computed from it alone.

:func:`finalize` is the post-run step of ``wheelchair-hil run``: once the parts have
exited it merges the controller's log (``controller.mcap``) into the recorder's
``run.mcap`` and adds the statistics of the parts and of the run as metadata
records (``run``, ``bench_stats``; ``controller_stats`` and ``controller_config``
come with the controller's log, ``recorder`` and ``versions`` are the recorder's).
``controller.mcap`` is deleted once merged and kept if the merge fails.

:func:`summarize` computes ``summary.json`` from a finalized ``run.mcap``; a run's summary
(``tools.run.summary.build_summary``) and ``wheelchair-hil summarize LOG.mcap`` both call it,
so the two cannot disagree.  Without a trajectory it re-plans the route from the
log's attachment.
"""

from __future__ import annotations

import json
import logging
import math
import tempfile
import tomllib
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from controller.config import ControllerConfig, load_config
from controller.limits import RATE_LIMITS
from controller.planner import load_route, plan
from controller.types import Trajectory
from dbc.runtime import jsonsafe, params
from dbc.runtime.errors import WheelchairError
from tools.logs import mcap_io
from tools.logs.mcap_io import iter_frames, read_contents
from tools.metrics import diagnosis as diagnosis_metrics
from tools.metrics.tracking import BusSeries, read_bus_log, summarize_bus

log = logging.getLogger(__name__)

CONTROLLER_LOG = "controller.mcap"


class RunLogError(WheelchairError):
    """The log lacks what a summary or a replay needs."""


def finalize(
    out: Path,
    run_info: Mapping[str, Any],
    on_message: Callable[[Any, Any], None] | None = None,
) -> mcap_io.LogContents | None:
    """Merge ``out/controller.mcap`` and the parts' statistics into ``out/run.mcap``.

    ``on_message(channel, message)`` sees every message of the merged log as it is
    written, so a summary needs no second read.  Returns the merged log's contents
    (metadata, attachments, channels), or None if there was nothing to finalize or the
    merge failed.  Never raises: on failure the reason is logged and the files are
    left as they were.
    """
    run_path = out / "run.mcap"
    ctl_path = out / CONTROLLER_LOG
    if not run_path.exists():
        log.warning("no %s to finalize", run_path)
        return None
    md: dict[str, dict[str, str]] = {"run": {k: str(v) for k, v in run_info.items()}}
    bench = _read_json(out / "bench_stats.json")
    if bench:
        md["bench_stats"] = {k: jsonsafe.dumps(v) for k, v in bench.items()}
    extras = [ctl_path] if ctl_path.exists() else []
    contents = mcap_io.LogContents()
    try:
        mcap_io.merge_into(run_path, extras, metadata=md, on_message=on_message, contents=contents)
    except Exception as err:  # the run's data must survive a failed merge
        log.warning("could not merge %s into %s: %s (both kept)", ctl_path, run_path, err)
        return None
    if extras:
        ctl_path.unlink()
    return contents


def _read_json(path: Path) -> dict[str, Any]:
    try:
        return dict(json.loads(path.read_text()))
    except (OSError, ValueError, TypeError):
        return {}


def _stats(md: Mapping[str, str]) -> dict[str, Any]:
    """A metadata record of JSON-encoded values back as a dict."""
    out: dict[str, Any] = {}
    for k, v in md.items():
        try:
            out[k] = json.loads(v)
        except ValueError:
            out[k] = v
    return out


def recorded_config(metadata: Mapping[str, Mapping[str, str]]) -> ControllerConfig:
    """The controller configuration the run used (the defaults if the log does not say)."""
    cc = metadata.get("controller_config", {})
    if "config" in cc:
        return params.load(
            ControllerConfig, json.loads(cc["config"]), source="log: controller_config"
        )
    return load_config()


def recorded_trajectory(attachments: Mapping[str, bytes]) -> Trajectory:
    """Re-plan the route attached to the log (``route/<name>.toml``)."""

    routes = [n for n in attachments if n.startswith("route/")]
    if not routes:
        raise RunLogError(
            "the log has no route attachment (route/<name>.toml); pass the scenario with --scenario"
        )
    name = routes[0]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / Path(name).name
        path.write_bytes(attachments[name])
        tomllib.loads(path.read_text())  # a clear error for a damaged attachment
        return plan(load_route(path), source=f"log attachment {name}")


def summarize(
    path: str | Path | None,
    *,
    trajectory: Trajectory | None = None,
    fallback_dir: Path | None = None,
    bus: BusSeries | None = None,
) -> dict[str, Any]:
    """``summary.json`` of the run logged in ``path`` (see the module doc).

    ``fallback_dir``: where to find the parts' ``*_stats.json`` if the log lacks
    their metadata records (a run whose merge failed).  ``bus``: the log's decoded
    channels if the caller has already read them (:func:`finalize` with a
    :class:`~tools.metrics.tracking.BusCollector`); otherwise ``path`` is read.
    ``path`` None: a run without a log (:mod:`tools.logs.collect`), whose ``bus`` and
    ``fallback_dir`` hold everything, and ``trajectory`` is given.
    """
    if bus is None:
        if path is None:
            raise ValueError("summarize needs a log or its decoded channels")
        bus = read_bus_log(path)
    if path is not None and (not bus.attachments or not bus.metadata):
        # damaged in the middle: reading through stopped there, but the summary section at
        # the end (metadata, attachments) may be intact

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tail = read_contents(path)
        for name, record in tail.metadata.items():
            bus.metadata.setdefault(name, record)
        for name, data in tail.attachments.items():
            bus.attachments.setdefault(name, data)
    md = bus.metadata
    fb = fallback_dir
    if trajectory is None:
        trajectory = recorded_trajectory(bus.attachments)
    cfg = recorded_config(md)
    run = dict(md.get("run", {}))
    bench = _stats(md["bench_stats"]) if "bench_stats" in md else _fallback(fb, "bench_stats")
    ctl = (
        _stats(md["controller_stats"])
        if "controller_stats" in md
        else _fallback(fb, "controller_stats")
    )
    rec = _stats(md["recorder"]) if "recorder" in md else _fallback(fb, "recorder_stats")
    m = summarize_bus(
        bus,
        trajectory,
        half_track_m=cfg.geometry.half_track_m,
        wheel_radius_m=cfg.geometry.wheel_radius_m,
        period_s=cfg.loop.period_s,
    )
    sim_s = float(bench.get("sim_time_s", math.nan))
    wall_s = float(bench.get("wall_s", math.nan))
    realtime = run.get("mode") == "realtime"
    summary: dict[str, Any] = {
        "controller": run.get("controller", ctl.get("controller")),
        "scenario": run.get("scenario"),
        "bus": run.get("bus"),
        "mode": run.get("mode"),
        "seed": int(run["seed"]) if run.get("seed", "").lstrip("-").isdigit() else run.get("seed"),
        "fault_setting": run.get("fault_setting"),
    }
    summary.update(m)
    summary.update(
        sim_duration_s=sim_s,
        wall_s=wall_s,
        real_time_factor=sim_s / wall_s if wall_s and wall_s == wall_s else math.nan,
        wall_total_s=float(run.get("wall_total_s", math.nan)),
        frames_total=_int_or_none(rec.get("frames", bench.get("frames_sent"))),
        recorder_missed_steps=int(rec.get("missed_steps", 0)),
        deadline_misses=(
            int(ctl["deadline_misses"]) if ctl.get("deadline_misses") is not None else None
        ),
        controller_step_us_p50=ctl.get("controller_step_us_p50"),
        controller_step_us_p99=ctl.get("controller_step_us_p99"),
        tick_us_p50=ctl.get("tick_us_p50"),
        tick_us_p99=ctl.get("tick_us_p99"),
        final_state=ctl.get("final_state"),
        stop_reason=ctl.get("stop_reason"),
        frames_rejected_by_controller=ctl.get("link_rejected", {}),
        frames_rejected_by_bench=bench.get("frames_rejected_by_reason", {}),
        missed_acks=bench.get("missed_acks"),
        controller_peak_rss_mb=ctl.get("peak_rss_mb"),
        # the estimate's largest per-tick step beyond odometry while tracking (m, rad)
        estimate_step_max_m=ctl.get("estimate_step_max_m"),
        estimate_step_max_rad=ctl.get("estimate_step_max_rad"),
        rate_limit_share=rate_limit_share(ctl.get("rate_limits")),
        law_activity_share=law_activity_share(ctl.get("law_activity"), ctl.get("tracking_ticks")),
        # the estimator's health: fixes fused and gated, its scale held, inputs refused
        estimator=ctl.get("estimator", {}),
    )
    if realtime:
        for k in (
            "lateness_us_p50",
            "lateness_us_p99",
            "lateness_us_p999",
            "lateness_us_max",
            "missed_ticks",
            "realtime_notes",
        ):
            if k in ctl:
                summary[k] = ctl[k]
    else:
        summary["lockstep_budget_us"] = lockstep_budget(bench, ctl)
    bits = rec.get("bits")
    bitrate = float(run.get("bitrate", 500_000))
    if bits and sim_s == sim_s and sim_s > 0:
        summary["bus_load_pct"] = 100.0 * bits / (sim_s * bitrate)

    summary["fault_diagnosis"] = diagnosis_metrics.diagnosis_summary(bus)
    return mark_completeness(summary, lost_from_stats(bench, ctl, rec))


def rate_limit_share(counts: Mapping[str, Any] | None) -> dict[str, float]:
    """Per limit of :data:`controller.limits.RATE_LIMITS`, the share of the tracking ticks
    whose law command was at it (the controller's ``rate_limits`` counts over their
    ``ticks``); NaN for each without a counted tick (a run that never tracked)."""
    counts = counts or {}
    ticks = _int_or_none(counts.get("ticks")) or 0
    return {
        k: (_int_or_none(counts.get(k)) or 0) / ticks if ticks > 0 else math.nan
        for k in RATE_LIMITS
    }


def law_activity_share(
    counts: Mapping[str, Any] | None, tracking_ticks: Any = None
) -> dict[str, float]:
    """Per event the law counts (its ``activity()``, the controller's ``law_activity``), the
    share of the law's steps it happened in: the count over the law's own ``ticks`` (else the
    controller's tracking ticks); ``ticks`` itself is the denominator, not an entry.  Empty
    for a law that counts nothing; NaN entries without a step."""
    counts = counts or {}
    ticks = _int_or_none(counts.get("ticks"))
    if ticks is None:
        ticks = _int_or_none(tracking_ticks) or 0
    return {
        str(k): (_int_or_none(v) or 0) / ticks if ticks > 0 else math.nan
        for k, v in counts.items()
        if k != "ticks"
    }


def lockstep_budget(bench: Mapping[str, Any], ctl: Mapping[str, Any]) -> dict[str, float]:
    """Where a lock-step bench step's wall time went, in us per step (mean).

    ``physics``: the bench integrating the chair and its drives' 1 kHz loops;
    ``controller_tick``: the controller's ticks (estimation, control law, its frames out);
    ``rest``: everything else (the bench's frames, receiving and decoding, the clocks,
    recording), the wall time less the two.  ``rtf_ceiling``: the real-time factor if
    ``rest`` cost nothing, i.e. the physics and the ticks alone.  NaN where the parts'
    statistics lack a figure.
    """
    steps = int(bench.get("steps") or 0)
    nan = math.nan
    if steps <= 0:
        return {"physics": nan, "controller_tick": nan, "rest": nan, "rtf_ceiling": nan}
    per = 1e6 / steps
    wall = float(bench.get("wall_s", nan)) * per
    physics = float(bench.get("physics_s", nan)) * per
    tick = float(ctl.get("tick_s_total", nan)) * per
    step_us = float(bench.get("sim_time_s", nan)) * per
    return {
        "physics": physics,
        "controller_tick": tick,
        "rest": wall - physics - tick,
        "rtf_ceiling": step_us / (physics + tick) if physics + tick > 0 else nan,
    }


def _fallback(out: Path | None, name: str) -> dict[str, Any]:
    return _read_json(out / f"{name}.json") if out is not None else {}


def _int_or_none(v: Any) -> int | None:
    try:
        return None if v is None else int(v)
    except (TypeError, ValueError):
        return None


def completeness(path: str | Path, summary: Mapping[str, Any], damage: list[str]) -> list[str]:
    """What a summary of the log at ``path`` is missing (empty: the log is whole).

    ``damage``: the log readers' own reports (``TruncatedLogWarning`` texts).  The log's
    records say what should be there: the recorder's frame count and end, the parts'
    statistics, the scenario and route attachments.
    """

    missing = list(damage)
    contents = read_contents(path)
    md = contents.metadata
    for name, what in (
        ("recorder", "the recorder's record (frame count, how it ended)"),
        ("controller_stats", "the controller's statistics (ticks, deadline misses, stop)"),
        ("bench_stats", "the bench's statistics (simulated time, acks)"),
        ("run", "the run's description (controller, scenario, bus, mode)"),
    ):
        if name not in md:
            missing.append(f"no {name} metadata: {what} unknown")
    atts = contents.attachments
    if not any(n.startswith("route/") for n in atts):
        missing.append("no route attachment")
    if not any(n.startswith("scenario/") for n in atts):
        missing.append("no scenario attachment")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        times = [t for t, _m in iter_frames(path)]
    recorded = _int_or_none(md.get("recorder", {}).get("frames"))
    if recorded is not None and len(times) < recorded:
        missing.append(f"{recorded - len(times)} of {recorded} recorded frames are not readable")
    ended = md.get("recorder", {}).get("ended_by")
    if ended is not None and "Bench_End" not in ended:
        missing.append(f"the recorder did not see the end of the run (ended by {ended})")
    sim_s = summary.get("sim_duration_s")
    if times and isinstance(sim_s, float) and sim_s == sim_s:
        span = (times[-1] - times[0]) / 1e9
        if summary.get("mode") != "realtime" and span < sim_s - 0.5:
            missing.append(f"frames cover {span:.1f} s of the {sim_s:.1f} s simulated")
    elif times:
        missing.append(
            f"frames cover {(times[-1] - times[0]) / 1e9:.1f} s; the simulated time is unknown"
        )
    else:
        missing.append("no frames")
    return missing


#: Summary keys computed from the log's frames: withheld (kept under ``partial``) when
#: a part lost frames, so that nobody reads a partial log's figures as a whole run's.
LOG_FIGURES = (
    "rmse_xe_m",
    "rmse_ye_m",
    "rmse_phie_rad",
    "rmse_pos_m",
    "max_pos_err_m",
    "max_phie_rad",
    "final_pos_err_m",
    "samples",
    "control_effort",
    "tv_v",
    "tv_omega",
    "chattering_hz",
    "wheel_speed_tracking_rms_revps",
    "fault_diagnosis",
    "bus_load_pct",
)


def lost_from_stats(
    bench: Mapping[str, Any], controller: Mapping[str, Any], recorder: Mapping[str, Any]
) -> dict[str, int]:
    """Frames each part lost, from its statistics (parts that lost none are left out)."""
    lost: dict[str, int] = {}
    for part, stats in (("sim", bench), ("control", controller), ("record", recorder)):
        n = int(stats.get("rx_dropped") or 0)
        if part == "record" and n == 0 and stats.get("missed_steps"):
            n = int(stats["missed_steps"])  # a gap in the steps with no kernel count
        if n:
            lost[part] = n
    return lost


def mark_completeness(summary: dict[str, Any], lost: dict[str, int]) -> dict[str, Any]:
    """``complete``/``lost_frames`` in ``summary``; a partial log's figures under ``partial``."""
    summary["complete"] = not lost
    summary["lost_frames"] = dict(lost)
    if lost:
        summary["partial"] = {k: summary[k] for k in LOG_FIGURES if k in summary}
        for k in LOG_FIGURES:
            if k in summary:
                summary[k] = None
    return summary


def loss_message(lost: dict[str, int]) -> str:
    parts = ", ".join(f"{part} lost {n} frames" for part, n in lost.items())
    return (
        f"incomplete run: {parts} (kernel receive-queue drops; see its *_stats.json "
        "rx_dropped); the tracking figures are withheld"
    )
