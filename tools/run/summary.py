"""A run's summary: its ``run`` metadata record (:func:`run_info`), the log finalized and the
summary computed from it or from the frames kept in memory (:func:`build_summary`), the
frames the parts lost (:func:`lost_frames`) and the summary as text (:func:`format_summary`,
what ``run``, ``summarize`` and ``replay`` print).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from tools.bus.transport import BusSpec
from tools.logs import mcap_io, runlog
from tools.logs.collect import FrameCollector
from tools.logs.runlog import loss_message, lost_from_stats
from tools.metrics.tracking import BusCollector
from tools.run.plan import RunPlan


def run_info(plan_: RunPlan, spec: BusSpec) -> dict[str, str]:
    """The run's ``run`` metadata record: controller, scenario, bus, mode, seed, duration."""
    return {
        "controller": plan_.controller,
        "scenario": plan_.scenario.name,
        "bus": spec.describe(),
        "mode": "realtime" if plan_.realtime else "lockstep",
        "seed": str(plan_.seed),
        "duration_s": f"{plan_.duration_s:.3f}",
        "fault_setting": plan_.scenario.setting,
    }


def lost_frames(out: Path) -> dict[str, int]:
    """Frames each part lost, from its statistics in ``out`` (parts that lost none are left out)."""
    stats = {}
    for name in ("bench_stats.json", "controller_stats.json", "recorder_stats.json"):
        try:
            stats[name] = json.loads((out / name).read_text())
        except (OSError, ValueError):
            stats[name] = {}
    return lost_from_stats(
        stats["bench_stats.json"], stats["controller_stats.json"], stats["recorder_stats.json"]
    )


def build_summary(
    out: Path,
    plan_: RunPlan,
    spec: BusSpec,
    wall_total_s: float,
    collector: BusCollector | None = None,
    results: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Finalize the run's log (``tools.logs.runlog.finalize``) and compute the summary from it.

    The log is read once, while it is merged; ``collector`` (give one to collect more
    topics, e.g. the controller's) holds what was read afterwards.  A run whose frames were
    collected in this process (:func:`run_threads`'s ``collect``: pass its ``results``) is
    summarized from them and the parts' statistics, by the same code; its log, if it has
    one, is still merged, and ``collector`` then sees only what the merge writes.
    """
    frames: FrameCollector | None = (results or {}).get("frames")
    if frames is None and collector is not None and collector.wanted is not None:
        raise ValueError("build_summary needs a BusCollector of every /can/ channel (names=None)")
    info = {
        **run_info(plan_, spec),
        "bitrate": str(spec.bitrate),
        "wall_total_s": repr(wall_total_s),
    }
    if frames is not None:
        # a run without a log (recorder "none") leaves alone any run.mcap an earlier run
        # wrote into ``out``: finalizing it would stamp that log with this run's metadata
        if (results or {}).get("logged", True) and (out / "run.mcap").exists():
            runlog.finalize(out, info, on_message=collector)
        md = {
            "run": info,
            "recorder": frames.metadata(),
            "controller_config": dict((results or {}).get("control_config") or {}),
        }
        bus = frames.series.series(md, {})
        summary = runlog.summarize(None, trajectory=plan_.trajectory, fallback_dir=out, bus=bus)
    else:
        collector = BusCollector() if collector is None else collector
        contents = runlog.finalize(out, info, on_message=collector)
        if contents is None:  # not merged: read what the recorder wrote
            collector.clear()
            contents = mcap_io.scan(out / "run.mcap", collector)
        bus = collector.series(contents.metadata, contents.attachments)
        summary = runlog.summarize(
            out / "run.mcap", trajectory=plan_.trajectory, fallback_dir=out, bus=bus
        )
    # what the launcher knows first-hand wins over the log (e.g. a log whose merge failed)
    summary.update(
        controller=plan_.controller,
        scenario=plan_.scenario.name,
        bus=spec.describe(),
        mode="realtime" if plan_.realtime else "lockstep",
        seed=plan_.seed,
        fault_setting=plan_.scenario.setting,
        wall_total_s=wall_total_s,
    )
    return summary  # runlog.summarize marked it complete or not, from the parts' statistics


def format_summary(s: dict[str, Any]) -> str:
    """The summary as the lines ``run``, ``summarize`` and ``replay`` print."""

    def f(key: str, scale: float = 1.0, unit: str = "", fmt: str = ".4f") -> str:
        v = s.get(key)
        return "n/a" if v is None or v != v else f"{v * scale:{fmt}}{unit}"

    if s.get("complete") is False and s.get("lost_frames"):
        return "\n".join(
            [
                f"{s['controller']} on {s['scenario']} ({s['mode']}, {s['bus']}): INCOMPLETE",
                f"  {loss_message(s.get('lost_frames') or {})}",
                f"  {s.get('frames_total')} frames recorded; stop: {s.get('stop_reason')}; "
                "figures of the partial log are under 'partial' in summary.json",
            ]
        )

    def t(key: str) -> str:
        v = s.get(key)
        return "n/a" if v is None or v == "" else str(v)

    lines = [
        f"{t('controller')} on {t('scenario')} ({t('mode')}, {t('bus')})",
        f"  position RMSE {f('rmse_pos_m', 100, ' cm', '.2f')}, max {f('max_pos_err_m', 100, ' cm', '.2f')}; "
        f"heading RMSE {f('rmse_phie_rad', 57.29578, ' deg', '.2f')}, max {f('max_phie_rad', 57.29578, ' deg', '.2f')}",
        f"  x_e RMSE {f('rmse_xe_m', 1, ' m')}, y_e RMSE {f('rmse_ye_m', 1, ' m')}, phi_e RMSE {f('rmse_phie_rad', 1, ' rad')}",
        f"  {f('sim_duration_s', 1, ' s', '.1f')} simulated in {f('wall_s', 1, ' s', '.2f')} "
        f"({f('real_time_factor', 1, 'x', '.1f')} real time); {t('frames_total')} frames; "
        f"{t('deadline_misses')} deadline misses; stop: {t('stop_reason')}",
    ]
    for gap in s.get("missing") or []:
        lines.append(f"  MISSING: {gap}")
    b = s.get("lockstep_budget_us")
    if isinstance(b, dict) and all(v == v for v in b.values()):
        lines.append(
            f"  per step: physics {b['physics']:.0f} us, controller tick {b['controller_tick']:.0f} us, "
            f"the rest {b['rest']:.0f} us (physics and ticks alone: {b['rtf_ceiling']:.1f}x)"
        )
    return "\n".join(lines)
