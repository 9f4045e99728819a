"""What-if: another controller on a recorded run (``replay --controller NAME``).

Open loop (:func:`open_loop`): NAME's response to the same recorded inputs, offline
(:func:`tools.replay.verify.replay_offline`), its frames and internals kept in one MCAP and
its setpoints set against the recorded ones (:func:`setpoint_difference`).  Closed loop
(:func:`closed_loop`): the recorded scenario, rebuilt from the log's attachments
(:func:`scenario_from_log`), re-run with NAME on the virtual bus.
"""

from __future__ import annotations

import math
import tempfile
import time
import tomllib
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from controller.planner import load_route
from dbc.codec import Codec
from dbc.runtime import jsonsafe, params
from tools.bus.transport import resolve
from tools.logs import mcap_io
from tools.logs.mcap_io import merge_into
from tools.replay import ReplayError
from tools.replay.verify import OfflineResult, replay_offline
from tools.run import in_process
from tools.run.plan import make_plan
from tools.run.scenario import Scenario, ScenarioParams
from tools.run.summary import build_summary


def open_loop(path: Path, controller: str, out: Path) -> tuple[OfflineResult, Path]:
    """``controller``'s response to the recorded inputs of ``path``; its frames and internals
    in one MCAP in ``out`` (whose path is returned with the result)."""
    frames = out / f"open-loop-{controller}.mcap"
    internals = out / f"open-loop-{controller}-controller.mcap"
    res = replay_offline(path, controller, telemetry_path=internals, frames_path=frames)

    merge_into(frames, [internals])
    internals.unlink()
    return res, frames


def setpoint_difference(rows: Sequence[tuple[int, float, float]]) -> tuple[float, float]:
    """RMS and largest absolute difference (rev/s) of one wheel's replayed setpoints from the
    recorded ones (:attr:`OfflineResult.setpoints` rows); NaN without rows."""
    d = [b - a for _t, a, b in rows]
    rms = math.sqrt(sum(x * x for x in d) / len(d)) if d else math.nan
    big = max((abs(x) for x in d), default=math.nan)
    return rms, big


def scenario_from_log(contents: Any) -> Any:
    """The recorded scenario, rebuilt from the log's scenario and route attachments."""

    atts = contents.attachments
    scen_names = [n for n in atts if n.startswith("scenario/")]
    route_names = [n for n in atts if n.startswith("route/")]
    if not scen_names or not route_names:
        raise ReplayError("the log has no scenario/route attachments; cannot re-run it")
    tmp = Path(tempfile.mkdtemp(prefix="wheelchair-replay-"))
    scen_path = tmp / Path(scen_names[0]).name
    route_path = tmp / Path(route_names[0]).name
    scen_path.write_bytes(atts[scen_names[0]])
    route_path.write_bytes(atts[route_names[0]])
    table = tomllib.loads(scen_path.read_text())
    sp = params.load(
        ScenarioParams, table.get("scenario", {}), source=str(scen_path), prefix="scenario"
    )
    return Scenario(
        scen_path,
        sp,
        load_route(route_path),
        route_path,
        table.get("bench", {}),
        table.get("faults", []),
    )


def closed_loop(path: Path, controller: str, out: Path) -> dict[str, Any]:
    """Re-run the recorded scenario with ``controller`` (lock-step, virtual bus)."""

    contents = mcap_io.read_contents(path)
    run = contents.metadata.get("run", {})
    scen = scenario_from_log(contents)
    duration = float(run["duration_s"]) if "duration_s" in run else None
    seed = int(run["seed"]) if run.get("seed", "").isdigit() else None
    plan_ = make_plan(scen, controller, realtime=False, duration_s=duration, seed=seed)
    spec = resolve("virtual", f"whatif-{uuid.uuid4()}")
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    in_process.run_threads(spec, plan_, out, Codec.default())
    summary = build_summary(out, plan_, spec, time.monotonic() - t0)
    (out / "summary.json").write_text(jsonsafe.dumps(summary, indent=2, default=str) + "\n")
    return summary
