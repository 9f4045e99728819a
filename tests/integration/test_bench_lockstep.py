"""The bench on python-can's virtual bus against a tiny scripted host (lock-step and real time)."""

from __future__ import annotations

import threading
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can
import pytest

from dbc.codec import (
    Address,
    AxisError,
    AxisState,
    BenchEnd,
    BenchStep,
    BenchStepAck,
    Codec,
    EncoderCount,
    EncoderEstimates,
    Heartbeat,
    Node,
    PoseFix,
    Powers,
    SetAxisState,
    SetInputVel,
    SetInputVelAuth,
    SetWatchdog,
    Torques,
    TruthPose,
    TruthTwist,
    TruthWheels,
    TxSdo,
    Version,
)
from dbc.endpoints import ODRIVE_ENDPOINTS, from_value
from dbc.errors import DecodeError
from firmware_sim.bench import Bench, BenchHandshakeError, BenchStats
from firmware_sim.config import load_bench_config
from firmware_sim.drive_reads import EMULATED_VERSION
from tests.unit.dbc.test_odrive_cansimple import ODRIVE

CODEC = Codec.default()
MS = 1_000_000
TRUTH = (TruthPose, TruthTwist, TruthWheels, PoseFix)

Setpoints = Callable[[int], tuple[float, float] | None]


@dataclass
class HostLog:
    """Everything the scripted host saw, by payload type, in arrival order."""

    frames: list[tuple[Node | None, Any]] = field(default_factory=list)
    raw_truth: list[tuple[int, bytes]] = field(default_factory=list)
    step_times: list[int] = field(default_factory=list)

    def last(self, cls: type, node: Node | None = None) -> Any:
        for n, p in reversed(self.frames):
            if type(p) is cls and (node is None or n == node):
                return p
        raise AssertionError(f"host never received {cls.__name__} from {node!r}")

    def all(self, cls: type, node: Node | None = None) -> list[Any]:
        return [p for n, p in self.frames if type(p) is cls and (node is None or n == node)]


class ScriptedHost(threading.Thread):
    """Arms the drives at t = 0, sends ``setpoints(t)`` each step, acks each Bench_Step.

    ``arm`` lists the nodes to arm, ``extra(t)`` returns further frames to send in
    the tick at ``t``, ``ack_until_ns`` stops acking after that time (the setpoints go on),
    ``quiet_after_ns`` stops sending anything after that time (a host that went away).
    """

    def __init__(
        self,
        bus: can.BusABC,
        *,
        setpoints: Setpoints,
        arm: tuple[Node, ...] = (Node.LEFT, Node.RIGHT),
        extra: Callable[[int], list[can.Message]] | None = None,
        ack_until_ns: int | None = None,
        quiet_after_ns: int | None = None,
    ) -> None:
        super().__init__(daemon=True)
        self.bus = bus
        self.setpoints = setpoints
        self.arm = arm
        self.extra = extra
        self.ack_until_ns = ack_until_ns
        self.quiet_after_ns = quiet_after_ns
        self.log = HostLog()
        self.error: BaseException | None = None
        self._quit = threading.Event()
        self._last_t: int | None = None

    def stop(self) -> None:
        self._quit.set()

    def run(self) -> None:
        try:
            while not self._quit.is_set():
                msg = self.bus.recv(0.05)
                if msg is None:
                    continue
                try:
                    frame = CODEC.decode(msg)
                except DecodeError:
                    continue
                p = frame.payload
                self.log.frames.append((frame.node, p))
                if type(p) in TRUTH:
                    self.log.raw_truth.append((msg.arbitration_id, bytes(msg.data)))
                if type(p) is BenchEnd:
                    return
                if type(p) is BenchStep:
                    self._tick(p.sim_time_ns)
        except BaseException as err:  # surfaced by the test
            self.error = err

    def _tick(self, t: int) -> None:
        if self.quiet_after_ns is not None and t > self.quiet_after_ns:
            self._last_t = t
            self.log.step_times.append(t)
            return
        if t != self._last_t:  # a repeated Bench_Step(0) during the handshake is only re-acked
            self._last_t = t
            self.log.step_times.append(t)
            if t == 0:
                for node in self.arm:
                    self.bus.send(CODEC.encode(SetAxisState(AxisState.CLOSED_LOOP_CONTROL), node))
            for msg in self.extra(t) if self.extra else ():
                self.bus.send(msg)
            sp = self.setpoints(t)
            if sp is not None:
                for node, v in zip((Node.LEFT, Node.RIGHT), sp, strict=True):
                    if node in self.arm:
                        self.bus.send(CODEC.encode(SetInputVel(v), node))
        if self.ack_until_ns is None or t <= self.ack_until_ns:
            self.bus.send(CODEC.encode(BenchStepAck(t)))


def run_bench(
    *,
    duration_s: float,
    setpoints: Setpoints = lambda t: (0.3, 0.4),
    overrides: dict[str, Any] | None = None,
    seed: int = 0,
    realtime: bool = False,
    **host_kw: Any,
) -> tuple[BenchStats, HostLog]:
    channel = f"bench-test-{uuid.uuid4()}"
    # a stock (unauthenticated) ODrive: these tests script plain frames against the bench's
    # lock-step protocol; authentication is tests/unit/test_drive_safety.py's and the suite's
    stock = {"drive.require_auth": False, "drive.check_contract": False}
    cfg = load_bench_config({**stock, **(overrides or {})}, source="test")
    with (
        can.Bus(interface="virtual", channel=channel) as host_bus,
        can.Bus(interface="virtual", channel=channel) as bench_bus,
    ):
        host = ScriptedHost(host_bus, setpoints=setpoints, **host_kw)
        host.start()
        try:
            bench = Bench(bench_bus, cfg, duration_s=duration_s, seed=seed, realtime=realtime)
            stats = bench.run()
        finally:
            host.join(timeout=5.0)
            host.stop()
            host.join(timeout=5.0)
    assert host.error is None, host.error
    return stats, host.log


def test_both_drives_arm_and_their_encoders_follow_the_setpoints() -> None:
    stats, log = run_bench(duration_s=2.0)
    for node in (Node.LEFT, Node.RIGHT):
        hb = log.last(Heartbeat, node)
        assert hb.axis_state == AxisState.CLOSED_LOOP_CONTROL
        assert hb.axis_error == 0
    assert log.last(EncoderEstimates, Node.LEFT).vel_revps == pytest.approx(0.3, rel=0.01)
    assert log.last(EncoderEstimates, Node.RIGHT).vel_revps == pytest.approx(0.4, rel=0.01)
    # A faster right wheel turns the chair counter-clockwise.
    assert log.last(TruthTwist).omega_radps > 0.1
    assert stats.steps == 200
    assert stats.missed_acks == 0
    assert stats.frames_rejected_by_reason == {}
    assert log.step_times == [k * 10 * MS for k in range(201)]


def test_lockstep_runs_with_the_same_seed_are_identical() -> None:
    def profile(t: int) -> tuple[float, float]:
        return (0.2, 0.2) if t < 500 * MS else (0.1, 0.35)

    _, a = run_bench(duration_s=1.0, setpoints=profile, seed=7)
    _, b = run_bench(duration_s=1.0, setpoints=profile, seed=7)
    _, c = run_bench(duration_s=1.0, setpoints=profile, seed=8)
    assert len(a.raw_truth) > 200
    assert a.raw_truth == b.raw_truth
    # The seed only changes the localizer's noise, not the physics.
    assert a.all(TruthPose) == c.all(TruthPose)
    assert a.all(PoseFix) != c.all(PoseFix)


def test_watchdog_trips_and_brakes_when_the_host_stops_sending_setpoints() -> None:
    def watchdog(t: int) -> list[can.Message]:
        if t != 0:
            return []
        cfg = SetWatchdog(timeout_ms=100, stop_decel_revps2=2.0, require_auth=False)
        return [CODEC.encode(cfg, n) for n in (Node.LEFT, Node.RIGHT)]

    stats, log = run_bench(
        duration_s=2.0,
        setpoints=lambda t: (0.3, 0.3) if t < 800 * MS else None,
        extra=watchdog,
    )
    for node in (Node.LEFT, Node.RIGHT):
        hb = log.last(Heartbeat, node)
        assert hb.axis_state == AxisState.IDLE
        assert hb.axis_error & AxisError.WATCHDOG_TIMER_EXPIRED
        assert abs(log.last(EncoderEstimates, node).vel_revps) < 0.01
        states = [h.axis_state for h in log.all(Heartbeat, node)]
        assert AxisState.CLOSED_LOOP_CONTROL in states
    assert stats.missed_acks == 0


def test_a_drive_ignores_frames_for_the_other_node() -> None:
    _, log = run_bench(duration_s=0.5, arm=(Node.LEFT,))
    assert log.last(Heartbeat, Node.LEFT).axis_state == AxisState.CLOSED_LOOP_CONTROL
    assert log.last(Heartbeat, Node.RIGHT).axis_state == AxisState.IDLE
    assert log.last(EncoderEstimates, Node.LEFT).vel_revps > 0.25
    # The idle right wheel is held by its brake while the chair pivots about it.
    assert abs(log.last(EncoderEstimates, Node.RIGHT).pos_rev) < 0.001


def test_garbage_frames_are_counted_as_rejected_and_nothing_raises() -> None:
    good_auth = CODEC.encode(SetInputVelAuth(0.1, 0.1, 1, 0), Node.LEFT)
    out_of_range = bytearray(good_auth.data)
    out_of_range[0:2] = b"\x00\x80"  # Input_Vel raw -32768, below -3.2767 rev/s
    setpoint_id = CODEC.frame_id(SetInputVel, Node.LEFT)

    def garbage(t: int) -> list[can.Message]:
        if t != 100 * MS:
            return []
        return [
            can.Message(arbitration_id=0x7FF, data=b"\x01\x02", is_extended_id=False),
            can.Message(arbitration_id=setpoint_id, data=b"\x00\x00\x80", is_extended_id=False),
            can.Message(
                arbitration_id=good_auth.arbitration_id, data=out_of_range, is_extended_id=False
            ),
        ]

    stats, log = run_bench(duration_s=0.3, extra=garbage)
    assert stats.frames_rejected_by_reason == {"unknown_id": 1, "length": 1, "range": 1}
    assert stats.steps == 30
    assert log.last(Heartbeat, Node.LEFT).axis_state == AxisState.CLOSED_LOOP_CONTROL


def test_rtr_requests_are_answered_in_the_same_step() -> None:
    def ask(t: int) -> list[can.Message]:
        return [CODEC.request(EncoderCount, Node.RIGHT)] if t == 200 * MS else []

    _, log = run_bench(duration_s=0.3, extra=ask)
    counts = log.all(EncoderCount, Node.RIGHT)
    assert len(counts) == 1
    assert counts[0].shadow_count > 0
    assert counts[0].count_in_cpr == counts[0].shadow_count % 8192


def test_missed_acks_are_counted_and_the_drives_watchdog_acts_in_sim_time() -> None:
    def watchdog(t: int) -> list[can.Message]:
        cfg = SetWatchdog(timeout_ms=50, stop_decel_revps2=0.0, require_auth=False)
        return [CODEC.encode(cfg, n) for n in (Node.LEFT, Node.RIGHT)] if t == 0 else []

    stats, log = run_bench(
        duration_s=0.5,
        extra=watchdog,
        quiet_after_ns=100 * MS,
        overrides={"bench.ack_timeout_s": 0.05, "bench.give_up_after_missed_acks": 3},
    )
    # The host sends nothing after t = 0.1 s (no setpoint feeds the watchdog, whatever the
    # two threads' pace), so the drives' 50 ms watchdog expires in simulation time.
    # Awaited after the host went quiet: t = 0.11 ... 0.49 in the loop, then the final 0.5.
    assert stats.missed_acks == 40
    assert stats.steps == 50
    assert log.last(Heartbeat, Node.LEFT).axis_state == AxisState.IDLE
    assert log.last(Heartbeat, Node.LEFT).axis_error & AxisError.WATCHDOG_TIMER_EXPIRED


def test_handshake_without_a_controller_raises_a_clear_error() -> None:
    cfg = load_bench_config({"bench.handshake_timeout_s": 0.2}, source="test")
    with can.Bus(interface="virtual", channel=f"bench-test-{uuid.uuid4()}") as bus:
        bench = Bench(bus, cfg, duration_s=1.0)
        with pytest.raises(BenchHandshakeError, match="handshake_timeout_s"):
            bench.run()


def test_realtime_mode_publishes_every_step_without_waiting_for_acks() -> None:
    stats, log = run_bench(duration_s=0.2, realtime=True, ack_until_ns=-1)
    assert stats.steps == 20
    assert stats.missed_acks == 0
    assert log.step_times == [k * 10 * MS for k in range(21)]
    assert isinstance(log.last(BenchEnd), BenchEnd)


def test_a_stop_event_ends_the_run_early_with_bench_end() -> None:
    stop = threading.Event()
    stop.set()
    channel = f"bench-test-{uuid.uuid4()}"
    cfg = load_bench_config(None, source="test")
    with (
        can.Bus(interface="virtual", channel=channel) as host_bus,
        can.Bus(interface="virtual", channel=channel) as bench_bus,
    ):
        stats = Bench(bench_bus, cfg, duration_s=10.0, stop_event=stop, realtime=True).run()
        names = []
        while (msg := host_bus.recv(0.0)) is not None:
            names.append(type(CODEC.decode(msg).payload).__name__)
    assert stats.stopped_early
    assert stats.steps == 0
    assert names[-1] == "BenchEnd"


def test_a_failing_simulation_ends_the_run_cleanly_with_bench_end() -> None:
    channel = f"bench-test-{uuid.uuid4()}"
    cfg = load_bench_config(None, source="test")

    def broken_fault(t_ns: int, _plant: object) -> None:
        if t_ns >= 50 * MS:
            raise ZeroDivisionError("fault model bug")

    with (
        can.Bus(interface="virtual", channel=channel) as host_bus,
        can.Bus(interface="virtual", channel=channel) as bench_bus,
    ):
        host = ScriptedHost(host_bus, setpoints=lambda t: (0.1, 0.1))
        host.start()
        bench = Bench(bench_bus, cfg, duration_s=1.0)
        bench.sim.add_tick_hook(broken_fault)
        stats = bench.run()
        host.join(timeout=5.0)
        host.stop()
    assert stats.steps == 5
    assert stats.aborted is not None and "fault model bug" in stats.aborted
    assert host.log.last(BenchEnd).sim_time_ns == 50 * MS


def test_a_host_speaking_odrives_own_definition_is_answered_and_nothing_is_rejected() -> None:
    # frames built with cantools from ODrive's 0.6.10 DBC, as an ODrive tool would send them
    vel_gain = ODRIVE_ENDPOINTS["axis0.controller.config.vel_gain"]

    def odrive_tool(t: int) -> list[can.Message]:
        if t != 100 * MS:
            return []
        out = [
            can.Message(
                arbitration_id=ODRIVE.get_message_by_name(f"Axis1_{name}").frame_id,
                is_remote_frame=True,
                dlc=8,
                is_extended_id=False,
            )
            for name in ("Get_Version", "Address", "Get_Torques", "Get_Powers")
        ]
        for name, values in (
            ("RxSdo", {"Opcode": 0, "Endpoint_ID": vel_gain.id, "Reserved": 0, "Value": 0}),
            ("Clear_Errors", {"Identify": 0}),
            ("Set_Input_Torque", {"Input_Torque": 0.5}),
            ("Set_Traj_Vel_Limit", {"Traj_Vel_Limit": 2.0}),
        ):
            m = ODRIVE.get_message_by_name(f"Axis2_{name}")
            out.append(
                can.Message(arbitration_id=m.frame_id, data=m.encode(values), is_extended_id=False)
            )
        return out

    stats, log = run_bench(duration_s=0.3, extra=odrive_tool)
    assert stats.frames_rejected_by_reason == {}
    assert log.last(Version, Node.LEFT) == EMULATED_VERSION
    assert log.last(Address, Node.LEFT).node_id == 1
    assert type(log.last(Torques, Node.LEFT).estimate_nm) is float
    assert type(log.last(Powers, Node.LEFT).electrical_w) is float
    reply = log.last(TxSdo, Node.RIGHT)
    assert reply.endpoint_id == vel_gain.id
    default_gain = load_bench_config({}, source="test").drive.vel_gain
    assert from_value(vel_gain.kind, reply.value) == pytest.approx(default_gain)
    assert log.last(Heartbeat, Node.RIGHT).axis_state == AxisState.CLOSED_LOOP_CONTROL
