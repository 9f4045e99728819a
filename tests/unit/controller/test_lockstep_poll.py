"""The controller loop driven by ``poll`` (one-thread lock-step runs) is the loop of ``run``."""

from __future__ import annotations

import itertools
from typing import Any

import can

from controller.clock import NOT_DUE, LockstepClock
from controller.config import load_config
from controller.node import ControllerNode
from controller.planner import plan
from controller.tracking import registry
from dbc.codec import BenchEnd, BenchStep, BenchStepAck, Codec
from tools.bus.transport import open_bus, resolve
from tools.run import scenario as scenario_mod

CODEC = Codec.default()
CFG = load_config()
PERIOD_NS = 10_000_000
_chan = itertools.count()


def _setup(*, wait: bool) -> tuple[ControllerNode, can.BusABC, can.BusABC]:
    spec = resolve("virtual", f"poll-test-{next(_chan)}")
    bus, bench = open_bus(spec), open_bus(spec)
    traj = plan(scenario_mod.load("short").route)
    law = registry.create("baseline", CFG.geometry, traj, motor=CFG.motor)
    clock = LockstepClock(bus, PERIOD_NS, codec=CODEC, wait=wait)
    return ControllerNode(bus, CFG, law, traj, clock, codec=CODEC), bus, bench


def _sent(bench: can.BusABC) -> list[tuple[Any, ...]]:
    out = []
    while (m := bench.recv(0.0)) is not None:
        out.append(tuple(CODEC.decode(m)))
    return out


def test_a_clock_that_does_not_wait_says_no_tick_is_due() -> None:
    node, bus, bench = _setup(wait=False)
    try:
        assert node.clock.wait_tick(lambda m: None) == NOT_DUE
        bench.send(CODEC.encode(BenchStep(0)))
        assert node.clock.wait_tick(lambda m: None) == 0
        assert node.clock.wait_tick(lambda m: None) == NOT_DUE
    finally:
        bus.shutdown()
        bench.shutdown()


def test_poll_runs_the_due_ticks_without_waiting_and_ends_on_bench_end() -> None:
    node, bus, bench = _setup(wait=False)
    try:
        node.begin()
        assert node.poll() is True  # nothing due: returns at once, nothing sent
        assert _sent(bench) == [] and node.stats.ticks == 0
        for k in range(3):
            bench.send(CODEC.encode(BenchStep(k * PERIOD_NS)))
        assert node.poll() is True
        acks = [p.sim_time_ns for _n, p in _sent(bench) if isinstance(p, BenchStepAck)]
        assert acks == [0, PERIOD_NS, 2 * PERIOD_NS] and node.stats.ticks == 3
        bench.send(CODEC.encode(BenchEnd(3 * PERIOD_NS)))
        assert node.poll() is False
        assert node.poll() is False  # over stays over
        node.end()
        assert node.clock.ended_by == "Bench_End"
    finally:
        bus.shutdown()
        bench.shutdown()


def test_poll_and_run_send_the_same_frames_for_the_same_steps() -> None:
    runs = []
    for wait in (True, False):
        node, bus, bench = _setup(wait=wait)
        try:
            for k in range(120):  # no drive answers: acks, heartbeats, arming requests
                bench.send(CODEC.encode(BenchStep(k * PERIOD_NS)))
            bench.send(CODEC.encode(BenchEnd(120 * PERIOD_NS)))
            if wait:
                node.run()
            else:
                node.begin()
                assert node.poll() is False
                node.end()
            runs.append((_sent(bench), node.stats.ticks, node.stats.final_state))
        finally:
            bus.shutdown()
            bench.shutdown()
    assert runs[0][1] == 120
    assert len(runs[0][0]) > 120
    assert runs[0] == runs[1]
