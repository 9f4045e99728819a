"""How often a law's command sits at a limit of the envelope (controller.limits.RateLimitMeter),
counted by the node on the twist the law returns, and the law's own ``activity()`` counts,
read once at the end of a run.  Synthetic time: the node's ticks are called directly."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import pytest

from controller.config import load_config
from controller.limits import RATE_LIMITS, RateLimitMeter
from controller.node import ControllerNode
from controller.planner import plan
from controller.tracking import registry
from controller.types import ReferenceSample, StateEstimate, TwistCommand
from dbc.codec import HostState
from tests.unit.idle_clock import IdleClock
from tools.bus.transport import open_bus, resolve
from tools.run import scenario as scenario_mod

CFG = load_config()
LIM = CFG.limits
DT = CFG.loop.period_s
_chan = itertools.count()


class _Law:
    """A law that commands ``command(k)`` at its k-th step (from 1) and counts its steps."""

    name = "fake"
    drive_gains = None

    def __init__(self, command: Callable[[int], tuple[float, float]]) -> None:
        self.command = command
        self.k = 0

    def reset(self, estimate: StateEstimate, t_s: float) -> None:
        self.k = 0

    def step(
        self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate
    ) -> TwistCommand:
        self.k += 1
        return TwistCommand(*self.command(self.k))

    def internals(self) -> Mapping[str, float]:
        return {}

    def activity(self) -> Mapping[str, int]:
        return {"ticks": self.k, "odd": (self.k + 1) // 2}


def _track(law: Any, ticks: int) -> ControllerNode:
    """``law`` tracking the ``short`` route for ``ticks`` ticks, its estimate on the
    reference; then the run's end."""
    spec = resolve("virtual", f"rate-limits-{next(_chan)}")
    bus = open_bus(spec)
    traj = plan(scenario_mod.load("short").route)
    node = ControllerNode(
        bus, CFG, registry.create("baseline", CFG.geometry, traj), traj, IdleClock()
    )
    try:
        node.controller = law
        node._start_tracking(0)
        now = [0]

        def on_reference() -> StateEstimate:
            r = traj.sample(now[0] * 1e-9)
            return StateEstimate(r.t_s, r.x_m, r.y_m, r.heading_rad, r.v_mps, r.omega_radps)

        node.estimation.estimate = on_reference  # type: ignore[method-assign]
        for k in range(1, ticks + 1):
            now[0] = k * node.period_ns
            node._track(now[0])
        assert node.state == HostState.TRACKING
        node.end()
    finally:
        bus.shutdown()
    return node


def test_a_law_that_ramps_at_the_acceleration_limit_is_at_it_every_tick() -> None:
    a = LIM.accel_max_mps2
    node = _track(_Law(lambda k: (a * DT * k, 0.0)), 100)
    counts = node.stats.rate_limits
    assert counts["ticks"] == node.stats.tracking_ticks == 100
    assert counts["accel"] == 100
    # from rest the first tick starts the ramp: its one change of acceleration
    assert counts["jerk"] == 1
    assert counts["turn_accel"] == counts["speed"] == counts["turn_rate"] == 0


def test_a_gentle_law_is_at_no_limit() -> None:
    a, alpha = LIM.accel_max_mps2, LIM.alpha_max_radps2
    node = _track(_Law(lambda k: (0.1 * a * DT * k, 0.2 * alpha * DT * k)), 100)
    assert node.stats.rate_limits == {"ticks": 100, **dict.fromkeys(RATE_LIMITS, 0)}


def test_the_law_is_measured_before_the_limiter_clips_it() -> None:
    """A law that jumps beyond the envelope is at its limits every tick it does so, though
    the node's limiter sends a command within them."""
    w = LIM.omega_max_radps
    node = _track(_Law(lambda k: (2.0 * LIM.v_max_mps, 2.0 * w * (-1) ** k)), 50)
    counts = node.stats.rate_limits
    assert counts["speed"] == counts["turn_rate"] == counts["turn_accel"] == 50
    assert counts["accel"] == 1  # one jump from rest, then a constant speed
    assert abs(node.limiter.omega_radps) <= w and node.limiter.v_mps <= LIM.v_max_mps


def test_the_node_reads_the_laws_activity_once_at_the_end() -> None:
    node = _track(_Law(lambda k: (0.0, 0.0)), 7)
    assert node.stats.law_activity == {"ticks": 7, "odd": 4}


def test_a_law_without_activity_or_whose_activity_fails_reports_none() -> None:
    class _Plain(_Law):
        activity = None  # type: ignore[assignment]

    class _Broken(_Law):
        def activity(self) -> Mapping[str, int]:
            raise RuntimeError("boom")

    for law in (_Plain(lambda k: (0.0, 0.0)), _Broken(lambda k: (0.0, 0.0))):
        node = _track(law, 3)
        assert node.stats.law_activity == {}
        assert node.stats.rate_limits["ticks"] == 3


# ------------------------------------------------------------ the meter alone


def _meter(commands: Iterator[tuple[float, float]]) -> dict[str, int]:
    m = RateLimitMeter(LIM, DT)
    for v, w in commands:
        m.observe(v, w)
    return m.counts()


def test_slowing_down_is_judged_against_the_deceleration_limit() -> None:
    v0, d, a = 1.0, LIM.decel_max_mps2, LIM.accel_max_mps2
    assert d > a  # the default envelope brakes harder than it accelerates
    up = [(min(v0, a * DT * k), 0.0) for k in range(1, 200)]
    at_decel = _meter(iter([*up, *((v0 - d * DT * k, 0.0) for k in range(1, 50))]))
    at_accel = _meter(iter([*up, *((v0 - a * DT * k, 0.0) for k in range(1, 50))]))
    ramp = sum(1 for k in range(1, 200) if a * DT * k <= v0)
    assert at_decel["accel"] == ramp + 49
    assert at_accel["accel"] == ramp  # slowing at the (lower) acceleration limit: within
    # reverse: speeding up backwards is judged against the acceleration limit
    back = _meter(iter((-a * DT * k, 0.0) for k in range(1, 30)))
    assert back["accel"] == 29


def test_the_reverse_speed_limit_and_the_turn_rate_limit_count_in_both_directions() -> None:
    vr, w = LIM.v_reverse_max_mps, LIM.omega_max_radps
    counts = _meter(iter([(-vr, w), (-vr, -w), (-0.5 * vr, 0.5 * w), (LIM.v_max_mps, -w)]))
    assert counts["speed"] == 3 and counts["turn_rate"] == 3


def test_the_jerk_limit_counts_a_change_of_the_acceleration() -> None:
    j = LIM.jerk_max_mps3
    # acceleration growing at the jerk limit, then held
    a_k = [min(j * DT * k, 0.5) for k in range(1, 60)]
    v = list(itertools.accumulate(a * DT for a in a_k))
    counts = _meter(iter((x, 0.0) for x in v))
    grows = sum(1 for k in range(1, 60) if j * DT * k <= 0.5)
    assert counts["jerk"] == grows
    assert counts["accel"] == 0


def test_a_reset_zeroes_the_counts_and_starts_from_rest() -> None:
    m = RateLimitMeter(LIM, DT)
    m.observe(LIM.v_max_mps, LIM.omega_max_radps)
    assert m.counts()["speed"] == 1
    m.reset()
    assert m.counts() == {"ticks": 0, **dict.fromkeys(RATE_LIMITS, 0)}
    m.observe(0.0, 0.0)
    assert m.counts() == {"ticks": 1, **dict.fromkeys(RATE_LIMITS, 0)}


@pytest.mark.parametrize(("fraction", "at"), [(1.0, 1), (1.0 - 5e-4, 1), (1.5, 1), (0.998, 0)])
def test_a_command_within_a_tenth_of_a_percent_of_a_limit_or_beyond_is_at_it(
    fraction: float, at: int
) -> None:
    assert _meter(iter([(fraction * LIM.v_max_mps, 0.0)]))["speed"] == at
