"""Fault models on the simulated chair: each moves the ground truth the way its physics says."""

from __future__ import annotations

import dataclasses
import math
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import pytest

from dbc.codec import (
    AxisState,
    EncoderEstimates,
    FaultAction,
    FaultCommand,
    FaultEvent,
    FaultSide,
    FaultState,
    FaultType,
    Node,
    PoseFix,
    SetAxisState,
    SetInputVel,
)
from dbc.runtime.errors import ConfigError
from firmware_sim import busfaults as bf
from firmware_sim.config import load_bench_config
from firmware_sim.faults import FaultManager
from firmware_sim.faultspec import KINDS, BusRuleParams, FaultSpec, parse_fault, parse_schedule
from firmware_sim.sim import ChairSim

SRC = "test.toml"
R0 = 0.30
B = 0.28  # half track


def fault(**table: Any) -> FaultSpec:
    return parse_fault(table, source=SRC, key="faults[0]")


@dataclass
class Run:
    sim: ChairSim
    mgr: FaultManager
    frames: list[tuple[int, Any, Node | None]] = field(default_factory=list)
    heading: list[float] = field(default_factory=list)
    left_angle: list[float] = field(default_factory=list)

    def of(self, cls: type, node: Node | None = None) -> list[tuple[int, Any]]:
        return [(t, p) for t, p, n in self.frames if type(p) is cls and (node is None or n == node)]


def drive(
    faults: list[FaultSpec],
    seconds: float,
    *,
    left_revps: float = 0.4,
    right_revps: float = 0.4,
    seed: int = 0,
    bus: bf.FaultInjectingBus | None = None,
) -> Run:
    """Both drives armed at t = 0 with constant wheel setpoints; the faults on their schedule."""
    # a stock ODrive: these tests script plain frames (authentication: test_drive_safety.py)
    cfg = load_bench_config(
        {"drive.require_auth": False, "drive.check_contract": False}, source="test"
    )
    sim = ChairSim(cfg, seed=seed)
    mgr = FaultManager(sim, faults, seed=seed, bus=bus)
    out: list[Any] = []
    for node, sp in ((Node.LEFT, left_revps), (Node.RIGHT, right_revps)):
        sim.handle(node, SetAxisState(AxisState.CLOSED_LOOP_CONTROL), out)
        sim.handle(node, SetInputVel(sp), out)
    run = Run(sim, mgr)
    for _ in range(round(seconds * 100)):
        mgr.on_step(sim.now_ns)
        for ev in mgr.take_events():
            run.frames.append((sim.now_ns, ev, None))
        step: list[Any] = []
        sim.emit_due(step)
        run.frames += [(sim.now_ns, p, n) for p, n in step]
        run.heading.append(sim.plant.heading_rad)
        run.left_angle.append(sim.plant.left.angle_rad)
        sim.advance()
    return run


@pytest.fixture(scope="module")
def nominal() -> Run:
    return drive([], 12.0)


# ------------------------------------------------------------------- plant faults


@pytest.mark.parametrize(("side", "sign"), [("right", -1.0), ("left", 1.0)])
def test_a_flat_tire_under_equal_wheel_commands_turns_the_chair_toward_it(
    side: str, sign: float
) -> None:
    run = drive([fault(type="flat-tire", side=side, onset_s=1.0, time_constant_s=0.5)], 8.0)
    p = run.sim.plant
    wheel = p.right if side == "right" else p.left
    assert wheel.radius_m == pytest.approx(0.26, abs=1e-4)
    # flat right: the right wheel covers less ground, the chair turns right (clockwise)
    assert sign * p.heading_rad > 0.2
    assert sign * p.y_m > 0.1


def test_the_flat_tire_decays_exponentially_with_its_time_constant() -> None:
    run = drive([fault(type="flat-tire", side="left", onset_s=0.5, time_constant_s=2.0)], 2.5)
    # 2.0 s after the onset: r = 0.26 + 0.04 / e
    assert run.sim.plant.left.radius_m == pytest.approx(0.26 + 0.04 / math.e, abs=2e-4)
    assert run.sim.plant.right.radius_m == R0


@pytest.mark.parametrize(("side", "sign"), [("left", -1.0), ("right", 1.0)])
def test_a_shaft_bump_swings_the_heading_once_per_wheel_revolution(
    side: str, sign: float, nominal: Run
) -> None:
    a = 0.015
    run = drive([fault(type="shaft-bump", side=side, onset_s=2.0, amplitude_m=a)], 12.0)
    onset = 200
    th0 = run.left_angle[onset]
    dev = [h - n for h, n in zip(run.heading, nominal.heading, strict=True)]
    # the bumped wheel rolls on r + a sin(theta - theta_on): after half a revolution it has
    # covered 2a more ground than nominal, after a whole one as much as nominal
    half = next(k for k in range(onset, len(dev)) if run.left_angle[k] - th0 >= math.pi)
    full = next(k for k in range(onset, len(dev)) if run.left_angle[k] - th0 >= 2 * math.pi)
    peak = 2 * a / (2 * B)
    assert sign * dev[half] == pytest.approx(peak, rel=0.15)
    assert abs(dev[full] - dev[onset]) < 0.15 * peak
    # periodic: the same swing one revolution later
    half2 = next(k for k in range(full, len(dev)) if run.left_angle[k] - th0 >= 3 * math.pi)
    assert sign * (dev[half2] - dev[full]) == pytest.approx(peak, rel=0.15)


def test_slip_on_both_wheels_shortens_the_path_without_turning(nominal: Run) -> None:
    run = drive([fault(type="slip", side="both", onset_s=0.0, ratio=0.2)], 12.0)
    p, n = run.sim.plant, nominal.sim.plant
    assert abs(p.heading_rad) < 1e-6
    assert math.hypot(p.x_m, p.y_m) == pytest.approx(0.8 * math.hypot(n.x_m, n.y_m), rel=0.02)


def test_slip_on_the_left_wheel_turns_the_chair_left() -> None:
    run = drive([fault(type="slip", side="left", onset_s=1.0, ratio=0.2)], 5.0)
    assert run.sim.plant.heading_rad > 0.2


def test_a_dead_left_motor_lets_the_right_wheel_turn_the_chair_left() -> None:
    run = drive([fault(type="dead-motor", side="left", onset_s=1.0)], 4.0)
    p = run.sim.plant
    assert p.left.current_a == 0.0
    # the free left wheel is dragged along by the chair, slower than the driven right one
    assert p.left.omega_radps < 0.85 * p.right.omega_radps
    assert p.heading_rad > 0.3


def test_torque_loss_slows_the_weak_wheel_while_the_chair_accelerates() -> None:
    run = drive([fault(type="torque-loss", side="right", onset_s=0.0, gain=0.3)], 0.5)
    p = run.sim.plant
    assert p.right.omega_radps < p.left.omega_radps
    assert p.heading_rad < 0.0


# ------------------------------------------------------------------ sensor faults


def test_a_stuck_left_encoder_freezes_its_estimate_and_the_drive_pushes_blindly() -> None:
    run = drive([fault(type="encoder-stuck", side="left", onset_s=1.0)], 3.0)
    est = [p.pos_rev for t, p in run.of(EncoderEstimates, Node.LEFT) if t > 1.5e9]
    assert max(est) - min(est) < 1e-6
    # the drive believes the wheel stopped: its integrator winds up to the current limit,
    # while the wheel keeps turning (the voltage-mode loop assumes zero back-EMF)
    assert run.sim.left.iq_setpoint_a == pytest.approx(25.0)
    assert run.sim.plant.left.omega_radps > 1.0


def test_an_encoder_scale_error_makes_the_drive_turn_its_wheel_slower() -> None:
    run = drive([fault(type="encoder-scale", side="left", onset_s=0.0, scale=1.25)], 3.0)
    left = run.of(EncoderEstimates, Node.LEFT)[-1][1]
    assert left.vel_revps == pytest.approx(0.4, rel=0.02)  # what the drive sees
    p = run.sim.plant
    assert p.left.omega_radps == pytest.approx(p.right.omega_radps / 1.25, rel=0.03)
    assert p.heading_rad > 0.1


def test_encoder_noise_perturbs_the_estimate_with_the_configured_spread(nominal: Run) -> None:
    run = drive([fault(type="encoder-noise", side="right", onset_s=0.0, sigma_counts=20.0)], 4.0)
    vel = [p.vel_revps for t, p in run.of(EncoderEstimates, Node.RIGHT) if t > 2e9]
    ref = [p.vel_revps for t, p in nominal.of(EncoderEstimates, Node.RIGHT) if 2e9 < t <= 4e9]

    def spread(v: list[float]) -> float:
        m = sum(v) / len(v)
        return math.sqrt(sum((x - m) ** 2 for x in v) / len(v))

    assert spread(vel) > 10 * spread(ref)


def test_encoder_dropout_loses_estimates_at_the_configured_rate() -> None:
    run = drive([fault(type="encoder-dropout", side="left", onset_s=0.0, probability=0.3)], 20.0)
    n_left = len(run.of(EncoderEstimates, Node.LEFT))
    n_right = len(run.of(EncoderEstimates, Node.RIGHT))
    assert n_right == 2000
    assert 1 - n_left / n_right == pytest.approx(0.3, abs=0.03)
    assert run.sim.left.estimates_dropped == n_right - n_left


def test_localizer_dropout_and_bias_act_on_the_fixes(nominal: Run) -> None:
    drop = fault(type="localizer-dropout", onset_s=0.0, probability=0.4)
    bias = fault(type="localizer-bias", onset_s=0.0, offset_m=0.5, direction_rad=math.pi / 2)
    run = drive([drop, bias], 12.0)
    fixes = run.of(PoseFix)
    assert 1 - len(fixes) / len(nominal.of(PoseFix)) == pytest.approx(0.4, abs=0.1)
    # same noise sequence as the nominal run: the fixes that survive differ by the bias only
    ref = {t: p for t, p in nominal.of(PoseFix)}
    dy = [p.y_m - ref[t].y_m for t, p in fixes]
    dx = [p.x_m - ref[t].x_m for t, p in fixes]
    assert all(d == pytest.approx(0.5, abs=2e-3) for d in dy)
    assert all(abs(d) < 2e-3 for d in dx)


# ---------------------------------------------------------------- events and life


def test_activation_and_clearing_are_reported_with_their_parameters() -> None:
    flat = fault(type="flat-tire", side="right", onset_s=0.5, duration_s=1.0, to_radius_m=0.27)
    run = drive([flat], 2.0)
    events = run.of(FaultEvent)
    assert [(t, e.state) for t, e in events] == [
        (500_000_000, FaultState.ACTIVE),
        (1_500_000_000, FaultState.CLEARED),
    ]
    e = events[0][1]
    assert (e.fault_id, e.fault_type, e.side) == (1, FaultType.FLAT_TIRE, FaultSide.RIGHT)
    assert (e.amplitude, e.param, e.duration_s) == (0.27, 2.0, 1.0)
    assert run.sim.plant.right.radius_m == R0  # re-inflated when cleared


def test_a_live_command_injects_and_clears_a_fault() -> None:
    run = drive([], 0.1)
    sim, mgr = run.sim, run.mgr
    mgr.command(
        FaultCommand(0, FaultType.FLAT_TIRE, FaultSide.LEFT, FaultAction.INJECT, 0.0, 0.26, 0.0),
        sim.now_ns,
    )
    (ev,) = mgr.take_events()
    assert ev.state == FaultState.ACTIVE and ev.fault_id == 1
    sim.advance()
    assert sim.plant.left.radius_m == pytest.approx(0.26)  # time constant 0: a step
    mgr.command(FaultCommand(0, FaultType.FLAT_TIRE, FaultSide.LEFT, FaultAction.CLEAR), sim.now_ns)
    (ev,) = mgr.take_events()
    assert ev.state == FaultState.CLEARED
    sim.advance()
    assert sim.plant.left.radius_m == R0


def test_invalid_or_pointless_commands_are_rejected_not_raised() -> None:
    run = drive([], 0.1)
    mgr = run.mgr
    too_big = FaultCommand(0, FaultType.FLAT_TIRE, FaultSide.LEFT, FaultAction.INJECT, 0, 0.9, 0)
    no_side = FaultCommand(0, FaultType.SLIP, FaultSide.NONE, FaultAction.INJECT, 0, 0.1, 0)
    nothing = FaultCommand(7, FaultType.NONE, FaultSide.NONE, FaultAction.CLEAR)
    for cmd in (too_big, no_side, nothing):
        mgr.command(cmd, run.sim.now_ns)
    assert [e.state for e in mgr.take_events()] == [FaultState.REJECTED] * 3
    assert not mgr.active


def test_runs_with_the_same_seed_are_identical_and_seeds_differ() -> None:
    noise = fault(type="encoder-noise", side="left", onset_s=0.2, sigma_counts=30.0)
    a, b, c = (drive([noise], 1.0, seed=s) for s in (3, 3, 4))
    assert a.heading == b.heading
    assert a.of(EncoderEstimates) == b.of(EncoderEstimates)
    assert a.of(EncoderEstimates) != c.of(EncoderEstimates)


def test_bus_faults_install_wrapper_rules_only_while_active() -> None:
    with can.Bus(interface="virtual", channel=f"faults-{uuid.uuid4()}") as inner:
        bus = bf.FaultInjectingBus(inner)
        try:
            silent = fault(type="node-silent", node="right", onset_s=0.2, duration_s=0.3)
            run = drive([silent], 0.3, bus=bus)
            (rule,) = bus.rules.values()
            assert isinstance(rule, bf.Silence) and rule.match.nodes == {2}
            run.sim.advance()
            for _ in range(30):
                run.mgr.on_step(run.sim.now_ns)
                run.sim.advance()
            assert bus.rules == {}
        finally:
            bus.shutdown()


def test_a_scheduled_bus_fault_becomes_its_rule_with_its_times_in_ns() -> None:
    match, both = bf.FrameMatch(), bf.Direction.BOTH
    delay = fault(type="bus-delay", delay_ms=12.5, jitter_ms=0.25).params
    assert delay.rule_for(match, both) == bf.Delay(
        match=match, direction=both, delay_ns=12_500_000, jitter_ns=250_000
    )
    drop = fault(type="bus-drop", probability=0.3, burst_length=4.0).params
    assert drop.rule_for(match, both) == bf.Drop(
        match=match, direction=both, probability=0.3, burst_length=4.0
    )
    reorder = fault(type="bus-reorder", probability=0.2, max_hold_ms=30.0).params
    assert reorder.rule_for(match, both) == bf.Reorder(
        match=match, direction=both, probability=0.2, max_hold_ns=30_000_000
    )


def test_every_bus_fault_parameter_is_a_field_of_its_rule() -> None:
    common = {f.name for f in dataclasses.fields(BusRuleParams)}
    kinds = [k for k in KINDS.values() if issubclass(k.params, BusRuleParams)]
    assert {k.name for k in kinds} >= {"bus-drop", "bus-delay", "bus-corrupt"}
    for k in kinds:
        rule_fields = {f.name for f in dataclasses.fields(k.params.rule)}
        for f in dataclasses.fields(k.params):
            if f.name not in common:
                name = f.name.removesuffix("_ms") + "_ns" if f.name.endswith("_ms") else f.name
                assert name in rule_fields, f"{k.name}.{f.name} is not a field of {k.params.rule}"


def test_a_node_reboot_makes_the_drive_silent_for_its_boot_time() -> None:
    run = drive([fault(type="node-reboot", node="left", onset_s=0.5)], 0.52)
    assert run.sim.left.booting(run.sim.now_ns)
    assert run.sim.left.state == AxisState.IDLE
    states = [e.state for _t, e in run.of(FaultEvent)]
    assert states == [FaultState.ACTIVE, FaultState.CLEARED]


def test_a_diverging_state_raises_for_the_bench_to_end_the_run_cleanly() -> None:
    run = drive([], 0.1)

    def poison(t_ns: int, plant: Any) -> None:
        plant.left.radius_m = math.nan

    run.sim.add_tick_hook(poison)
    # Bench.run turns any exception of advance() into stats.aborted and ends the run
    with pytest.raises((FloatingPointError, ValueError, OverflowError)):
        run.sim.advance()


# -------------------------------------------------------------------- validation


def test_every_fault_type_has_a_wire_type_and_round_trips_through_a_command() -> None:
    from firmware_sim.faultspec import spec_from_command

    assert len({k.fault_type for k in KINDS.values()}) == len(KINDS)
    for name, info in KINDS.items():
        table: dict[str, Any] = {"type": name, "onset_s": 1.0}
        if info.sided:
            table["side"] = "left"
        spec = parse_fault(table, source=SRC, key="f")
        ev = spec.wire(5, FaultState.ACTIVE)
        cmd = FaultCommand(
            5, ev.fault_type, ev.side, FaultAction.INJECT, ev.duration_s, ev.amplitude, ev.param
        )
        again = spec_from_command(cmd, 1_000_000_000)
        assert again.kind == name
        assert again.params == spec.params, name


@pytest.mark.parametrize(
    ("table", "message"),
    [
        (
            {"type": "flat-tyre", "side": "left"},
            r"faults\[0\]\.type = 'flat-tyre' is not a fault type",
        ),
        ({"type": "flat-tire"}, r"faults\[0\]\.side is required for flat-tire"),
        (
            {"type": "flat-tire", "side": "left", "to_radius_m": 0.7},
            r"test\.toml: faults\[0\]\.to_radius_m = 0\.7 is above its maximum 0\.6 \(m\)",
        ),
        (
            {"type": "slip", "side": "both", "ratio": -0.1},
            r"faults\[0\]\.ratio = -0\.1 is below its minimum 0\.0",
        ),
        ({"type": "slip", "side": "both", "radius": 0.1}, r"unknown key 'faults\[0\]\.radius'"),
        ({"type": "shaft-bump", "side": "middle"}, r"faults\[0\]\.side = 'middle' is not one of"),
        (
            {"type": "bus-drop", "frames": ["Left_Set_Input_Velocity"]},
            r"faults\[0\]\.frames\[0\] = 'Left_Set_Input_Velocity'",
        ),
        ({"type": "node-reboot", "duration_s": 1.0}, r"duration_s must be 0 for node-reboot"),
        (
            {"type": "flat-tire", "side": "left", "onset_s": "20"},
            r"faults\[0\]\.onset_s must be a number \(s\)",
        ),
    ],
)
def test_a_bad_schedule_entry_names_the_file_the_key_and_the_bound(
    table: dict[str, Any], message: str
) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_schedule([table], source=SRC)


def test_a_scenario_file_with_a_bad_fault_fails_to_load(tmp_path: Path) -> None:
    from tools.run import scenario

    p = tmp_path / "bad.toml"
    p.write_text(
        '[scenario]\nroute = "short"\n[[faults]]\ntype = "flat-tire"\nside = "left"\n'
        "to_radius_m = 0.01\n"
    )
    with pytest.raises(ConfigError, match=r"bad\.toml: faults\[0\]\.to_radius_m = 0\.01 is below"):
        scenario.load(str(p))


@pytest.mark.parametrize(
    "name", ["bump-left", "bump-right", "flat-left", "flat-right", "slip", "cascaded"]
)
def test_the_shipped_fault_scenarios_carry_the_papers_parameters(name: str) -> None:
    from tools.run import scenario

    s = scenario.load(name)
    labels = [(f.label, f.params.onset_s) for f in s.faults]
    expected = {
        "bump-left": [("bump-left", 20.0)],
        "bump-right": [("bump-right", 20.0)],
        "flat-left": [("flat-left", 20.0)],
        "flat-right": [("flat-right", 20.0)],
        "slip": [("slip", 20.0)],
        "cascaded": [("slip", 10.0), ("flat-left", 28.0), ("bump-right", 46.0)],
    }[name]
    assert labels == expected
    for f in s.faults:
        if f.kind == "flat-tire":
            assert f.params.to_radius_m == 0.26
        if f.kind == "shaft-bump":
            assert f.params.amplitude_m == 0.015
    if name == "cascaded":
        assert max(f.end_ns or 0 for f in s.faults) == 62_000_000_000


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_kind_has_its_model_and_is_activated_and_cleared(kind: str) -> None:
    # MODELS is the one table of models, keyed as KINDS: each kind builds, acts, clears
    from firmware_sim.faults import MODELS

    assert set(MODELS) == set(KINDS)
    required: dict[str, Any] = {"side": "left"} if KINDS[kind].sided else {}
    if "node" in {f.name for f in dataclasses.fields(KINDS[kind].params)}:
        required["node"] = "left"
    if kind != "node-reboot":  # instantaneous: no duration
        required["duration_s"] = 0.3
    spec = fault(type=kind, onset_s=0.2, **required)
    inner = can.Bus(interface="virtual", channel=f"kinds-{uuid.uuid4()}")
    bus = bf.FaultInjectingBus(inner, now_ns=lambda: 0, seed=1, owns_bus=True)
    try:
        run = drive([spec], 1.0, bus=bus)
    finally:
        bus.shutdown()
    events = [e.state for _t, e in run.of(FaultEvent)]
    assert events[0] == FaultState.ACTIVE and events[-1] == FaultState.CLEARED
    assert not run.mgr.active
