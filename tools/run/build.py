"""The one place that builds a run's parts: the bench, and the controller's law, clock and node.

The parts of a run (:mod:`tools.run.parts`, in threads or processes), replay
(:mod:`tools.replay.verify`) and the safety suite (:mod:`tools.safety.runner`) all get
their :class:`~firmware_sim.bench.Bench` and :class:`~controller.node.ControllerNode` from
here.  Whoever needs a variation passes a hook (:class:`ControllerHooks`: a clock wrapper, a
law wrapper, a node class) or wraps the bus before handing it over, instead of wiring a
node of its own.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import can

from controller.clock import Clock, LockstepClock, RealtimeClock
from controller.config import ControllerConfig
from controller.telemetry import Telemetry
from controller.tracking import registry
from controller.types import Controller, Pose, Trajectory
from dbc.codec import Codec
from firmware_sim.bench import Bench
from firmware_sim.config import BenchConfig

if TYPE_CHECKING:
    from controller.node import ControllerNode
    from tools.run.plan import RunPlan


@dataclass(frozen=True)
class ControllerHooks:
    """How a caller varies the controller without rewiring it (all optional)."""

    #: wraps the loop's clock (a fault-injecting clock, the telemetry's tick hook)
    wrap_clock: Callable[[Clock], Clock] | None = None
    #: wraps the tracking law (a law that fails on purpose)
    wrap_law: Callable[[Controller], Controller] | None = None
    #: the node's class (a subclass that misbehaves on purpose); None: ControllerNode
    node_cls: type[ControllerNode] | None = None


def bench(
    bus: can.BusABC,
    cfg: BenchConfig,
    plan: RunPlan,
    *,
    codec: Codec | None = None,
    stop_event: threading.Event | None = None,
) -> Bench:
    """The bench of ``plan`` (its duration, clock, seed, chair pose and faults) on ``bus``."""
    pose = plan.chair_pose
    return Bench(
        bus,
        cfg,
        duration_s=plan.duration_s,
        realtime=plan.realtime,
        seed=plan.seed,
        codec=codec,
        stop_event=stop_event,
        initial_pose=(pose.x_m, pose.y_m, pose.heading_rad),
        faults=plan.scenario.bench_faults,
    )


def law(
    name: str,
    cfg: ControllerConfig,
    trajectory: Trajectory,
    *,
    overrides: Mapping[str, Any] | None = None,
) -> Controller:
    """Tracking controller ``name`` with its gains, for the deployment ``cfg`` believes in."""
    return registry.create(
        name,
        cfg.geometry,
        trajectory,
        overrides=overrides,
        motor=cfg.motor,
        body=cfg.body,
        limits=cfg.limits,
    )


def clock(
    bus: can.BusABC,
    cfg: ControllerConfig,
    *,
    realtime: bool,
    codec: Codec,
    stop_event: threading.Event | None = None,
    duration_s: float | None = None,
    rt_priority: int = 0,
    wait: bool = True,
    idle_timeout_s: float | None = None,
) -> Clock:
    """The loop's clock: the monotonic clock in real time, the bench's steps in lock-step.

    ``wait=False`` (lock-step only) is for a caller that drives the loop with
    :meth:`ControllerNode.poll`; ``idle_timeout_s`` defaults to the config's.
    """
    if realtime:
        return RealtimeClock(
            bus,
            round(cfg.loop.period_s * 1e9),
            stop_event=stop_event,
            duration_s=duration_s,
            realtime_priority=rt_priority,
        )
    return lockstep_clock(
        bus, cfg, codec=codec, stop_event=stop_event, wait=wait, idle_timeout_s=idle_timeout_s
    )


def lockstep_clock(
    bus: can.BusABC,
    cfg: ControllerConfig,
    *,
    codec: Codec,
    stop_event: threading.Event | None = None,
    wait: bool = True,
    idle_timeout_s: float | None = None,
) -> LockstepClock:
    """The lock-step clock: the loop ticks on the bench's ``Bench_Step`` frames."""
    timeout_s = cfg.loop.lockstep_idle_timeout_s if idle_timeout_s is None else idle_timeout_s
    return LockstepClock(
        bus,
        round(cfg.loop.period_s * 1e9),
        codec=codec,
        idle_timeout_s=timeout_s,
        # the first step may take longer (a bench starting in a slow guest)
        start_timeout_s=cfg.loop.lockstep_start_timeout_s if idle_timeout_s is None else timeout_s,
        stop_event=stop_event,
        wait=wait,
    )


def node(
    bus: can.BusABC,
    cfg: ControllerConfig,
    controller: Controller,
    trajectory: Trajectory,
    loop_clock: Clock,
    *,
    codec: Codec,
    start_pose: Pose,
    telemetry: Telemetry | None = None,
    stop_event: threading.Event | None = None,
    hooks: ControllerHooks | None = None,
) -> ControllerNode:
    """The controller's node: ``controller`` tracking ``trajectory`` on ``bus``, ticked by
    ``loop_clock``, with the caller's hooks applied."""
    hooks = hooks or ControllerHooks()
    if hooks.wrap_clock is not None:
        loop_clock = hooks.wrap_clock(loop_clock)
    if hooks.wrap_law is not None:
        controller = hooks.wrap_law(controller)
    if hooks.node_cls is None:
        # imported here: the bench and the recorder, which share this module, start without
        # the controller's estimator (filterpy, scipy.stats: about 0.7 s of start-up)
        from controller.node import ControllerNode  # lazy

        node_cls: type[ControllerNode] = ControllerNode
    else:
        node_cls = hooks.node_cls
    return node_cls(
        bus,
        cfg,
        controller,
        trajectory,
        loop_clock,
        codec=codec,
        telemetry=telemetry,
        start_pose=start_pose,
        stop_event=stop_event,
    )
