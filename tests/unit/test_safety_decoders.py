"""Property-based tests of every receive path: arbitrary IDs, lengths and payloads.

Nothing raises out of the codec (other than :class:`DecodeError`), the bench's receive path
and drives, the controller's link and loop, or the lock-step clock; and no frame makes a
drive or the controller produce a non-finite or out-of-range command.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import typing
from typing import Any

import can
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.clock import LockstepClock
from controller.config import load_config
from controller.node import ControllerNode
from controller.planner import plan
from controller.tracking import registry
from dbc.codec import (
    AxisState,
    BenchEnd,
    Codec,
    HostState,
    Node,
    Request,
    SetAxisState,
    SetInputVel,
    SetInputVelAuth,
)
from dbc.errors import DecodeError
from dbc.runtime import params
from firmware_sim.bench import Bench
from firmware_sim.config import load_bench_config
from tests.unit.idle_clock import IdleClock
from tools.bus.transport import open_bus, resolve
from tools.run import scenario as scenario_mod

CODEC = Codec.default()
KNOWN = sorted({(CODEC.frame_id(cls, n), n is None) for cls, n, _name in CODEC.all_messages()})
_chan = itertools.count()


def _example(cls: type, node: Node | None) -> Any:
    """An in-range payload of ``cls`` (37 % into every signal's range)."""
    bound = CODEC._bound(cls, node)
    hints = typing.get_type_hints(cls)
    kw: dict[str, Any] = {}
    for fname, _sig, lo, hi, _unit in bound.limits:
        t = hints[fname]
        if isinstance(t, type) and issubclass(t, int) and t not in (int, bool):
            kw[fname] = next(m for m in t if lo <= int(m) <= hi)
        elif t is bool:
            kw[fname] = False
        else:
            v = max(lo, -1000.0) + (min(hi, 1000.0) - max(lo, -1000.0)) * 0.37
            kw[fname] = int(v) if t is int else v
    return cls(**kw)


VALID = [CODEC.encode(_example(cls, n), n) for cls, n, _name in CODEC.all_messages()]


@st.composite
def frames(draw: Any) -> can.Message:
    """Random frames, valid frames with mutated bytes, and random bytes on the DBC's IDs."""
    kind = draw(st.sampled_from(["random", "known-id", "mutated"]))
    if kind == "mutated":
        base = draw(st.sampled_from(VALID))
        data = bytearray(base.data)
        for i, b in draw(st.lists(st.tuples(st.integers(0, 7), st.integers(0, 255)), max_size=3)):
            if i < len(data):
                data[i] = b
        return can.Message(
            arbitration_id=base.arbitration_id,
            is_extended_id=base.is_extended_id,
            data=bytes(data),
            dlc=len(data),
        )
    if kind == "known-id":
        aid, ext = draw(st.sampled_from(KNOWN))
    else:
        ext = draw(st.booleans())
        aid = draw(st.integers(0, 0x1FFFFFFF if ext else 0x7FF))
    if draw(st.integers(0, 19)) == 0:
        return can.Message(
            arbitration_id=aid,
            is_extended_id=ext,
            is_remote_frame=True,
            dlc=draw(st.integers(0, 8)),
        )
    data = draw(st.binary(max_size=draw(st.sampled_from([8, 8, 8, 64]))))
    return can.Message(
        arbitration_id=aid,
        is_extended_id=ext,
        data=data,
        dlc=min(len(data), 8) if draw(st.booleans()) else draw(st.integers(0, 15)),
        is_error_frame=draw(st.integers(0, 29)) == 0,
        check=False,
    )


def _finite_fields(payload: Any) -> bool:
    if not dataclasses.is_dataclass(payload):
        return True
    return all(
        math.isfinite(v)
        for f in dataclasses.fields(payload)
        if isinstance(v := getattr(payload, f.name), float)
    )


# ------------------------------------------------------------------------- codec


@settings(max_examples=600, deadline=None)
@given(frames())
def test_the_codec_decodes_or_raises_decode_error_and_never_lets_a_bad_value_through(
    msg: can.Message,
) -> None:
    try:
        frame = CODEC.decode(msg)
    except DecodeError as err:
        assert err.reason
        return
    if isinstance(frame.payload, Request):
        assert msg.is_remote_frame
        return
    assert _finite_fields(frame.payload)
    bound = CODEC._bound(type(frame.payload), frame.node)
    for fname, _sig, lo, hi, _unit in bound.limits:
        v = getattr(frame.payload, fname)
        assert lo <= v <= hi, (fname, v)


@settings(max_examples=300, deadline=None)
@given(frames())
def test_decode_signals_agrees_with_decode(msg: can.Message) -> None:
    try:
        CODEC.decode(msg)
        ok = True
    except DecodeError:
        ok = False
    try:
        CODEC.decode_signals(msg)
        ok2 = True
    except DecodeError:
        ok2 = False
    assert ok == ok2


# --------------------------------------------------------------- bench and drives


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(st.lists(frames(), min_size=1, max_size=40))
def test_the_bench_receive_path_never_raises_and_the_drives_stay_within_limits(
    msgs: list[can.Message],
) -> None:
    spec = resolve("virtual", f"prop-bench-{next(_chan)}")
    bus = open_bus(spec)
    try:
        bench = Bench(bus, load_bench_config({}, source="test"), duration_s=1.0)
        sim = bench.sim
        # armed, moving drives: the state a stray frame is most dangerous in
        for n in (Node.LEFT, Node.RIGHT):
            bench._on_message(CODEC.encode(SetInputVel(0.0), n))
        for n in (Node.LEFT, Node.RIGHT):
            bench._on_message(CODEC.encode(SetAxisState(AxisState.CLOSED_LOOP_CONTROL), n))
            bench._on_message(CODEC.encode(SetInputVel(0.3), n))
        sim.advance()
        for m in msgs:
            bench._on_message(m)
        sim.advance()
        stats = bench.stats
        assert "internal" not in stats.frames_rejected_by_reason
        assert "handler_error" not in stats.frames_rejected_by_reason
        for d in (sim.left, sim.right):
            assert math.isfinite(d.input_vel_revps) and abs(d.input_vel_revps) <= 20.0
            assert math.isfinite(d.vel_setpoint_revps)
            assert abs(d.vel_setpoint_revps) <= d.rt.vel_limit_revps + 1e-12
            assert math.isfinite(d.iq_setpoint_a)
            assert abs(d.iq_setpoint_a) <= d.rt.current_limit_a + 1e-9
        p = sim.plant
        assert math.isfinite(p.x_m + p.y_m + p.left.omega_radps + p.right.omega_radps)
    finally:
        bus.shutdown()


# ------------------------------------------------------------ controller side

_CFG = params.replace(load_config(), {"drives": {"require_auth": True}}, source="test")
_TRAJ = plan(scenario_mod.load("short").route)


@settings(max_examples=150, deadline=None)
@given(st.lists(frames(), min_size=1, max_size=40))
def test_the_controller_never_raises_and_never_sends_a_bad_setpoint(
    msgs: list[can.Message],
) -> None:
    spec = resolve("virtual", f"prop-ctl-{next(_chan)}")
    bus, listener = open_bus(spec), open_bus(spec)
    try:
        law = registry.create("baseline", _CFG.geometry, _TRAJ, motor=_CFG.motor)
        node = ControllerNode(bus, _CFG, law, _TRAJ, IdleClock())
        node.state = HostState.TRACKING
        node._tracking_start_ns = 0
        node.limiter.reset(0.8, 0.2)
        for k, m in enumerate(msgs):
            node.link.on_frame(m)
            if k % 10 == 9:
                node._tick((k + 1) * 1_000_000)
        node._tick(100_000_000)
        assert "internal" not in node.link.counters.rejected
        assert node.stats.exceptions == 0
        lim = _CFG.drives.velocity_limit_revps
        while (m := listener.recv(0.0)) is not None:
            _n, p = CODEC.decode(m)  # everything the controller sends decodes
            if isinstance(p, SetInputVelAuth | SetInputVel):
                assert math.isfinite(p.input_vel_revps) and abs(p.input_vel_revps) <= lim
    finally:
        bus.shutdown()
        listener.shutdown()


class _ScriptBus(can.BusABC):
    """Delivers a fixed list of frames, then Bench_End."""

    def __init__(self, msgs: list[can.Message]) -> None:
        self._msgs = [*msgs, CODEC.encode(BenchEnd(0))]
        super().__init__(channel="script")

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return (self._msgs.pop(0) if self._msgs else None), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass


@settings(max_examples=200, deadline=None)
@given(st.lists(frames(), max_size=30))
def test_the_lock_step_clock_never_raises(msgs: list[can.Message]) -> None:
    bus = _ScriptBus(msgs)
    try:
        clock = LockstepClock(bus, 10_000_000, codec=CODEC, idle_timeout_s=0.1)
        clock.start()
        seen: list[can.Message] = []
        for _ in range(len(msgs) + 2):
            if clock.wait_tick(seen.append) is None:
                break
    finally:
        bus.shutdown()
