"""The plan of a run: what its three parts (bench, controller, recorder) agree on, derived once
from the scenario (:func:`make_plan`), and the planned trajectory it tracks (:func:`planned`).

Every way of running the parts takes a :class:`RunPlan`: in this process
(:mod:`tools.run.in_process`), as OS processes (:mod:`tools.run.cross_process`), one part per
command (``sim``, ``control``, ``record``: :mod:`tools.run.parts`) and one experiment as a
function (:mod:`tools.run.experiment`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

from controller.planner import RouteParams, SplineTrajectory, plan
from controller.tracking import registry
from controller.types import Pose, Trajectory
from dbc.runtime.errors import ConfigError
from tools.run.scenario import Scenario, check_seed

#: Simulated time the controller is given to arm before its route starts (s).
ARMING_ALLOWANCE_S = 1.0


@dataclass(frozen=True)
class RunPlan:
    """Everything the three parts need to agree on, derived once from the scenario."""

    scenario: Scenario
    controller: str
    trajectory: Trajectory
    start_pose: Pose  # where the controller believes the chair starts (route start)
    chair_pose: Pose  # where the bench puts the chair
    duration_s: float
    seed: int
    realtime: bool


@functools.lru_cache(maxsize=16)
def planned(route: RouteParams, source: str) -> SplineTrajectory:
    """:func:`controller.planner.plan` of ``route``, once per process for equal routes
    (a trajectory is immutable; planning the paper route takes about 0.2 s)."""
    return plan(route, source=source)


def make_plan(
    scenario: Scenario,
    controller: str | None,
    *,
    realtime: bool,
    duration_s: float | None = None,
    seed: int | None = None,
    trajectory: SplineTrajectory | None = None,
) -> RunPlan:
    """The plan of ``scenario``; ``trajectory``: its route's trajectory, planned already (a
    saved plan, :func:`controller.planner.load_plan`), instead of planning it here."""
    try:
        name = registry.canonical(controller or scenario.params.controller)
        registry.controller_class(name)  # fail early on a controller that cannot be imported
    except ConfigError as err:
        where = "--controller" if controller else f"{scenario.path}: scenario.controller"
        raise ConfigError(f"{where}: {err}") from None
    if seed is not None:
        check_seed(seed)
    traj = trajectory or planned(scenario.route, str(scenario.route_path))
    s0 = traj.sample(0.0)
    start = Pose(s0.x_m, s0.y_m, s0.heading_rad)
    along, left, dphi = scenario.params.initial_offset
    c, s = math.cos(start.heading_rad), math.sin(start.heading_rad)
    chair = Pose(
        start.x_m + c * along - s * left, start.y_m + s * along + c * left, start.heading_rad + dphi
    )
    if duration_s is None:
        duration_s = scenario.params.duration_s or (
            ARMING_ALLOWANCE_S + traj.duration_s + scenario.params.tail_s
        )
    return RunPlan(
        scenario,
        name,
        traj,
        start,
        chair,
        duration_s,
        scenario.params.seed if seed is None else seed,
        realtime,
    )
