"""Faults end to end on the virtual bus: scenarios, the bench's fault frames, live injection,
bus faults, and the controller's diagnosis of each fault."""

from __future__ import annotations

import threading
import uuid
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from dbc.codec import (
    Codec,
    EncoderEstimates,
    FaultAction,
    FaultCommand,
    FaultEvent,
    FaultSide,
    FaultState,
    FaultType,
    Node,
    TruthContact,
    TruthWheels,
)
from firmware_sim.bench import Bench, BenchStats
from firmware_sim.config import load_bench_config
from firmware_sim.faultspec import parse_schedule
from tests.integration.conftest import run_stack
from tests.integration.test_bench_lockstep import HostLog, ScriptedHost
from tools.metrics.tracking import read_bus_log

# make test starts the heaviest files first (tests/conftest.py)
pytestmark = pytest.mark.heavy(seconds=29)

CODEC = Codec.default()
MS = 1_000_000


def bench_with_host(
    *,
    duration_s: float,
    faults: list[dict[str, Any]] | None = None,
    extra: Any = None,
    hook: Any = None,
    during: Any = None,
) -> tuple[BenchStats, HostLog, Bench]:
    """A lock-step bench with ``faults`` against the scripted host (equal wheel setpoints).

    ``during(channel)`` runs in a thread of its own beside the bench, which then ends when it
    returns (or at ``duration_s``): a lock-step bench runs as fast as the CPU allows, so a
    fixed simulated time would race whatever ``during`` does."""
    channel = f"faults-{uuid.uuid4()}"
    done = threading.Event() if during is not None else None
    cfg = load_bench_config({}, source="test")
    with (
        can.Bus(interface="virtual", channel=channel) as host_bus,
        can.Bus(interface="virtual", channel=channel) as bench_bus,
    ):
        host = ScriptedHost(host_bus, setpoints=lambda t: (0.4, 0.4), extra=extra)
        host.start()
        try:
            bench = Bench(
                bench_bus,
                cfg,
                duration_s=duration_s,
                faults=parse_schedule(faults or [], source="test"),
                stop_event=done,
            )
            if hook is not None:
                bench.sim.add_tick_hook(hook)
            if during is not None and done is not None:

                def run_during(finished: threading.Event = done) -> None:
                    try:
                        during(channel)
                    finally:
                        finished.set()

                t = threading.Thread(target=run_during, daemon=True)
                t.start()
            stats = bench.run()
        finally:
            host.join(timeout=5.0)
            host.stop()
            host.join(timeout=5.0)
    assert host.error is None, host.error
    return stats, host.log, bench


# ------------------------------------------------------------------- bench level


def test_a_command_frame_injects_and_clears_a_fault_in_a_lockstep_bench() -> None:
    def extra(t: int) -> list[can.Message]:
        if t == 500 * MS:
            cmd = FaultCommand(0, FaultType.FLAT_TIRE, FaultSide.LEFT, FaultAction.INJECT, 0, 0.26)
            return [CODEC.encode(cmd)]
        if t == 1500 * MS:
            return [
                CODEC.encode(
                    FaultCommand(0, FaultType.FLAT_TIRE, FaultSide.LEFT, FaultAction.CLEAR)
                )
            ]
        return []

    stats, log, bench = bench_with_host(duration_s=2.0, extra=extra)
    events = log.all(FaultEvent)
    assert [(e.fault_id, e.state) for e in events] == [
        (1, FaultState.ACTIVE),
        (1, FaultState.CLEARED),
    ]
    assert events[0].amplitude == pytest.approx(0.26)
    radii = [w.radius_left_m for w in log.all(TruthWheels)]
    assert min(radii) == pytest.approx(0.26, abs=1e-4)
    assert radii[-1] == pytest.approx(0.30, abs=1e-5)
    assert stats.fault_events == 2
    assert [e.state for _t, e in bench.faults.history] == [FaultState.ACTIVE, FaultState.CLEARED]


def test_the_contact_truth_frame_shows_slip() -> None:
    slip = {"type": "slip", "side": "both", "onset_s": 0.5, "ratio": 0.2}
    _stats, log, _bench = bench_with_host(duration_s=1.0, faults=[slip])
    last = log.all(TruthContact)[-1]
    assert last.slip_left == pytest.approx(0.2) and last.slip_right == pytest.approx(0.2)
    assert last.contact_radius_left_m == pytest.approx(0.24, abs=1e-5)
    assert log.all(TruthWheels)[-1].radius_left_m == pytest.approx(0.30, abs=1e-5)


def test_a_scheduled_bus_drop_loses_the_configured_share_of_a_frame() -> None:
    drop = {
        "type": "bus-drop",
        "frames": ["Right_Get_Encoder_Estimates"],
        "direction": "send",
        "probability": 0.3,
        "onset_s": 0.0,
    }
    stats, log, _bench = bench_with_host(duration_s=10.0, faults=[drop])
    left = len(log.all(EncoderEstimates, Node.LEFT))
    right = len(log.all(EncoderEstimates, Node.RIGHT))
    assert 1 - right / left == pytest.approx(0.3, abs=0.04)
    assert stats.bus_fault_effects["dropped"] == left - right
    assert stats.missed_acks == 0  # the lock-step clock frames are untouched


def test_a_bus_delay_in_lockstep_is_simulation_time() -> None:
    delay = {
        "type": "bus-delay",
        "frames": ["Left_Get_Encoder_Estimates"],
        "direction": "send",
        "delay_ms": 30.0,
        "onset_s": 0.0,
    }
    stats, log, _bench = bench_with_host(duration_s=1.0, faults=[delay])
    # delayed frames arrive three steps late; the last three never leave before Bench_End
    assert (
        len(log.all(EncoderEstimates, Node.LEFT)) == len(log.all(EncoderEstimates, Node.RIGHT)) - 3
    )
    assert stats.bus_fault_effects["delayed"] == 101


def test_a_diverging_simulation_ends_the_run_cleanly() -> None:
    def poison(t_ns: int, plant: Any) -> None:
        if t_ns >= 300 * MS:
            plant.right.radius_m = float("nan")

    stats, _log, _bench = bench_with_host(duration_s=1.0, hook=poison)
    assert stats.aborted is not None and "simulation failed at t=0.30" in stats.aborted
    assert stats.steps == 30


def test_wheelchair_hil_inject_talks_to_a_running_bench(capsys: pytest.CaptureFixture[str]) -> None:
    from tools import cli

    codes: list[int] = []

    def inject(channel: str) -> None:
        base = ["--bus", "virtual", "--channel", channel, "--wait", "3"]
        codes.append(
            cli.main(["inject", "shaft-bump", "--side", "right", "--amplitude", "0.015", *base])
        )
        codes.append(cli.main(["inject", "all", "--clear", *base]))
        for _ in range(2):  # the second asks for an ID that is taken: refused by the bench
            codes.append(
                cli.main(["inject", "slip", "--side", "both", "--ratio", "0.1", "--id", "7", *base])
            )
        codes.append(cli.main(["inject", "slip", "--side", "both", "--ratio", "0.95", *base]))

    # until the five commands are done (each waits for the bench's answer)
    _stats, log, _bench = bench_with_host(duration_s=3600.0, during=inject)
    captured = capsys.readouterr()
    out = captured.out
    assert codes == [0, 0, 0, 1, 2], out
    assert "ACTIVE fault 1 shaft-bump side=right amplitude_m=0.015" in out
    assert "CLEARED fault 1 shaft-bump" in out
    assert "ACTIVE fault 7 slip side=both ratio=0.1" in out
    assert "REJECTED fault 7 slip" in out
    assert "fault.ratio = 0.95 is above its maximum 0.9" in captured.err
    states = [e.state for e in log.all(FaultEvent)]
    assert states == [
        FaultState.ACTIVE,
        FaultState.CLEARED,
        FaultState.ACTIVE,
        FaultState.REJECTED,
    ]


# ----------------------------------------------------------------- the diagnosis

SCENARIOS = {
    "fault-free": "none",
    "flat-left": "flat-left",
    "flat-right": "flat-right",
    "bump-left": "bump-left",
    "bump-right": "bump-right",
    "slip": "slip",
}


class _Runs:
    """The paper route up to 28 s (faults from 20 s) for a scenario, baseline controller: run
    when a test first asks for it, once per test process (under pytest-xdist a test needs only
    its own scenario's run, so the six are spread over the workers, not all made on each)."""

    def __init__(self, factory: pytest.TempPathFactory) -> None:
        self.factory = factory
        self.done: dict[str, tuple[Path, dict[str, Any]]] = {}

    def __getitem__(self, name: str) -> tuple[Path, dict[str, Any]]:
        if name not in self.done:
            d = self.factory.mktemp(name)
            self.done[name] = (d, run_stack(d, name, "baseline", duration_s=28.0))
        return self.done[name]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> _Runs:
    return _Runs(tmp_path_factory)


@pytest.mark.slow
@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_the_diagnosis_identifies_each_injected_fault_within_five_seconds(
    runs: _Runs, scenario: str
) -> None:
    _d, s = runs[scenario]
    fd = s["fault_diagnosis"]
    assert fd["injected"] == SCENARIOS[scenario]
    assert fd["identified"] == SCENARIOS[scenario]
    assert fd["false_alarm_fraction"] == 0.0
    if scenario != "fault-free":
        assert fd["detection_delay_s"] is not None and fd["detection_delay_s"] <= 5.0
        (f,) = fd["faults"]
        assert f["onset_s"] == 20.0


@pytest.mark.slow
def test_the_fault_and_the_diagnosis_are_in_the_log_with_their_parameters(
    runs: _Runs,
) -> None:
    d, _s = runs["flat-right"]
    bus = read_bus_log(
        d / "run.mcap", ["Bench_Fault_Event", "Host_Diagnosis", "Bench_Truth_Wheels"]
    )
    ev = bus.get("Bench_Fault_Event")
    assert list(ev["t"]) == [20_000_000_000]
    assert (ev["Fault_Type"][0], ev["Side"][0], ev["Fault_State"][0]) == (1, 2, 1)
    assert (ev["Amplitude"][0], ev["Param"][0]) == (0.26, 2.0)
    diag = bus.get("Host_Diagnosis")
    assert np.median(np.diff(diag["t"])) == 100 * MS
    late = diag["t"] > 26e9
    assert (diag["Hypothesis"][late] == 2).all()  # FLAT_RIGHT
    # the estimated radius feeds odometry: it follows the deflating tire
    truth = bus.get("Bench_Truth_Wheels")
    r_true = float(truth["Radius_Right"][-1])
    assert float(diag["Radius_Right_Est"][-1]) == pytest.approx(r_true, abs=0.006)
    assert float(diag["Radius_Left_Est"][-1]) == pytest.approx(0.30, abs=1e-4)
