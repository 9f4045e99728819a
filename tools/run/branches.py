"""Lock-step experiments that are the same run until their first fault, run once up to there.

An evaluation's Monte-Carlo replicate runs one controller, with one draw of the conditions,
on every scenario of the paper's table: fault-free, the bumps and the flat tires all start
at the same moment of the same route, so up to that moment (a fifth of the route) the runs
are one and the same computation.  :func:`run_branches` makes it once: it runs the first
scenario (the trunk, without a log: :mod:`tools.logs.collect`) and, at the last bench step
before any branch's first fault, forks this process once per other scenario.  Each child
takes its scenario's faults (the bench's :meth:`~firmware_sim.faults.FaultManager.reschedule`,
and the controller's sensor faults, which act on nothing before their onset) and runs to the
end; the children run one after the other, the parent waiting, so the run keeps one core.

What a branch gives is what a fresh run of its scenario gives, figure for figure
(``tests/integration/test_branches.py``): before the fork nothing depends on the faults,
and a forked process is the same state.  That holds for scenarios that differ only in their
faults (route, seed, bench, initial pose, controller configuration but the sensor-fault
list, duration), whose first fault starts no sooner than two bench steps into the run, and
whose sensor-fault lists are all empty or all not (the odometry takes another, bit-different
path with them); :func:`branch_point` checks it and says why not.  Forking needs a process
with no other thread (a campaign's worker); elsewhere the branches run one by one, fresh.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import pickle
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dbc.codec import Codec
from firmware_sim.config import load_bench_config
from tools.bus.transport import resolve
from tools.run.in_process import run_threads
from tools.run.parts import controller_config
from tools.run.plan import RunPlan, make_plan
from tools.run.scenario import Scenario
from tools.run.summary import build_summary

if TYPE_CHECKING:
    from controller.node import ControllerNode
    from firmware_sim.bench import Bench
    from tools.logs.collect import FrameCollector

#: ``finish(i, summary, frames, started)``, run in branch ``i``'s own process (``started``:
#: the monotonic time its run began, the shared start counted, the other branches not): what
#: it returns (it must pickle) is that branch's outcome
Finish = Callable[[int, dict[str, Any], "FrameCollector", float], Any]

_channels = itertools.count()


@dataclasses.dataclass(frozen=True)
class BranchError:
    """A branch that failed: its exception as text (the outcome :func:`run_branches` gives)."""

    error: str
    traceback: str


def _first_fault_ns(plan: RunPlan) -> float:
    onsets = [f.onset_ns for f in plan.scenario.bench_faults]
    onsets += [round(f.onset_s * 1e9) for f in controller_config(plan).estimation.perceived_flats]
    return min(onsets, default=math.inf)


def branch_point(plans: Sequence[RunPlan], step_ns: int) -> tuple[int | None, str]:
    """The bench step at which ``plans`` part (simulation ns), or None and why they cannot
    share a trunk (see the module doc)."""
    if len(plans) < 2:
        return None, "one run"
    trunk = plans[0]
    cfg0 = controller_config(trunk)
    perceived0 = bool(cfg0.estimation.perceived_flats)
    for p in plans[1:]:
        if (p.controller, p.seed, p.duration_s, p.realtime) != (
            trunk.controller,
            trunk.seed,
            trunk.duration_s,
            trunk.realtime,
        ):
            return None, "runs of other controllers, seeds, durations or clocks"
        if p.chair_pose != trunk.chair_pose or p.start_pose != trunk.start_pose:
            return None, "another initial pose"
        a, b = p.scenario, trunk.scenario
        if (a.route, a.bench, a.gains, a.setting) != (b.route, b.bench, b.gains, b.setting):
            return None, "scenarios that differ beyond their faults"
        cfg = controller_config(p)
        if bool(cfg.estimation.perceived_flats) != perceived0:
            return None, "sensor faults in some runs only"
        if dataclasses.replace(
            cfg, estimation=dataclasses.replace(cfg.estimation, perceived_flats=())
        ) != dataclasses.replace(
            cfg0, estimation=dataclasses.replace(cfg0.estimation, perceived_flats=())
        ):
            return None, "another controller configuration"
    first = min(_first_fault_ns(p) for p in plans)
    if not math.isfinite(first):
        return None, "no fault in any run"
    steps = int(first // step_ns) - 2  # two whole steps before any fault can act
    if steps < 1:
        return None, "a fault from the start"
    return steps * step_ns, ""


def run_branches(
    scenarios: Sequence[Scenario],
    controller: str,
    scratch: Path,
    finish: Finish,
    *,
    seed: int | None = None,
    duration_s: float | None = None,
) -> list[Any]:
    """Run ``scenarios`` (lock-step, no log) with ``controller``, sharing their run up to
    their first fault where they may (:func:`branch_point`); ``finish(i, summary, frames)``
    turns branch ``i``'s summary and collected frames into its outcome, in its own process.
    Returns the outcomes in order; a branch that failed gives a :class:`BranchError`.

    ``scratch`` holds the parts' statistics files while each branch ends (one at a time).
    """
    plans = [
        make_plan(s, controller, realtime=False, duration_s=duration_s, seed=seed)
        for s in scenarios
    ]
    scratch.mkdir(parents=True, exist_ok=True)
    codec = Codec.default()
    step_ns = load_bench_config(plans[0].scenario.bench, source="branches").step_ns
    fork_ns, _why = branch_point(plans, step_ns)
    if fork_ns is None or threading.active_count() > 1:
        return [_run_one(plan, scratch, codec, finish, i) for i, plan in enumerate(plans)]
    outcomes: dict[int, Any] = {}
    branch = 0
    reply_fd = -1
    t0 = time.monotonic()

    def on_parts(bench: Bench, node: ControllerNode) -> None:
        def on_step(t_ns: int) -> None:
            nonlocal branch, reply_fd, t0
            if t_ns < fork_ns:
                return
            bench.on_step = None  # one fork point, in the parent and in every child
            for i in range(1, len(plans)):
                r, w = os.pipe()
                forked = time.monotonic()
                pid = os.fork()
                if pid == 0:  # branch i goes on from here with its own faults
                    os.close(r)
                    branch, reply_fd = i, w
                    bench.faults.reschedule(plans[i].scenario.bench_faults)
                    node.estimation.perceived.faults = tuple(
                        controller_config(plans[i]).estimation.perceived_flats
                    )
                    return
                os.close(w)
                outcomes[i] = _receive(r, pid)
                t0 += time.monotonic() - forked  # the parent's clock leaves out branch i

        bench.on_step = on_step

    spec = resolve("virtual", f"branches-{os.getpid()}-{next(_channels)}")
    outcome: Any = BranchError("the run ended without an outcome", "")
    try:
        results = run_threads(
            spec, plans[0], scratch, codec, recorder="none", collect=True, on_parts=on_parts
        )
        wall = time.monotonic() - t0
        summary = build_summary(scratch, plans[branch], spec, wall, results=results)
        outcome = finish(branch, summary, results["frames"], t0)
    except Exception as err:  # a failed branch is its outcome, never another branch's end
        outcome = BranchError(f"{type(err).__name__}: {err}", traceback.format_exc())
    finally:
        if branch:  # a child hands its outcome to the parent and ends here, whatever happened
            _send(reply_fd, outcome)
    outcomes[0] = outcome
    missing = [i for i in range(len(plans)) if i not in outcomes]
    for i in missing:  # the trunk failed before the fork: nothing was shared
        outcomes[i] = _run_one(plans[i], scratch, codec, finish, i)
    return [outcomes[i] for i in range(len(plans))]


def _run_one(plan: RunPlan, scratch: Path, codec: Codec, finish: Finish, i: int) -> Any:
    spec = resolve("virtual", f"branches-{os.getpid()}-{next(_channels)}")
    t0 = time.monotonic()
    try:
        results = run_threads(spec, plan, scratch, codec, recorder="none", collect=True)
        summary = build_summary(scratch, plan, spec, time.monotonic() - t0, results=results)
        return finish(i, summary, results["frames"], t0)
    except Exception as err:
        return BranchError(f"{type(err).__name__}: {err}", traceback.format_exc())


def _send(fd: int, outcome: Any) -> None:
    """In a child: write ``outcome`` to the parent and exit, whatever happens."""
    try:
        try:
            data = pickle.dumps(outcome)
        except Exception as err:
            data = pickle.dumps(BranchError(f"outcome does not pickle: {err}", ""))
        with os.fdopen(fd, "wb") as f:
            f.write(data)
    finally:
        os._exit(0)


def _receive(fd: int, pid: int) -> Any:
    """In the parent: the child's outcome (read to the end), once it has exited."""
    with os.fdopen(fd, "rb") as f:
        data = f.read()
    _, status = os.waitpid(pid, 0)
    if not data:
        return BranchError(f"branch process ended with status {status} and no outcome", "")
    return pickle.loads(data)
