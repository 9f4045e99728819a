"""``summary.json`` recomputed from a run's log alone (``wheelchair-hil summarize``), with what
the log lacks: damage, missing records, lost frames (:func:`tools.logs.runlog.completeness`)."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

from controller.planner import plan
from tools.logs import runlog
from tools.logs.mcap_io import TruncatedLogWarning
from tools.replay import ReplayError
from tools.run import scenario as scenario_mod


def summarize_log(path: Path, scenario: str | None = None) -> dict[str, Any]:
    """The summary of the log ``path``; ``complete`` and ``missing`` say what it lacks.

    ``scenario`` (a name or a file) gives the route of a log whose scenario and route
    attachments were lost.
    """
    trajectory = None
    supplied = None
    if scenario:
        supplied = scenario_mod.load(scenario)
        trajectory = plan(supplied.route, source=str(supplied.route_path))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TruncatedLogWarning)
        try:
            summary = runlog.summarize(path, trajectory=trajectory)
        except runlog.RunLogError as err:
            raise ReplayError(f"{path}: {err}") from err
        damage = sorted(
            {str(w.message) for w in caught if issubclass(w.category, TruncatedLogWarning)}
        )
        missing = runlog.completeness(path, summary, damage)
    if supplied is not None:
        missing = [m for m in missing if m not in ("no route attachment", "no scenario attachment")]
        summary["route_from"] = f"{supplied.path} (given with --scenario)"
        if summary.get("scenario") is None:
            summary["scenario"] = supplied.name
    if summary.get("lost_frames"):
        missing.append(runlog.loss_message(summary["lost_frames"]))
    summary["complete"] = not missing
    summary["missing"] = missing
    return summary
