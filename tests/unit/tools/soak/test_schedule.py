"""The soak's schedule: the same from the same seed, every fault kind in it, faults that
overlap, every event a valid one."""

from __future__ import annotations

import pytest

from firmware_sim.faultspec import KINDS
from tools.run.inject import fault_command
from tools.soak import schedule


@pytest.mark.parametrize("minutes", [3.0, 60.0])
def test_the_schedule_is_the_same_from_the_same_seed(minutes: float) -> None:
    assert schedule.build(5, minutes) == schedule.build(5, minutes)
    assert schedule.build(5, minutes) != schedule.build(6, minutes)


@pytest.mark.parametrize("seed", range(10))
def test_every_fault_kind_attack_and_signal_is_scheduled(seed: int) -> None:
    events = schedule.build(seed, 3.0).events
    faults = {e.kind for e in events if e.action == "fault"}
    assert faults == set(KINDS)
    assert {e.kind for e in events if e.action == "attack"} == set(schedule.ATTACKS)
    assert {e.kind for e in events if e.action == "signal"} == set(schedule.SIGNALS)


@pytest.mark.parametrize("seed", range(10))
def test_faults_follow_one_another_and_some_overlap(seed: int) -> None:
    sched = schedule.build(seed, 3.0)
    assert schedule.overlapping(sched.events)
    times = [e.at_s for e in sched.events]
    assert times == sorted(times)
    assert times[0] >= schedule.WARMUP_S
    assert times[-1] <= sched.duration_s - schedule.COOLDOWN_S


def test_a_long_soak_repeats_every_kind_in_each_round() -> None:
    events = schedule.build(1, 60.0).events
    rounds = int((3600 - schedule.WARMUP_S - schedule.COOLDOWN_S) // schedule.ROUND_S)
    per_kind = {k: sum(e.kind == k for e in events) for _a, k in schedule.kinds()}
    assert set(per_kind.values()) == {rounds}


def test_every_fault_event_is_a_valid_bench_fault_command() -> None:
    for e in schedule.build(3, 60.0).events:
        if e.action == "fault":
            fault_command(e.fault_table(), source=e.describe())
    reboot = [e for e in schedule.build(3, 3.0).events if e.kind == "node-reboot"]
    assert reboot and reboot[0].duration_s == 0.0


def test_the_schedule_survives_its_json_form() -> None:
    sched = schedule.build(9, 3.0)
    assert schedule.Schedule.from_dict(sched.as_dict()) == sched


def test_a_soak_shorter_than_its_minimum_is_refused() -> None:
    with pytest.raises(ValueError, match="at least 2 minutes"):
        schedule.build(1, 1.0)
