"""Where a lock-step step goes: its wall time split by component (``bench --case breakdown``).

One lock-step run of the paper route (:func:`tools.run.experiment.run_experiment`, the bench,
the controller and the recorder on the virtual bus, in one thread) with a timer around each
component's entry points.  Each timer counts its component's own time: a call it makes into
another timed component (the EKF calling nothing timed, the setpoint's send calling the
codec) is counted there, not twice.  What no timer covers is the loops' own code (the
node's tick outside its components, the bench's loop), given as "loop" of each side.

The side of a component (host, bench) is the loop it runs in: the host's tick runs inside the
bench's receive (a one-thread run drives the controller while the bench waits for its ack),
so a timer's side is that of the nearest enclosing loop.

Timers cost time themselves (about a quarter of a microsecond per call on the machines this
was written on): ``timer_overhead_us`` is that cost, measured, per step, and is part of the
step's total, not of a component.  The figures come with the run's own real-time factor
untimed (``step_us_untimed``), so what the timers added is in the table.

The physics and the drives' loops (``Sim.advance``) are compiled where the bench is
(:mod:`dbc.runtime.compiled`): they are timed by the bench itself (the summary's ``lockstep_budget_us``).
"""

from __future__ import annotations

import functools
import importlib
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from controller.tracking import registry
from tools.run.experiment import run_experiment

#: (component, module, class, methods): the entry points timed.  The loops are the first two.
COMPONENTS: tuple[tuple[str, str, str, tuple[str, ...]], ...] = (
    ("loop", "controller.node", "ControllerNode", ("_step",)),
    ("loop", "firmware_sim.bench", "Bench", ("_run",)),
    ("receive", "controller.link", "DriveLink", ("on_frame",)),
    ("receive", "tools.bus.transport", "LightVirtualBus", ("recv",)),
    ("decode", "dbc.codec", "Codec", ("decode",)),
    ("odometry", "controller.odometry", "Odometry", ("update",)),
    ("EKF", "controller.pose_ekf", "PoseEstimator", ("predict", "correct", "estimate")),
    ("fault bank", "controller.diagnosis", "FaultBank", ("predict", "correct", "diagnosis")),
    ("safety checks", "controller.safety", "SafetyMonitor", ("observe", "check")),
    ("safety checks", "controller.obedience", "ObedienceMonitor", ("check", "commanded")),
    ("reference", "controller.planner", "SplineTrajectory", ("sample",)),
    ("limits", "controller.limits", "CommandLimiter", ("apply",)),
    ("encode and MAC", "dbc.codec", "Codec", ("encode", "encode_secured")),
    ("send", "tools.bus.transport", "LightVirtualBus", ("send",)),
    ("telemetry", "controller.telemetry", "ForkedTelemetry", ("log",)),
    ("telemetry", "controller.telemetry", "McapTelemetry", ("log",)),
    ("recorder and metrics", "tools.logs.collect", "FrameCollector", ("take",)),
    ("recorder and metrics", "dbc.runtime.forked", "ForkedWriter", ("put",)),
    ("drives' frames", "firmware_sim.bench", "Bench", ("_on_message", "_publish")),
    ("ground truth", "firmware_sim.bench", "Bench", ("_publish_truth",)),
)

#: The side of a call made outside both loops (planning the route, summarising the run).
OUTSIDE = "outside the loop"

#: The side each loop's timer opens.
_SIDES = {"ControllerNode._step": "host", "Bench._run": "bench"}


class _Timers:
    """Own-time accumulators keyed by (side, component), and a stack of the open timers."""

    def __init__(self) -> None:
        self.own_ns: dict[tuple[str, str], int] = {}
        self.calls = 0
        # each open timer: (its side, [time of its children])
        self._stack: list[tuple[str, list[int]]] = []

    def wrap(self, fn: Callable[..., Any], component: str, side: str | None) -> Callable[..., Any]:
        stack, own, clock = self._stack, self.own_ns, time.perf_counter_ns

        @functools.wraps(fn)
        def timed(*args: Any, **kwargs: Any) -> Any:
            s = side or (stack[-1][0] if stack else OUTSIDE)
            children = [0]
            stack.append((s, children))
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                dt = clock() - t0
                stack.pop()
                key = (s, component)
                own[key] = own.get(key, 0) + dt - children[0]
                if stack:
                    stack[-1][1][0] += dt
                self.calls += 1

        return timed


@contextmanager
def _timed(timers: _Timers, law: type) -> Iterator[None]:
    """Install the timers on the classes (restored on exit)."""
    saved: list[tuple[type, str, Any]] = []
    targets = [(c, importlib.import_module(m), k, ms) for c, m, k, ms in COMPONENTS]
    try:
        for component, module, cls_name, methods in targets:
            cls = getattr(module, cls_name)
            for name in methods:
                fn = cls.__dict__[name]
                saved.append((cls, name, fn))
                setattr(cls, name, timers.wrap(fn, component, _SIDES.get(f"{cls_name}.{name}")))
        fn = law.__dict__["step"]
        saved.append((law, "step", fn))
        law.step = timers.wrap(fn, "law", None)  # type: ignore[attr-defined]
        yield
    finally:
        for cls, name, fn in reversed(saved):
            setattr(cls, name, fn)


def _timer_cost_ns(rounds: int = 20_000, repeats: int = 7) -> float:
    """What one timed call costs beyond the call itself (ns), measured here: the least of
    ``repeats`` differences, each over ``rounds`` calls (a loaded machine only adds)."""
    timers = _Timers()

    def nothing() -> None:
        return None

    timed = timers.wrap(nothing, "x", "host")
    costs = []
    for _ in range(repeats):
        per_call = []
        for f in (nothing, timed):
            t0 = time.perf_counter_ns()
            for _ in range(rounds):
                f()
            per_call.append((time.perf_counter_ns() - t0) / rounds)
        costs.append(per_call[1] - per_call[0])
    return max(0.0, min(costs))


def breakdown(controller: str, scenario: str, work: Path | None = None) -> dict[str, Any]:
    """One timed lock-step run of ``scenario`` with ``controller``; figures per step (us)."""
    law = registry.controller_class(controller)
    with tempfile.TemporaryDirectory(prefix="whil-breakdown-") as tmp:
        root = Path(work or tmp)
        plain = run_experiment(root / "untimed", scenario, controller)
        timers = _Timers()
        with _timed(timers, law):
            t0 = time.perf_counter_ns()
            summary = run_experiment(root / "timed", scenario, controller)
            wall_ns = time.perf_counter_ns() - t0
    steps = max(1, round(summary["sim_duration_s"] / 0.01))
    budget = summary.get("lockstep_budget_us") or {}
    physics_ns = float(budget.get("physics") or 0.0) * 1e3 * steps
    own = dict(timers.own_ns)
    # the physics is inside the bench loop's own time: take it out of the loop
    if physics_ns:
        own[("bench", "loop")] = own.get(("bench", "loop"), 0) - physics_ns
        own[("bench", "physics and drive loops")] = physics_ns
    loop_ns = sum(v for (s, _), v in own.items() if s != OUTSIDE)
    overhead_ns = _timer_cost_ns() * timers.calls
    rows = sorted(
        (
            {"side": s, "component": c, "us_per_step": v / steps / 1e3}
            for (s, c), v in own.items()
            if s != OUTSIDE
        ),
        key=lambda r: -r["us_per_step"],
    )
    return {
        "controller": controller,
        "scenario": scenario,
        "steps": steps,
        "components": rows,
        "step_us_timed_loop": loop_ns / steps / 1e3,
        "timer_overhead_us": overhead_ns / steps / 1e3,
        "after_run_us": (wall_ns - loop_ns) / steps / 1e3,
        "step_us_untimed": plain["wall_s"] * 1e6 / max(1, round(plain["sim_duration_s"] / 0.01)),
        "rtf_untimed": plain["real_time_factor"],
    }


def format_breakdown(results: list[dict[str, Any]]) -> str:
    """One table: a row per (side, component), a column per controller (us per step)."""
    names = [r["controller"] for r in results]
    keys: list[tuple[str, str]] = []
    for r in results:
        for row in r["components"]:
            k = (row["side"], row["component"])
            if k not in keys:
                keys.append(k)
    value = {
        (r["controller"], row["side"], row["component"]): row["us_per_step"]
        for r in results
        for row in r["components"]
    }
    lines = [
        "| side | component | " + " | ".join(f"{n} (us/step)" for n in names) + " |",
        "|---|---|" + "---|" * len(names),
    ]
    for side, comp in keys:
        cells = " | ".join(f"{value.get((n, side, comp), 0.0):.1f}" for n in names)
        lines.append(f"| {side} | {comp} | {cells} |")

    def total(label: str, key: str, fmt: str = ".1f") -> str:
        return f"| | {label} | " + " | ".join(format(r[key], fmt) for r in results) + " |"

    lines.append(total("of which the timers' own cost (estimated)", "timer_overhead_us"))
    lines.append(total("**step, timed (sum of the rows)**", "step_us_timed_loop"))
    lines.append(total("step, untimed run (wall / steps)", "step_us_untimed"))
    lines.append(total("real-time factor, untimed run", "rtf_untimed"))
    lines.append(total("after the run (log merge, summary), per step", "after_run_us"))
    return "\n".join(lines)
