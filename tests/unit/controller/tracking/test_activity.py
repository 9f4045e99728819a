"""The optional ``activity()`` of the tracking laws (controller.types.Controller): counts of the
law's own events since its last ``reset()``, ``ticks`` the steps counted; and what each law
we ship counts."""

from __future__ import annotations

import math
from collections.abc import Mapping

import pytest

from controller.config import GeometryParams, LimitParams
from controller.tracking import registry
from controller.tracking.adaptive import AdaptiveMPC
from controller.tracking.resilient import ACTIVITY_KEYS, ResilientTSK
from controller.types import Controller, ReferenceSample, StateEstimate, Trajectory

GEOM = GeometryParams()
DT = 0.01


def _on_route(law: Controller, traj: Trajectory, steps: int) -> None:
    """``steps`` steps of ``law`` with the chair on the reference, from its start."""
    s0 = traj.sample(0.0)
    law.reset(StateEstimate(0.0, s0.x_m, s0.y_m, s0.heading_rad, 0.0, 0.0), 0.0)
    for k in range(steps):
        r = traj.sample(k * DT)
        law.step(k * DT, DT, r, StateEstimate(r.t_s, r.x_m, r.y_m, r.heading_rad, r.v_mps, 0.0))


#: The laws that count activity (BASELINE has none: test_the_baseline_switches_nothing...).
COUNTING = [n for n in registry.names() if registry.canonical(n) != "baseline"]


@pytest.mark.parametrize("name", COUNTING)
def test_a_laws_activity_counts_its_steps_in_ints_and_a_reset_clears_it(
    name: str, short: Trajectory
) -> None:
    law = registry.create(name, GEOM, short)
    activity = law.activity  # type: ignore[attr-defined]
    _on_route(law, short, 50)
    counts: Mapping[str, int] = activity()
    assert counts and all(isinstance(k, str) for k in counts)
    assert all(isinstance(v, int) and 0 <= v <= 50 for v in counts.values()), counts
    assert counts.get("ticks", 50) == 50
    law.reset(StateEstimate(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), 0.0)
    assert set(activity().values()) == {0}


def test_the_baseline_switches_nothing_and_counts_nothing(short: Trajectory) -> None:
    """Nothing in it switches, and its steps are the node's tracking ticks: it has no
    ``activity()`` (and its step allocates nothing, tools/perf)."""
    assert getattr(registry.create("baseline", GEOM, short), "activity", None) is None


def _rest(*, done: bool = False) -> ReferenceSample:
    return ReferenceSample(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, done=done)


def _at(x: float, y: float, heading: float) -> StateEstimate:
    return StateEstimate(0.0, x, y, heading, 0.0, 0.0)


def test_resilient_counts_the_dominant_rule_the_wheel_limit_and_parking() -> None:
    p = ResilientTSK.Params(d_near_m=0.1, d_far_m=0.5, theta_small_rad=0.1, theta_large_rad=0.5)
    tsk = ResilientTSK(p, GEOM, None, limits=LimitParams(wheel_max_radps=50.0))  # type: ignore[arg-type]
    tsk.step(0.0, DT, _rest(), _at(-0.05, 0.0, 0.0))  # near, small (carrot straight ahead)
    tsk.step(0.0, DT, _rest(), _at(-2.0, 0.0, 0.0))  # far, small
    tsk.step(0.0, DT, _rest(), _at(-2.0, 0.0, 1.5))  # far, large
    tsk.step(0.0, DT, _rest(), _at(-2.0, 0.0, 1.5))
    tsk.step(0.0, DT, _rest(done=True), _at(0.0, 0.01, 0.0))  # parked
    counts = tsk.activity()
    assert list(counts) == list(ACTIVITY_KEYS)
    assert counts["ticks"] == 5 and counts["parked"] == 1
    assert counts["rule_near_small"] == 1 and counts["rule_far_small"] == 1
    assert counts["rule_far_large"] == 2 and counts["rule_near_large"] == 0
    assert counts["wheel_limit"] == 0
    rim_limited = ResilientTSK(p, GEOM, None, limits=LimitParams(wheel_max_radps=1.0))  # type: ignore[arg-type]
    rim_limited.step(0.0, DT, _rest(), _at(-2.0, 0.0, 0.3))
    assert rim_limited.activity()["wheel_limit"] == 1


def test_adaptive_counts_its_solves_its_fallbacks_and_parking(short: Trajectory) -> None:
    law = registry.create("adaptive", GEOM, short)
    assert isinstance(law, AdaptiveMPC)
    _on_route(law, short, 20)
    blind = StateEstimate(0.2, math.nan, 0.0, 0.0, 0.0, 0.0, valid=False)
    law.step(0.2, DT, short.sample(0.2), blind)  # no estimate: the previous plan
    counts = law.activity()
    assert counts["ticks"] == 21 and counts["qp_fallback"] == 1
    assert counts["qp_solved"] == 20 and counts["qp_max_iter"] == 0
    assert counts["parked"] == 0 and counts["qp_cold_start"] == 0
    end = short.sample(short.duration_s + 1.0)
    law.step(end.t_s, DT, end, StateEstimate(end.t_s, end.x_m, end.y_m, end.heading_rad, 0, 0))
    assert law.activity()["parked"] == 1 and law.activity()["ticks"] == 22


def test_adaptive_counts_a_solve_stopped_at_max_iter(short: Trajectory) -> None:
    law = registry.create(
        "adaptive", GEOM, short, overrides={"max_iter": 10, "eps_abs": 1e-9, "eps_rel": 1e-9}
    )
    assert isinstance(law, AdaptiveMPC)
    s0 = short.sample(0.0)
    law.reset(StateEstimate(0.0, s0.x_m, s0.y_m, s0.heading_rad, 0.0, 0.0), 0.0)
    law.step(0.0, DT, s0, StateEstimate(0.0, s0.x_m, s0.y_m + 0.3, s0.heading_rad + 0.3, 0, 0))
    counts = law.activity()
    assert counts["qp_max_iter"] == 1 and counts["qp_fallback"] == 1
