"""A run's three parts as separate OS processes on one bus (``run`` over udp_multicast or
socketcan): their command lines (``sim``, ``control``, ``record`` with the plan's scenario,
duration and seed; the bench and the controller also get the route as planned here, saved,
which they load instead of planning it again), started and watched by
:class:`tools.run.processes.Parts`.

For udp_multicast outside a private network namespace ``run`` has re-executed itself inside
one (``unshare -rn``) before it comes here (:mod:`tools.cli.run`).
"""

from __future__ import annotations

import tempfile
import threading
from pathlib import Path
from typing import Any

from controller.planner import SplineTrajectory, save_plan
from tools.bus import transport
from tools.bus.rxloss import LOSS_EXIT
from tools.bus.transport import BusSpec
from tools.live.server import LiveServer
from tools.run.parts import RECORDER_WINDOW_STEPS
from tools.run.plan import RunPlan
from tools.run.processes import Part, Parts


def run_processes(
    spec: BusSpec,
    plan_: RunPlan,
    out: Path,
    dbc: str | None,
    rt_priority: int = 0,
    live: LiveServer | None = None,
    stop_event: threading.Event | None = None,
) -> dict[str, Any]:
    """The three parts as separate OS processes on ``spec`` (``live``: the recorder and the
    controller feed this live view), started and watched by :class:`~tools.run.processes.Parts`.
    ``stop_event`` set (a stop signal to ``run``): each part is sent SIGTERM and ends with its
    own status."""
    logs = out / "logs"
    logs.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="wheelchair-hil-plan-") as tmp:
        # the route planned once, here: the bench and the controller load it (--plan)
        # instead of importing scipy's interpolation and planning it again each
        planned: list[str] = []
        if isinstance(plan_.trajectory, SplineTrajectory):
            saved = Path(tmp) / "plan.npz"
            save_plan(plan_.trajectory, saved)
            planned = ["--plan", str(saved)]
        return _run_parts(spec, plan_, out, logs, dbc, planned, rt_priority, live, stop_event)


def _run_parts(
    spec: BusSpec,
    plan_: RunPlan,
    out: Path,
    logs: Path,
    dbc: str | None,
    planned: list[str],
    rt_priority: int,
    live: LiveServer | None,
    stop_event: threading.Event | None,
) -> dict[str, Any]:
    common = [
        *transport.bus_argv(spec),
        "--scenario",
        str(plan_.scenario.path),
        "--duration",
        repr(plan_.duration_s),
        "--seed",
        str(plan_.seed),
        "--ready",
    ]
    if plan_.realtime:
        common.append("--realtime")
    if dbc:
        common += ["--dbc", dbc]
    feed = ["--live-feed", live.socket_path] if live else []
    control_extra = ["--rt-priority", str(rt_priority)] if rt_priority else []
    # the bench stands in for the drives' own hardware: one priority above the host's
    sim_extra = ["--rt-priority", str(min(rt_priority + 1, 99))] if rt_priority else []
    # the recorder one priority below the host: the loops first, but no starved black box
    record_extra = ["--rt-priority", str(max(rt_priority - 1, 1))] if rt_priority else []
    record = transport.python_argv(
        "record", *common, *record_extra, *feed, "--out", str(out / "run.mcap")
    )
    control = transport.python_argv(
        "control",
        *common,
        *planned,
        *control_extra,
        *feed,
        "--controller",
        plan_.controller,
        "--out",
        str(out),
    )
    sim = transport.python_argv(
        "sim",
        *common,
        *planned,
        *sim_extra,
        "--out",
        str(out),
        "--recorder-window",
        str(RECORDER_WINDOW_STEPS),
    )
    with Parts() as parts:
        parts.start(Part("record", tuple(record), str(logs / "record.log")))
        parts.start(Part("control", tuple(control), str(logs / "control.log")))
        parts.start(Part("sim", tuple(sim), str(logs / "sim.log"), ready=False))
        timeout = plan_.duration_s * (1.5 if plan_.realtime else 3.0) + 60.0
        # a part that lost frames ends with LOSS_EXIT after a whole run: the summary says so
        parts.wait(timeout, ok=(0, LOSS_EXIT), stop_event=stop_event)
    return {}
