"""Controller-side safety rules (docs/safety.md): what the loop sends, when, and what cannot
stall it.  Synthetic time throughout; no wall-clock thresholds."""

from __future__ import annotations

import ast
import gc
import itertools
import math
import threading
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from controller.clock import RealtimeClock
from controller.config import load_config
from controller.kinematics import TWO_PI, inverse
from controller.limits import LimitedCommand
from controller.link import SEND_FAIL_STREAK_DOWN, DriveLink
from controller.node import ARM_RESEND_S, CONTRACT_REASK_S, ControllerNode
from controller.planner import plan
from controller.safety import StopReason
from controller.tracking import registry
from controller.types import ReferenceSample, StateEstimate, TwistCommand
from dbc.codec import (
    AxisError,
    AxisState,
    Codec,
    HostAuth,
    HostHeartbeat,
    HostState,
    Node,
    RxSdo,
    SdoEndpoint,
    SetAxisState,
    SetInputVel,
    SetInputVelAuth,
    SetWatchdog,
)
from dbc.runtime import params
from dbc.runtime.errors import ConfigError
from firmware_sim.bench import Bench
from firmware_sim.config import load_bench_config
from tests.unit.idle_clock import IdleClock
from tools.bus.transport import open_bus, resolve
from tools.run import scenario as scenario_mod

CODEC = Codec.default()
CFG = load_config()
SAFE_CFG = params.replace(
    CFG, {"drives": {"require_auth": True, "host_timeout_ms": 300}}, source="test"
)
_chan = itertools.count()


def _node(cfg: Any = SAFE_CFG) -> tuple[ControllerNode, can.BusABC, can.BusABC]:
    spec = resolve("virtual", f"safety-ctl-{next(_chan)}")
    bus, listener = open_bus(spec), open_bus(spec)
    scen = scenario_mod.load("short")
    traj = plan(scen.route)
    law = registry.create("baseline", cfg.geometry, traj, motor=cfg.motor)
    return ControllerNode(bus, cfg, law, traj, IdleClock()), bus, listener


def _wheels(v: float, omega: float, cfg: Any = SAFE_CFG) -> LimitedCommand:
    g = cfg.geometry
    return LimitedCommand.from_twist(v, omega, g.half_track_m, g.wheel_radius_m)


def _frames(listener: can.BusABC) -> list[tuple[Node | None, Any]]:
    out = []
    while (m := listener.recv(0.0)) is not None:
        out.append(tuple(CODEC.decode(m)))
    return out


# ------------------------------------------------------------------ what is sent


@pytest.mark.parametrize(
    ("v", "omega"),
    [(math.nan, 0.0), (0.5, math.inf), (-math.inf, math.nan), (1e9, 0.0), (-1e9, 1e9)],
)
def test_non_finite_or_out_of_range_commands_never_reach_a_frame(v: float, omega: float) -> None:
    node, bus, listener = _node()
    cmd = _wheels(v, omega)
    try:
        node._send_setpoints(cmd)
        sent = _frames(listener)
    finally:
        bus.shutdown()
        listener.shutdown()
    lim = SAFE_CFG.drives.velocity_limit_revps
    assert len(sent) == 2 and node.link.counters.send_failed == 0
    # each non-finite wheel speed is counted once, before encoding
    bad = sum(not math.isfinite(w) for w in (cmd.left_radps, cmd.right_radps))
    assert node.stats.non_finite_commands == bad
    for _n, p in sent:
        assert isinstance(p, SetInputVelAuth)
        assert math.isfinite(p.input_vel_revps) and abs(p.input_vel_revps) <= lim
        assert p.stop_ref_revps >= abs(p.input_vel_revps)


def test_the_frames_carry_the_limiters_wheel_speeds_converted_once_as_inverse_kinematics_gives() -> (
    None
):
    """One conversion per tick: the limiter's wheel speeds, rad/s to rev/s once, are the
    same float32 values as the twist's inverse kinematics (the node's former path)."""
    cfg = params.replace(CFG, {"drives": {"require_auth": False}}, source="test")
    node, bus, listener = _node(cfg)  # Set_Input_Vel: float32, no quantization
    g = cfg.geometry
    cmds = []
    try:
        for k in range(300):
            raw = TwistCommand(1.6 * math.sin(0.05 * k), 2.5 * math.cos(0.031 * k))
            cmd = node.limiter.apply(raw, 0.01)
            assert (cmd.left_radps, cmd.right_radps) == (
                inverse(cmd.v_mps, cmd.omega_radps, g.half_track_m, g.wheel_radius_m,
                        g.wheel_radius_m).left_radps,
                inverse(cmd.v_mps, cmd.omega_radps, g.half_track_m, g.wheel_radius_m,
                        g.wheel_radius_m).right_radps,
            )  # fmt: skip
            node._send_setpoints(cmd)
            cmds.append(cmd)
        sent = _frames(listener)
    finally:
        bus.shutdown()
        listener.shutdown()
    assert node.limiter.counters.wheel > 0 and node.limiter.counters.box > 0  # both paths
    assert all(isinstance(p, SetInputVel) for _n, p in sent)
    left = [p.input_vel_revps for n, p in sent if n == Node.LEFT]
    right = [p.input_vel_revps for n, p in sent if n == Node.RIGHT]
    f32 = np.float32
    assert left == [float(f32(c.left_radps / TWO_PI)) for c in cmds]
    assert right == [float(f32(c.right_radps / TWO_PI)) for c in cmds]


def test_a_non_finite_law_output_is_a_non_finite_stop_that_sends_nothing() -> None:
    node, bus, listener = _node()

    class _NaNLaw:
        name = "nan"

        def step(self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate):
            return TwistCommand(math.nan, 0.0)

        def internals(self) -> dict[str, float]:
            return {}

    try:
        node.state = HostState.TRACKING
        node.limiter.reset(0.8, 0.2)
        node.controller = _NaNLaw()  # type: ignore[assignment]
        node._track(10_000_000)
        sent = _frames(listener)
    finally:
        bus.shutdown()
        listener.shutdown()
    assert node.state == HostState.SAFE_STOP and node.stop_reason == StopReason.NON_FINITE
    assert node.stats.non_finite_commands == 1
    assert not any(isinstance(p, SetInputVelAuth) for _n, p in sent)
    assert (node.limiter.v_mps, node.limiter.omega_radps) == (0.8, 0.2)  # left as it was


@pytest.mark.parametrize(
    ("off_m", "stops"), [(0.5, False), (0.99, False), (1.01, True), (5.0, True)]
)
def test_an_estimate_farther_than_max_path_error_from_the_reference_is_an_off_path_stop(
    off_m: float, stops: bool
) -> None:
    node, bus, listener = _node()
    calls: list[float] = []

    class _Law:
        name = "recording"

        def step(self, t_s: float, dt_s: float, ref: ReferenceSample, est: StateEstimate):
            calls.append(t_s)
            return TwistCommand(0.5, 0.0)

        def internals(self) -> dict[str, float]:
            return {}

    assert node.cfg.safety.max_path_error_m == 1.0
    t_ns = 2_000_000_000
    ref = node.trajectory.sample(t_ns * 1e-9)
    c, s = math.cos(ref.heading_rad), math.sin(ref.heading_rad)
    est = StateEstimate(2.0, ref.x_m - s * off_m, ref.y_m + c * off_m, ref.heading_rad, 0.5, 0.0)
    try:
        node.state = HostState.TRACKING
        node.limiter.reset(0.8, 0.0)
        node.controller = _Law()  # type: ignore[assignment]
        node.estimation.estimate = lambda: est  # type: ignore[method-assign]
        node._track(t_ns)
        sent = _frames(listener)
    finally:
        bus.shutdown()
        listener.shutdown()
    if not stops:
        assert node.state == HostState.TRACKING and calls
        return
    assert node.state == HostState.SAFE_STOP and node.stop_reason == StopReason.OFF_PATH
    assert not calls  # the law is not asked once the path is lost
    assert "max_path_error_m" in node.stats.stop_detail
    assert f"{off_m:.2f} m" in node.stats.stop_detail
    # the first frames of the stop ramp: slower than before, never faster
    speeds = [p for _n, p in sent if isinstance(p, SetInputVelAuth)]
    assert speeds and node.limiter.v_mps < 0.8


def test_the_node_refuses_a_law_built_with_other_limits_than_its_own() -> None:
    """One envelope: the law saturates with the limits the node's limiter applies."""
    spec = resolve("virtual", f"safety-ctl-{next(_chan)}")
    bus = open_bus(spec)
    traj = plan(scenario_mod.load("short").route)
    other = params.replace(SAFE_CFG, {"limits": {"v_max_mps": 1.2}}, source="test")
    law = registry.create("robust", SAFE_CFG.geometry, traj, limits=other.limits)
    try:
        with pytest.raises(ConfigError, match=r"'robust' was built with other limits"):
            ControllerNode(bus, SAFE_CFG, law, traj, IdleClock())
        ControllerNode(bus, other, law, traj, IdleClock())  # the same limits: accepted
    finally:
        bus.shutdown()


def test_authenticated_setpoints_carry_the_peak_wheel_speed_as_the_stop_reference() -> None:
    node, bus, listener = _node()
    try:
        for _ in range(3):
            node._send_setpoints(_wheels(0.8, 0.6))
        sent = _frames(listener)
    finally:
        bus.shutdown()
        listener.shutdown()
    by_node: dict[Node | None, list[SetInputVelAuth]] = {}
    for n, p in sent:
        by_node.setdefault(n, []).append(p)
    peak = max(abs(p.input_vel_revps) for n in (Node.LEFT, Node.RIGHT) for p in by_node[n][:1])
    for n in (Node.LEFT, Node.RIGHT):
        frames = by_node[n]
        assert [p.freshness for p in frames] == [1, 2, 3]  # the freshness value advances
        for p in frames:
            assert peak <= p.stop_ref_revps <= peak + 0.0101  # same reference on both drives


def test_authentication_is_the_default_and_plain_odrive_setpoints_are_sent_without_it() -> None:
    assert CFG.drives.require_auth
    node, bus, listener = _node(
        params.replace(CFG, {"drives": {"require_auth": False}}, source="test")
    )
    try:
        node._send_setpoints(_wheels(0.5, 0.0))
        sent = _frames(listener)
    finally:
        bus.shutdown()
        listener.shutdown()
    assert [type(p) for _n, p in sent] == [SetInputVel, SetInputVel]


def test_the_host_heartbeat_goes_out_at_once_when_the_state_changes() -> None:
    node, bus, listener = _node()
    try:
        node._host_heartbeat(0)
        node._host_heartbeat(10_000_000)  # within the 100 ms period: nothing
        node._set_state(HostState.ARMING)
        node._host_heartbeat(20_000_000)  # a change: at once
        sent = _frames(listener)
    finally:
        bus.shutdown()
        listener.shutdown()
    states = [p.state for _n, p in sent if isinstance(p, HostHeartbeat)]
    assert states == [HostState.INIT, HostState.ARMING]


@pytest.mark.parametrize("reason", [StopReason.ENCODER_STUCK, StopReason.ENCODER_JUMP])
def test_a_blind_speed_loop_makes_the_host_brake_both_wheels(reason: StopReason) -> None:
    node, bus, listener = _node()
    try:
        node.state = HostState.TRACKING
        node._enter_safe_stop(reason)
        sent = _frames(listener)
    finally:
        bus.shutdown()
        listener.shutdown()
    idles = {n for n, p in sent if p == SetAxisState(AxisState.IDLE)}
    assert node.state == HostState.SAFE_STOP and idles == {Node.LEFT, Node.RIGHT}


def test_a_drive_falling_out_of_closed_loop_during_a_stop_brakes_the_other() -> None:
    node, bus, listener = _node()
    try:
        node.state = HostState.TRACKING
        node.limiter.reset(1.0, 0.2)
        node._enter_safe_stop(StopReason.DRIVE_ERROR)
        for d in node.link.drives.values():
            d.axis_state = AxisState.CLOSED_LOOP_CONTROL
        node._tick_body(0)  # both still in closed loop: a coordinated ramp
        first = _frames(listener)
        node.link.drives[Node.LEFT].axis_state = AxisState.IDLE  # e.g. rebooted
        node._tick_body(10_000_000)
        second = _frames(listener)
    finally:
        bus.shutdown()
        listener.shutdown()
    assert not any(isinstance(p, SetAxisState) for _n, p in first)
    assert {n for n, p in second if p == SetAxisState(AxisState.IDLE)} == {Node.LEFT, Node.RIGHT}


# ----------------------------------------------------------- what cannot stall it


class _GarbageLaw:
    """Wraps a law; every step leaves 2000 objects in reference cycles behind."""

    def __init__(self, law: Any) -> None:
        self._law = law
        self.gc_enabled_in_step: set[bool] = set()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._law, name)

    def step(self, *a: Any) -> TwistCommand:
        self.gc_enabled_in_step.add(gc.isenabled())
        for _ in range(1000):
            x: list[Any] = []
            y: list[Any] = [x]
            x.append(y)
        return self._law.step(*a)


def _collections_during_the_loop(disable_gc: bool) -> tuple[int, set[bool]]:
    """Run bench + controller (lock-step, 3 s) and count collections while the loop ticks."""
    cfg = params.replace(CFG, {"loop": {"disable_gc": disable_gc}}, source="test")
    scen = scenario_mod.load("short")
    traj = plan(scen.route)
    law = _GarbageLaw(registry.create("baseline", cfg.geometry, traj, motor=cfg.motor))
    spec = resolve("virtual", f"safety-gc-{next(_chan)}")
    b_bus, c_bus = open_bus(spec), open_bus(spec)
    from controller.clock import LockstepClock

    collections: list[int] = []
    ticking = threading.Event()

    def on_gc(phase: str, info: dict[str, Any]) -> None:
        if phase == "start" and ticking.is_set():
            collections.append(info["generation"])

    class _Observed(LockstepClock):
        def wait_tick(self, on_frame: Any) -> int | None:
            t = super().wait_tick(on_frame)
            if t is None:
                ticking.clear()  # the loop ends; run() restores the collector after this
            else:
                ticking.set()
            return t

    try:
        clock = _Observed(c_bus, 10_000_000, codec=CODEC)
        node = ControllerNode(c_bus, cfg, law, traj, clock)
        bench = Bench(b_bus, load_bench_config({}, source="test"), duration_s=3.0)
        th = threading.Thread(target=node.run, daemon=True)
        gc.callbacks.append(on_gc)
        th.start()
        bench.run()
        th.join(30)
        ticking.clear()
    finally:
        gc.callbacks.remove(on_gc)
        b_bus.shutdown()
        c_bus.shutdown()
    assert node.stats.tracking_ticks > 100
    return len(collections), law.gc_enabled_in_step


def test_the_garbage_collector_cannot_run_inside_the_loop() -> None:
    n, enabled = _collections_during_the_loop(disable_gc=True)
    assert enabled == {False}
    assert n == 0  # 2000 cyclic objects per tick, and not one collection while ticking


def test_without_disable_gc_the_same_loop_collects_every_few_ticks() -> None:
    n, enabled = _collections_during_the_loop(disable_gc=False)
    assert enabled == {True}
    assert n > 100  # the case the loop protects itself against


class _SyntheticTime:
    """A monotonic clock and a wall clock (= monotonic + offset) that tests step by hand."""

    def __init__(self) -> None:
        self.mono_ns = 1_000_000_000
        self.wall_offset_s = 1.7e9

    def wall(self) -> float:
        return self.mono_ns * 1e-9 + self.wall_offset_s


class _SilentBus(can.BusABC):
    """A bus on which nothing arrives: a receive blocks for its whole timeout (synthetic)."""

    def __init__(self, clock: _SyntheticTime, jump_during_recv_s: float = 0.0) -> None:
        self._clock = clock
        self._jump = jump_during_recv_s
        super().__init__(channel="silent")

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        self._clock.mono_ns += round((timeout or 0.0) * 1e9)
        if self._jump:
            self._clock.wall_offset_s += self._jump
            self._jump = 0.0
        return None, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass


def _patch_clocks(monkeypatch: Any, clock: _SyntheticTime) -> None:
    monkeypatch.setattr("controller.clock.time.monotonic_ns", lambda: clock.mono_ns)
    monkeypatch.setattr("time.time", clock.wall)
    monkeypatch.setattr("time.time_ns", lambda: int(clock.wall() * 1e9))
    monkeypatch.setattr("can.bus.time", clock.wall)  # python-can's recv() timeout loop


def test_a_wall_clock_jump_does_not_move_the_real_time_loop(monkeypatch: Any) -> None:
    clock = _SyntheticTime()
    _patch_clocks(monkeypatch, clock)
    bus = _SilentBus(clock)
    try:
        rt = RealtimeClock(bus, 10_000_000)
        rt.start()
        ticks = []
        for k in range(300):
            if k == 100:
                clock.wall_offset_s += 3600.0  # NTP step forward
            if k == 200:
                clock.wall_offset_s -= 7200.0  # and back, past the start
            t = rt.wait_tick(lambda _m: None)
            assert t is not None
            ticks.append(t)
    finally:
        bus.shutdown()
    assert ticks == [k * 10_000_000 for k in range(300)]
    assert rt.stats.missed_ticks == 0


def test_a_backward_wall_clock_step_during_a_receive_on_a_silent_bus(monkeypatch: Any) -> None:
    clock = _SyntheticTime()
    _patch_clocks(monkeypatch, clock)
    bus = _SilentBus(clock, jump_during_recv_s=-60.0)
    try:
        rt = RealtimeClock(bus, 10_000_000)
        rt.start()
        for _ in range(3):
            rt.wait_tick(lambda _m: None)
    finally:
        bus.shutdown()
    assert rt.stats.missed_ticks == 0


def test_the_loop_reads_no_wall_clock() -> None:
    """Only the telemetry stamps log records with the wall clock; the loop path never does."""
    root = Path(__file__).resolve().parents[3] / "controller"
    offenders = []
    for path in sorted(root.rglob("*.py")):
        if path.name == "telemetry.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr in ("time", "time_ns", "now"):
                base = node.value
                if isinstance(base, ast.Name) and base.id in ("time", "datetime"):
                    offenders.append(f"{path.name}:{node.lineno}")
    assert offenders == []


# ----------------------------------------------------------- the configured rules


def test_the_drives_and_the_host_stop_at_the_same_rim_deceleration() -> None:
    d, lim, g = CFG.drives, CFG.limits, CFG.geometry
    rim = d.stop_decel_revps2 * 2 * math.pi * g.wheel_radius_m
    assert rim == pytest.approx(lim.safe_stop_decel_mps2, rel=0.01) == 1.0


def test_the_watchdog_is_ten_periods_and_the_limits_leave_room_for_commands() -> None:
    d, loop, lim = CFG.drives, CFG.loop, CFG.limits
    assert d.watchdog_timeout_ms == round(10 * loop.period_s * 1000)
    assert d.velocity_limit_revps * 2 * math.pi > lim.wheel_max_radps
    assert CFG.safety.heartbeat_missed_max == 3 and CFG.safety.encoder_stale_periods == 3
    assert d.host_timeout_ms == 300 and d.require_neutral_start


# ------------------------------------------------------------------ contract check


def _drives_on_the_bus(node: ControllerNode) -> None:
    for d in node.link.drives.values():
        d.heartbeats, d.encoder_msgs = 1, 1
        d.heartbeat_fresh = d.encoder_fresh = True
        d.pos_rev, d.vel_revps = 0.0, 0.0


def test_a_drive_with_another_wire_contract_is_never_armed_and_both_hashes_are_named() -> None:
    node, bus, listener = _node()
    try:
        _drives_on_the_bus(node)
        node._tick(0)  # asks both drives for their hash
        asked = [p for _n, p in _frames(listener) if isinstance(p, RxSdo)]
        assert {p.endpoint_id for p in asked} == {SdoEndpoint.CONTRACT_HASH, SdoEndpoint.FRESHNESS}
        other = node.contract_hash ^ 0x00FF0000
        node.link.drives[Node.LEFT].sdo[SdoEndpoint.CONTRACT_HASH] = node.contract_hash
        node.link.drives[Node.RIGHT].sdo[SdoEndpoint.CONTRACT_HASH] = other
        _drives_on_the_bus(node)
        node._tick(10_000_000)
        sent = _frames(listener)
    finally:
        bus.shutdown()
        listener.shutdown()
    assert node.state == HostState.FAULT
    assert node.stop_reason == StopReason.CONTRACT_MISMATCH
    assert f"{node.contract_hash:08x}" in node.stats.stop_detail
    assert f"{other:08x}" in node.stats.stop_detail and "RIGHT" in node.stats.stop_detail
    assert not any(isinstance(p, SetAxisState) for _n, p in sent)  # never armed


def test_a_drive_that_does_not_answer_is_asked_again_until_the_contract_timeout() -> None:
    """An SDO read is not acknowledged: a lost request or answer is asked again every
    CONTRACT_REASK_S, only of the drive still missing, and the arming fails at the timeout."""
    node, bus, listener = _node()
    step = round(CONTRACT_REASK_S * 1e9)
    timeout_ns = round(node.cfg.auth.contract_timeout_s * 1e9)
    asked: list[tuple[int, set[Node]]] = []
    try:
        _drives_on_the_bus(node)
        node._tick(0)
        _frames(listener)
        node.link.drives[Node.LEFT].sdo[SdoEndpoint.CONTRACT_HASH] = node.contract_hash
        t = 0
        while node.state == HostState.INIT:
            t += 10_000_000
            _drives_on_the_bus(node)
            node._tick(t)
            to = {n for n, p in _frames(listener) if isinstance(p, RxSdo)}
            if to:
                asked.append((t, to))
    finally:
        bus.shutdown()
        listener.shutdown()
    assert asked, "the silent drive was never asked again"
    assert all(to == {Node.RIGHT} for _t, to in asked)  # not the drive that answered
    times = [t for t, _to in asked]
    assert times[0] == step and all(b - a == step for a, b in itertools.pairwise(times))
    assert node.state == HostState.FAULT and node.stop_reason == StopReason.ARMING_TIMEOUT
    assert timeout_ns < t <= timeout_ns + 10_000_000
    assert "RIGHT" in node.stats.stop_detail and "LEFT" not in node.stats.stop_detail


def test_matching_contracts_arm_and_the_host_writes_its_hash_before_arming() -> None:
    node, bus, listener = _node()
    try:
        _drives_on_the_bus(node)
        node._tick(0)
        for d in node.link.drives.values():
            d.sdo[SdoEndpoint.CONTRACT_HASH] = node.contract_hash
            d.sdo[SdoEndpoint.FRESHNESS] = 41
        _drives_on_the_bus(node)
        node._tick(10_000_000)
        sent = [p for _n, p in _frames(listener)]
    finally:
        bus.shutdown()
        listener.shutdown()
    assert node.state == HostState.ARMING
    kinds = [type(p) for p in sent]
    write = next(i for i, p in enumerate(sent) if isinstance(p, RxSdo) and p.opcode == 1)
    assert sent[write].value == node.contract_hash
    assert kinds.index(SetAxisState) > write
    # every command to a drive is followed by its Host_Auth; the host continued above the
    # drive's reported freshness reference
    assert kinds.count(HostAuth) >= kinds.count(SetAxisState) + kinds.count(SetWatchdog)
    assert node.auth is not None and node.auth.fv(int(Node.LEFT)) > 41


def test_a_drive_still_idle_while_arming_is_armed_again_one_with_an_error_is_named() -> None:
    """A command is not acknowledged: a drive that reports itself idle without an error
    did not get (or did not take) its arming and is sent it again every ARM_RESEND_S,
    Host_Auth and all; a drive that reports an error is idle for that error and is not.  At
    the timeout the detail names each drive's state and error."""
    cfg = params.replace(SAFE_CFG, {"auth": {"check_contract": False}}, source="test")
    node, bus, listener = _node(cfg)
    step = round(ARM_RESEND_S * 1e9)
    resent: list[tuple[int, set[Node]]] = []
    left, right = node.link.drives[Node.LEFT], node.link.drives[Node.RIGHT]
    try:
        _drives_on_the_bus(node)
        node._tick(0)
        assert node.state == HostState.ARMING
        _frames(listener)
        t = 0
        while node.state == HostState.ARMING:
            t += 10_000_000
            _drives_on_the_bus(node)
            left.axis_state, left.axis_error = AxisState.IDLE, 0  # the arming never came
            right.axis_state, right.axis_error = AxisState.IDLE, int(AxisError.ESTOP_REQUESTED)
            node._tick(t)
            sent = _frames(listener)
            to = {n for n, p in sent if isinstance(p, SetAxisState)}
            if to:
                assert any(isinstance(p, HostAuth) for _n, p in sent)
                resent.append((t, to))
    finally:
        bus.shutdown()
        listener.shutdown()
    assert resent and all(to == {Node.LEFT} for _t, to in resent)
    times = [t for t, _to in resent]
    assert times[0] == step and all(b - a == step for a, b in itertools.pairwise(times))
    assert node.stop_reason == StopReason.ARMING_TIMEOUT
    assert node.stats.arm_resent == len(resent)
    detail = node.stats.stop_detail
    assert "drive LEFT IDLE, axis error 0x0" in detail, detail
    assert f"drive RIGHT IDLE, axis error 0x{int(AxisError.ESTOP_REQUESTED):x}" in detail, detail


def test_a_missing_key_file_is_a_start_up_error_naming_it(tmp_path: Path) -> None:
    missing = tmp_path / "no-such.key"
    cfg = params.replace(SAFE_CFG, {"auth": {"key_file": str(missing)}}, source="test")
    bus = open_bus(resolve("virtual", f"safety-ctl-{next(_chan)}"))
    try:
        traj = plan(scenario_mod.load("short").route)
        law = registry.create("baseline", cfg.geometry, traj, motor=cfg.motor)
        with pytest.raises(ConfigError, match=r"no-such\.key"):
            ControllerNode(bus, cfg, law, traj, IdleClock())
    finally:
        bus.shutdown()


# ------------------------------------------------------------------ the bus goes down


class _DownBus(can.BusABC):
    """A bus whose sends fail as SocketCAN's do on an interface that is down (or ``code``)."""

    def __init__(self, code: int = 100) -> None:
        super().__init__(channel="vcan0")
        self.channel_info = "socketcan channel 'vcan0'"
        self.code = code
        self.down = True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self.down:
            return
        try:
            raise OSError(self.code, "Network is down" if self.code == 100 else "No buffer space")
        except OSError as error:
            raise can.CanOperationError(
                f"Failed to transmit: {error.strerror}", error.errno
            ) from error

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        return None, False


def test_a_send_on_an_interface_that_is_down_makes_the_link_down_at_once_naming_it() -> None:
    bus = _DownBus()
    try:
        link = DriveLink(bus, CODEC)
        assert link.bus_down() is None
        assert not link.send(SetInputVel(0.0, 0.0), Node.LEFT)
        why = link.bus_down()
        bus.down = False
        assert link.send(SetInputVel(0.0, 0.0), Node.LEFT)
        cleared = link.bus_down()
    finally:
        bus.shutdown()
    assert why is not None and "vcan0" in why and "ENETDOWN" in why
    assert cleared is None  # one send that went out clears it


def test_other_send_failures_make_the_link_down_only_after_a_streak() -> None:
    bus = _DownBus(code=105)  # ENOBUFS: a full transmit queue
    try:
        link = DriveLink(bus, CODEC)
        for _ in range(SEND_FAIL_STREAK_DOWN - 1):
            link.send(SetInputVel(0.0, 0.0), Node.LEFT)
        early = link.bus_down()
        link.send(SetInputVel(0.0, 0.0), Node.LEFT)
        why = link.bus_down()
    finally:
        bus.shutdown()
    assert early is None
    assert why is not None and "ENOBUFS" in why and f"{SEND_FAIL_STREAK_DOWN} sends failed" in why


def test_the_host_stops_with_bus_down_and_names_the_interface_when_it_cannot_send() -> None:
    scen = scenario_mod.load("short")
    traj = plan(scen.route)
    law = registry.create("baseline", SAFE_CFG.geometry, traj, motor=SAFE_CFG.motor)
    bus = _DownBus()
    node = ControllerNode(bus, SAFE_CFG, law, traj, IdleClock())
    try:
        for k in range(6):
            node._tick(k * 10_000_000)
        node.end()
    finally:
        bus.shutdown()
    assert node.stop_reason == StopReason.BUS_DOWN
    assert node.state == HostState.FAULT  # latched: it does not re-arm when the bus comes back
    assert "vcan0" in node.stats.stop_detail and "ENETDOWN" in node.stats.stop_detail


@pytest.mark.parametrize("reason", ["rx_os_error_ENETDOWN", "rx_os_error_ENODEV"])
def test_a_receive_that_finds_the_interface_down_stops_with_bus_down_before_any_send_fails(
    reason: str,
) -> None:
    """A host descheduled while the interface went down ticks first with stale feedback and no
    failed send of its own; its receive was refused already, and names the cause."""
    node, bus, listener = _node()
    try:
        node.state = HostState.TRACKING
        node.clock.stats.rx_invalid["rx_bad_length"] = 3  # bad frames: not the bus
        assert node._receive_down() is None
        node.clock.stats.rx_invalid[reason] = 1
        node._tick_body(0)
    finally:
        bus.shutdown()
        listener.shutdown()
    assert node.stop_reason == StopReason.BUS_DOWN
    assert "the interface is down" in node.stats.stop_detail
    assert reason.removeprefix("rx_os_error_") in node.stats.stop_detail


# ------------------------------------------------------------- after the stop


def test_the_stats_name_what_caused_the_stop_not_what_the_checks_said_after_it() -> None:
    node, bus, listener = _node()
    try:
        node.state = HostState.TRACKING
        node.safety.detail = "drive LEFT encoder stale for 40 ms"
        node._enter_safe_stop(StopReason.ENCODER_STALE)
        node.state = HostState.FAULT
        # the bench ended: later ticks find the drives silent altogether
        node.safety.detail = "drive LEFT lost: no heartbeat for 2210 ms"
        node.end()
    finally:
        bus.shutdown()
        listener.shutdown()
    assert node.stats.stop_reason == "ENCODER_STALE"
    assert node.stats.stop_detail == "drive LEFT encoder stale for 40 ms"


def test_a_tick_exception_keeps_its_text_as_the_stop_detail() -> None:
    node, bus, listener = _node()
    try:
        node.state = HostState.TRACKING
        node.safety.detail = ""
        node._enter_safe_stop(StopReason.TICK_EXCEPTION, "ZeroDivisionError: float division")
        node.end()
    finally:
        bus.shutdown()
        listener.shutdown()
    assert node.stats.stop_detail == "ZeroDivisionError: float division"


@pytest.mark.parametrize("fresh", [True, False])
def test_after_a_latched_stop_only_current_feedback_of_a_turning_wheel_means_another_driver(
    fresh: bool,
) -> None:
    """A wheel that turns after the latched stop is driven by someone else: Estop again.  A
    drive that fell silent (the bench ended, the cable is off) keeps its last speed in the
    link; that says nothing about the wheel now and is not a reason to Estop."""
    node, bus, listener = _node()
    try:
        node.state = HostState.FAULT
        node.stop_reason = StopReason.ENCODER_STALE
        for d in node.link.drives.values():
            d.axis_state = AxisState.IDLE
            d.pos_rev, d.vel_revps = 0.0, 0.5
        period = node.period_ns
        for k in range(100):
            if fresh or k == 0:  # one estimate at the start, then (not fresh) silence
                for d in node.link.drives.values():
                    d.encoder_fresh = True
                    d.pos_rev += 0.5 * period * 1e-9
            node._tick_body(k * period)
        estops = [n for n, p in _frames(listener) if type(p).__name__ == "Estop"]
    finally:
        bus.shutdown()
        listener.shutdown()
    if fresh:
        assert node.safe_stop.re_estops > 0 and set(estops) == {Node.LEFT, Node.RIGHT}
    else:
        assert node.safe_stop.re_estops == 0 and estops == []
