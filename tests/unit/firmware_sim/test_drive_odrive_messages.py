"""The emulated drives answer what an ODrive 0.6 answers: RTR requests, Address, SDO reads."""

from __future__ import annotations

import pytest

from dbc.codec import (
    Address,
    AxisState,
    Codec,
    EnterDfuMode,
    Node,
    Powers,
    Request,
    RxSdo,
    SdoEndpoint,
    SdoOpcode,
    SetAbsolutePosition,
    SetInputPos,
    SetInputTorque,
    SetInputVel,
    SetPosGain,
    SetTrajAccelLimits,
    SetTrajInertia,
    SetTrajVelLimit,
    Torques,
    TxSdo,
    Version,
)
from dbc.endpoints import ODRIVE_ENDPOINTS, ValueKind, from_value
from firmware_sim.drive_reads import EMULATED_SERIAL_BASE, EMULATED_VERSION
from tests.unit.firmware_sim.test_drive import Rig
from tests.unit.firmware_sim.test_drive_safety import Chair

L, R = Node.LEFT, Node.RIGHT
CODEC = Codec.default()
REQUESTABLE = sorted(
    {b.cls for b in CODEC._by_key.values() if b.requestable and b.node == L},
    key=lambda c: c.__name__,
)


def _moving_rig() -> Rig:
    rig = Rig()
    rig.arm()
    rig.run(0.2, lambda r: [r.send(n, SetInputVel(1.0)) for n in (L, R)])
    rig.replies.clear()
    return rig


@pytest.mark.parametrize("cls", REQUESTABLE, ids=lambda c: c.__name__)
def test_every_requestable_message_is_answered_with_a_frame_the_codec_encodes(cls: type) -> None:
    rig = _moving_rig()
    for node in (L, R):
        assert rig.send(node, Request(cls))
        payload, to = rig.replies.pop()
        assert (type(payload), to) == (cls, node)
        frame = CODEC.decode(CODEC.encode(payload, node))  # in range, on the wire
        assert frame.node == node and type(frame.payload) is cls
    assert rig.sim.left.ignored == {}


def test_get_version_reports_odrive_0_6_10_and_address_the_node_and_its_serial() -> None:
    rig = Rig()
    rig.send(R, Request(Version))
    rig.send(R, Request(Address))
    assert rig.replies == [
        (EMULATED_VERSION, R),
        (Address(int(R), EMULATED_SERIAL_BASE + int(R)), R),
    ]
    v = EMULATED_VERSION
    assert (v.fw_version_major, v.fw_version_minor, v.fw_version_revision) == (0, 6, 10)


def test_an_address_frame_for_another_drive_or_the_same_node_changes_nothing() -> None:
    rig = Rig()
    d = rig.sim.left
    assert rig.send(L, Address(int(L), d.serial_number))  # its own (an echo)
    assert rig.send(L, Address(5, d.serial_number + 1))  # another drive's serial
    assert d.ignored == {}
    assert rig.send(L, Address(5, d.serial_number))  # the bench's drives keep their node
    assert d.ignored == {"address_change_unsupported": 1}
    assert d.node == L and rig.replies == []


def test_torques_and_powers_follow_the_motor_current_and_speed() -> None:
    rig = _moving_rig()
    d = rig.sim.left
    rig.send(L, Request(Torques))
    rig.send(L, Request(Powers))
    (torques, _), (powers, _) = rig.replies
    k = rig.sim.config.motor.torque_constant_nm_per_a
    assert torques.estimate_nm == pytest.approx(k * rig.sim.plant.left.current_a)
    assert torques.target_nm == pytest.approx(k * d.iq_setpoint_a)
    assert powers.electrical_w == pytest.approx(d.bus_voltage_v * d.bus_current_a)
    assert powers.mechanical_w > 0.0  # driving forward: positive torque at positive speed


@pytest.mark.parametrize("path", sorted(ODRIVE_ENDPOINTS))
def test_every_emulated_endpoint_answers_an_sdo_read(path: str) -> None:
    rig = _moving_rig()
    ep = ODRIVE_ENDPOINTS[path]
    assert rig.send(L, RxSdo(SdoOpcode.READ, ep.id))
    ((reply, to),) = rig.replies
    assert to == L and type(reply) is TxSdo and reply.endpoint_id == ep.id
    assert CODEC.decode(CODEC.encode(reply, L)).payload == reply
    value = from_value(ep.kind, reply.value)
    assert (
        type(value) is {ValueKind.FLOAT: float, ValueKind.UINT: int, ValueKind.BOOL: bool}[ep.kind]
    )


def test_sdo_reads_return_the_drive_state() -> None:
    rig = _moving_rig()
    d = rig.sim.left

    def read(path: str) -> float | int | bool:
        ep = ODRIVE_ENDPOINTS[path]
        rig.send(L, RxSdo(SdoOpcode.READ, ep.id))
        return from_value(ep.kind, rig.replies.pop()[0].value)

    assert read("axis0.current_state") == AxisState.CLOSED_LOOP_CONTROL
    assert read("axis0.config.can.node_id") == 1
    assert read("vbus_voltage") == pytest.approx(rig.sim.config.motor.bus_voltage_v)
    assert read("axis0.controller.config.vel_gain") == pytest.approx(d.rt.kp)
    assert read("axis0.controller.config.vel_limit") == pytest.approx(d.rt.vel_limit_revps)
    assert read("axis0.controller.input_vel") == 1.0
    assert read("axis0.vel_estimate") == pytest.approx(d.encoder.vel_revps)
    assert read("fw_version_minor") == 6 and read("fw_version_revision") == 10
    assert read("axis0.config.enable_watchdog") is (d.rt.wd_timeout_ms > 0)


def test_an_unknown_endpoint_gets_no_answer_and_is_counted() -> None:
    rig = Rig()
    assert rig.send(L, RxSdo(SdoOpcode.READ, 999))
    assert rig.send(
        L, RxSdo(SdoOpcode.WRITE, ODRIVE_ENDPOINTS["axis0.controller.config.vel_gain"].id, 1)
    )
    assert rig.replies == []
    assert rig.sim.left.ignored == {"unsupported_endpoint": 2}


def test_the_project_endpoints_still_answer_and_lie_outside_odrives() -> None:
    rig = Rig()
    rig.send(L, RxSdo(SdoOpcode.READ, SdoEndpoint.CONTRACT_HASH))
    assert rig.replies == [(TxSdo(SdoEndpoint.CONTRACT_HASH, rig.sim.left.contract_hash), L)]
    ids = [e.id for e in ODRIVE_ENDPOINTS.values()]
    assert len(set(ids)) == len(ids)
    assert max(ids) < min(SdoEndpoint)


@pytest.mark.parametrize(
    "command",
    [
        SetInputPos(3.0, 0.5, 0.25),
        SetInputTorque(2.0),
        SetTrajVelLimit(2.0),
        SetTrajAccelLimits(1.0, 1.0),
        SetTrajInertia(0.1),
        SetAbsolutePosition(10.0),
        SetPosGain(20.0),
        EnterDfuMode(),
    ],
    ids=lambda c: type(c).__name__,
)
def test_commands_of_other_control_modes_are_ignored_and_counted(command: object) -> None:
    rig = _moving_rig()
    d = rig.sim.left
    before = (d.state, d.input_vel_revps, d.input_torque_ff_nm, d.encoder.pos_rev)
    assert rig.send(L, command)
    assert (d.state, d.input_vel_revps, d.input_torque_ff_nm, d.encoder.pos_rev) == before
    assert d.ignored == {"unsupported_command": 1}
    assert rig.replies == []


def test_with_require_auth_those_commands_need_their_host_auth_like_any_other() -> None:
    chair = Chair()
    d = chair.sim.left
    chair.forge(L, SetInputTorque(5.0))  # a foreign node, no Host_Auth
    chair.forge(L, EnterDfuMode())
    chair.step(3)
    assert d.ignored["auth_missing"] == 2
    assert "unsupported_command" not in d.ignored
    chair.send(L, SetInputTorque(5.0))  # the key holder: authenticated, then ignored
    assert d.ignored["unsupported_command"] == 1
    assert d.state == AxisState.CLOSED_LOOP_CONTROL
