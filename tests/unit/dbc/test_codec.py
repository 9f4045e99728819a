"""The wire contract: DBC <-> typed codec, strict both ways."""

from __future__ import annotations

import ast
import dataclasses
import hmac
import math
import struct
import typing
from pathlib import Path
from typing import Any

import can
import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbc import codec as C
from dbc import messages as M
from dbc.errors import DbcError, DecodeError, EncodeError
from dbc.secoc import Authenticator, Verifier, load_key

CODEC = C.Codec.default()
KEY = load_key(C.DBC_PATH.parent / "keys" / "TEST-ONLY-secoc.key")


def _sample_value(bound_min: float, bound_max: float, typ: type, i: int) -> typing.Any:
    """A deterministic in-range value for a field type."""
    if isinstance(typ, type) and issubclass(typ, C.enum.IntEnum):
        members = [m for m in typ if bound_min <= int(m) <= bound_max]
        return members[i % len(members)]
    if typ is bool:
        return bool(i % 2)
    lo, hi = max(bound_min, -1000.0), min(bound_max, 1000.0)
    if typ is int:
        return int(lo + (hi - lo) * 0.37)
    return lo + (hi - lo) * 0.37


def _example(cls: type, node: C.Node | None) -> typing.Any:
    bound = CODEC._bound(cls, node)
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for i, (fname, _sig, lo, hi, _unit) in enumerate(bound.limits):
        kwargs[fname] = _sample_value(lo, hi, hints[fname], i)
    return cls(**kwargs)


ALL = CODEC.all_messages()


@pytest.mark.parametrize(("cls", "node", "name"), ALL, ids=[n for _c, _n, n in ALL])
def test_every_message_round_trips(cls: type, node: C.Node | None, name: str) -> None:
    payload = _example(cls, node)
    msg = CODEC.encode(payload, node)
    frame = CODEC.decode(msg)
    assert frame.node == node
    assert type(frame.payload) is cls
    for f in dataclasses.fields(cls):
        a, b = getattr(payload, f.name), getattr(frame.payload, f.name)
        if f.name == "crc":
            continue
        if isinstance(a, float):
            # float32 or a scaled integer: equal to the signal's resolution
            sig = {s.name: s for s in CODEC.db.get_message_by_name(name).signals}
            res = max(abs(sig[dict(CODEC._bound(cls, node).fields)[f.name]].scale), abs(a) * 2**-23)
            assert b == pytest.approx(a, abs=res)
        else:
            assert a == b


def test_standard_ids_are_node_shifted_by_five_plus_command() -> None:
    for cls, node, name in ALL:
        m = CODEC.db.get_message_by_name(name)
        if node is None:
            assert m.is_extended_frame, name
            continue
        assert not m.is_extended_frame
        assert m.frame_id >> 5 == int(node), name
        spec = next(s for s in M.SPECS if s.cls is cls)
        assert m.frame_id & 0x1F == spec.cmd


def test_extensions_use_only_the_command_ids_odrive_06_leaves_free() -> None:
    # ODrive 0.6 CAN Simple uses every command ID but 0x08, 0x0A, 0x10 and 0x1E
    assert {0x08, 0x0A, 0x10, 0x1E} == C.ODRIVE_06_FREE_CMDS
    assert len(C.ODRIVE_06_CMDS) == 28
    for spec in M.SPECS:
        if spec.cmd is None:
            continue
        if spec.nodes != C.DRIVES:  # localizer and host frames: extensions only
            assert spec.cmd in C.ODRIVE_06_FREE_CMDS, spec.suffix


def test_every_odrive_06_command_is_in_the_contract_for_both_drives() -> None:
    drive_cmds = {spec.cmd for spec in M.SPECS if spec.nodes == C.DRIVES}
    assert drive_cmds - C.ODRIVE_06_FREE_CMDS == C.ODRIVE_06_CMDS
    for cmd in C.ODRIVE_06_CMDS:
        for node in C.DRIVES:
            m = CODEC.db.get_message_by_frame_id(int(node) << 5 | cmd)
            assert not m.is_extended_frame, m.name


def test_every_message_has_a_sender_and_cycle_times_only_on_cyclic_messages() -> None:
    cyclic = {
        "Heartbeat",
        "Get_Encoder_Estimates",
        "Set_Input_Vel",
        "Set_Input_Vel_Auth",
        "Get_Iq",
        "Get_Bus_Voltage_Current",
        "Pose_Fix",
        "Diagnosis",
        "Bench_Step",
        "Bench_Truth_Pose",
        "Bench_Truth_Twist",
        "Bench_Truth_Wheels",
        "Bench_Truth_Contact",
    }
    nodes = {n.name for n in CODEC.db.nodes}
    for m in CODEC.db.messages:
        assert m.senders and set(m.senders) <= nodes, m.name
        base = m.name.split("_", 1)[1] if not m.name.startswith("Bench") else m.name
        if base in cyclic or m.name in cyclic:
            assert m.cycle_time, m.name
        else:
            assert not m.cycle_time, m.name


def test_set_input_vel_units_are_revolutions_per_second_and_newton_metres() -> None:
    for side in ("Left", "Right"):
        sigs = {s.name: s for s in CODEC.db.get_message_by_name(f"{side}_Set_Input_Vel").signals}
        assert sigs["Input_Vel"].unit == "rev/s"
        assert sigs["Input_Torque_FF"].unit == "Nm"


def test_dump_reload_compare(tmp_path: Path) -> None:
    out = tmp_path / "dumped.dbc"
    cantools.database.dump_file(CODEC.db, str(out), database_format="dbc")
    again = C.Codec(out)
    assert [m.name for m in again.db.messages] == [m.name for m in CODEC.db.messages]
    for a, b in zip(CODEC.db.messages, again.db.messages, strict=True):
        assert (a.frame_id, a.is_extended_frame, a.length, a.senders, a.cycle_time) == (
            b.frame_id,
            b.is_extended_frame,
            b.length,
            b.senders,
            b.cycle_time,
        )
        for sa, sb in zip(a.signals, b.signals, strict=True):
            assert (
                sa.name,
                sa.start,
                sa.length,
                sa.byte_order,
                sa.is_signed,
                sa.is_float,
                sa.scale,
                sa.offset,
                sa.minimum,
                sa.maximum,
                sa.unit,
                sa.choices,
            ) == (
                sb.name,
                sb.start,
                sb.length,
                sb.byte_order,
                sb.is_signed,
                sb.is_float,
                sb.scale,
                sb.offset,
                sb.minimum,
                sb.maximum,
                sb.unit,
                sb.choices,
            )
    # the reloaded contract encodes byte-identical frames
    p = C.SetInputVelAuth(1.25, 0.5, 7, 0xDEADBEEF)
    assert bytes(again.encode(p, C.Node.RIGHT).data) == bytes(CODEC.encode(p, C.Node.RIGHT).data)


def test_a_frame_decodes_the_same_with_the_plain_odrive_can_simple_layout() -> None:
    # ODrive CAN Simple 0.6: Set_Input_Vel = <float32 vel, float32 torque_ff>,
    # Get_Encoder_Estimates = <float32 pos, float32 vel>, Heartbeat = <uint32 err, uint8 state, ...>
    msg = CODEC.encode(C.SetInputVel(-1.375, 0.25), C.Node.LEFT)
    assert msg.arbitration_id == (1 << 5) | 0x0D and not msg.is_extended_id
    assert struct.unpack("<ff", bytes(msg.data)) == (-1.375, 0.25)
    enc = CODEC.encode(C.EncoderEstimates(12.5, -0.75), C.Node.RIGHT)
    assert enc.arbitration_id == (2 << 5) | 0x09
    assert struct.unpack("<ff", bytes(enc.data)) == (12.5, -0.75)
    hb = CODEC.encode(C.Heartbeat(0x1000000, C.AxisState.CLOSED_LOOP_CONTROL, 0, True), C.Node.LEFT)
    err, state, proc, flags = struct.unpack("<IBBB", bytes(hb.data)[:7])
    assert (err, state, proc, flags & 1) == (0x1000000, 8, 0, 1)


def test_encoding_is_strict() -> None:
    with pytest.raises(
        EncodeError, match=r"Left_Set_Input_Vel.Input_Vel = 25.0 rev/s is outside \[-20, 20\]"
    ):
        CODEC.encode(C.SetInputVel(25.0), C.Node.LEFT)
    with pytest.raises(EncodeError, match="not finite"):
        CODEC.encode(C.SetInputVel(math.inf), C.Node.LEFT)
    with pytest.raises(EncodeError, match="not finite"):
        CODEC.encode(C.SetInputVel(0.0, math.nan), C.Node.LEFT)
    with pytest.raises(EncodeError, match="no message"):
        CODEC.encode(C.SetInputVel(0.0), C.Node.HOST)
    with pytest.raises(EncodeError, match=r"Left_Set_Input_Vel.Input_Vel = '1' is not a number"):
        CODEC.encode(C.SetInputVel("1"), C.Node.LEFT)  # type: ignore[arg-type]
    # two bad signals: the first of the payload is named, whichever path saw it
    with pytest.raises(EncodeError, match=r"Input_Vel = 25.0 rev/s is outside"):
        CODEC.encode(C.SetInputVel(25.0, math.nan), C.Node.LEFT)


def test_unknown_id_is_rejected_with_a_clear_error() -> None:
    with pytest.raises(DecodeError, match="unknown frame ID 0x7FF") as ei:
        CODEC.decode(can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False))
    assert ei.value.reason == "unknown_id"


def test_bad_length_is_rejected_with_a_clear_error() -> None:
    with pytest.raises(
        DecodeError, match=r"Left_Set_Input_Vel: 4 data bytes \(DLC 4\), expected 8"
    ) as ei:
        CODEC.decode(can.Message(arbitration_id=0x2D, data=bytes(4), is_extended_id=False))
    assert ei.value.reason == "length"


def test_decoding_range_checks_what_cantools_does_not() -> None:
    data = struct.pack("<ff", 55.0, 0.0)  # 55 rev/s: beyond the contract's +-20
    with pytest.raises(DecodeError, match=r"Input_Vel = 55\.0 rev/s is outside") as ei:
        CODEC.decode(can.Message(arbitration_id=0x2D, data=data, is_extended_id=False))
    assert ei.value.reason == "range"
    nan = struct.pack("<ff", math.nan, 0.0)
    with pytest.raises(DecodeError) as ei:
        CODEC.decode(can.Message(arbitration_id=0x2D, data=nan, is_extended_id=False))
    assert ei.value.reason == "range"


def test_every_odrive_06_axis_state_decodes_and_beyond_them_is_out_of_range() -> None:
    for state in (5, 14):  # SENSORLESS_CONTROL, ANTICOGGING_CALIBRATION
        data = bytes([0, 0, 0, 0, state, 0, 0, 0])
        frame = CODEC.decode(can.Message(arbitration_id=0x21, data=data, is_extended_id=False))
        assert frame.payload.axis_state == state
    data = bytes([0, 0, 0, 0, 15, 0, 0, 0])
    with pytest.raises(DecodeError, match=r"Left_Heartbeat.Axis_State = 15 is outside") as ei:
        CODEC.decode(can.Message(arbitration_id=0x21, data=data, is_extended_id=False))
    assert ei.value.reason == "range"


def test_undefined_choice_is_rejected(tmp_path: Path) -> None:
    # a contract whose range admits a state its value table lacks
    text = C.DBC_PATH.read_text().replace(
        "SG_ Axis_State : 32|8@1+ (1,0) [0|14]", "SG_ Axis_State : 32|8@1+ (1,0) [0|20]"
    )
    wide = tmp_path / "wide.dbc"
    wide.write_text(text)
    data = bytes([0, 0, 0, 0, 17, 0, 0, 0])
    msg = can.Message(arbitration_id=0x21, data=data, is_extended_id=False)
    with pytest.raises(DecodeError, match="Axis_State = 17 is not a defined choice") as ei:
        C.Codec(wide).decode(msg)
    assert ei.value.reason == "choice"
    with pytest.raises(DecodeError, match="not a defined choice"):
        C.Codec(wide).decode_signals(msg)


def test_error_bit_fields_decode_any_combination_of_bits() -> None:
    # the value tables name ODrive's error bits; a frame may carry several, or one this
    # firmware's table does not name
    bits = int(C.AxisError.WATCHDOG_TIMER_EXPIRED | C.AxisError.MISSING_INPUT) | 0x80000000
    data = bits.to_bytes(4, "little") + bytes([8, 0, 0, 0])
    msg = can.Message(arbitration_id=0x21, data=data, is_extended_id=False)
    assert CODEC.decode(msg).payload.axis_error == bits
    name, values = CODEC.decode_signals(msg)
    assert (name, values["Axis_Error"]) == ("Left_Heartbeat", bits)
    err = CODEC.encode(C.GetError(bits, int(C.AxisError.ESTOP_REQUESTED)), C.Node.RIGHT)
    assert CODEC.decode_signals(err)[1] == {"Active_Errors": bits, "Disarm_Reason": 0x2000000}
    for name in ("Left_Heartbeat", "Right_Get_Error"):
        for s in CODEC.describe_signals(name):
            if s["name"] in ("Axis_Error", "Active_Errors", "Disarm_Reason"):
                assert s["flags"]
                assert s["choices"] == {0: "NONE"} | {
                    int(f): str(f.name) for f in C.AxisError if f.value
                }


def test_reboot_and_clear_errors_are_one_byte_as_in_odrive_06() -> None:
    for payload, frame_id, data in (
        (C.Reboot(2), 0x36, b"\x02"),
        (C.ClearErrors(True), 0x38, b"\x01"),
    ):
        msg = CODEC.encode(payload, C.Node.LEFT)
        assert (msg.arbitration_id, msg.dlc, bytes(msg.data)) == (frame_id, 1, data)
        assert CODEC.decode(msg).payload == payload
    eight = can.Message(arbitration_id=0x36, data=bytes(8), is_extended_id=False)
    with pytest.raises(DecodeError, match=r"Left_Reboot: 8 data bytes \(DLC 8\), expected 1"):
        CODEC.decode(eight)


def test_an_authenticated_setpoint_carries_the_freshness_and_the_mac_of_its_bytes() -> None:
    auth = Authenticator(KEY)
    for k in range(1, 300):
        (msg,) = CODEC.encode_secured(C.SetInputVelAuth(0.5, 0.5), C.Node.LEFT, auth)
        data = bytes(msg.data)
        p = CODEC.decode(msg).payload
        assert p.freshness == k & 0xFF  # the low 8 bits of the 64-bit freshness value
        assert (
            data[4:8]
            == hmac.digest(
                KEY.secret,
                msg.arbitration_id.to_bytes(4, "little")
                + b"\x04"
                + data[:4]
                + k.to_bytes(8, "big"),
                "sha256",
            )[:4]
        )
        assert p.input_vel_revps == pytest.approx(0.5, abs=1e-4)


@pytest.mark.parametrize("bit", [0, 9, 17, 24, 40, 63])
def test_an_authenticated_setpoint_with_a_flipped_bit_fails_verification(bit: int) -> None:
    (msg,) = CODEC.encode_secured(C.SetInputVelAuth(0.5, 0.6), C.Node.LEFT, Authenticator(KEY))
    data = bytearray(msg.data)
    data[bit // 8] ^= 1 << (bit % 8)
    p = CODEC.decode(
        can.Message(arbitration_id=msg.arbitration_id, data=data, is_extended_id=False)
    ).payload
    why = Verifier(KEY).verify(msg.arbitration_id, data[:4], p.freshness, 8, p.mac)
    assert why == "auth_mac_mismatch"


def test_a_command_is_followed_by_its_host_auth_naming_it() -> None:
    msg, tag = CODEC.encode_secured(C.SetLimits(1.0, 40.0), C.Node.RIGHT, Authenticator(KEY))
    node, p = CODEC.decode(tag)
    assert node == C.Node.HOST and isinstance(p, C.HostAuth)
    assert (p.target_node << 5) | p.target_cmd == msg.arbitration_id
    assert Verifier(KEY).verify(msg.arbitration_id, msg.data, p.freshness, 16, p.mac) == ""


def test_the_contract_hash_ignores_formatting_and_changes_with_any_scale(tmp_path: Path) -> None:
    text = C.DBC_PATH.read_text()
    reformatted = tmp_path / "reformatted.dbc"
    reformatted.write_text(text.replace('CM_ BO_ 33 "ODrive Heartbeat', 'CM_ BO_ 33 "Heartbeat'))
    assert C.Codec(reformatted).contract_hash == CODEC.contract_hash
    doubled = tmp_path / "doubled.dbc"
    old = ' SG_ Input_Vel : 0|32@1- (1,0) [-20|20] "rev/s" Drive_Left'
    assert old in text
    doubled.write_text(text.replace(old, old.replace("(1,0)", "(2,0)")))
    assert C.Codec(doubled).contract_hash != CODEC.contract_hash


def test_remote_frames_request_only_requestable_messages() -> None:
    frame = CODEC.decode(CODEC.request(C.EncoderEstimates, C.Node.LEFT))
    assert frame == C.Frame(C.Node.LEFT, C.Request(C.EncoderEstimates))
    with pytest.raises(EncodeError, match="cannot be requested"):
        CODEC.request(C.SetInputVel, C.Node.LEFT)
    rtr = can.Message(arbitration_id=0x2D, is_remote_frame=True, dlc=8, is_extended_id=False)
    with pytest.raises(DecodeError) as ei:
        CODEC.decode(rtr)
    assert ei.value.reason == "rtr"


def test_a_missing_dbc_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(DbcError, match=r"nothere\.dbc: DBC file not found"):
        C.Codec(tmp_path / "nothere.dbc")


def test_a_dbc_that_drifted_from_the_code_is_rejected(tmp_path: Path) -> None:
    text = C.DBC_PATH.read_text().replace(
        "SG_ Vel_Estimate : 32|32@1-", "SG_ Vel_Est : 32|32@1-", 1
    )
    text = text.replace("SIG_VALTYPE_ 41 Vel_Estimate : 1;", "SIG_VALTYPE_ 41 Vel_Est : 1;")
    p = tmp_path / "drift.dbc"
    p.write_text(text)
    with pytest.raises(DbcError) as ei:
        C.Codec(p)
    assert str(ei.value) == (
        f"{p}: Left_Get_Encoder_Estimates signals differ from the codec: missing "
        "Vel_Estimate (EncoderEstimates.vel_revps); unexpected Vel_Est"
    )


def test_each_payload_field_names_its_signal_and_nothing_else_restates_them() -> None:
    """The message types are the one mapping from fields to signals: the codec binds each
    field to the signal its metadata names, and messages.py writes each signal name once (in
    that field's declaration); the codec's engine names none."""
    source = Path(M.__file__).read_text()
    # the export list names classes, and a class may share its name with a signal
    exports = next(
        n
        for n in ast.parse(source).body
        if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", "") == "__all__"
    )
    source = source.replace(ast.get_source_segment(source, exports) or "", "")
    engine = Path(C.__file__).read_text()
    for cls, node, name in ALL:
        signals = {s.name for s in CODEC.db.get_message_by_name(name).signals}
        declared = {f.name: f.metadata[C.SIGNAL] for f in dataclasses.fields(cls)}
        assert dict(CODEC._bound(cls, node).fields) == declared
        assert set(declared.values()) == signals, name
    quoted = {
        sig: source.count(f'"{sig}"')
        for m in CODEC.db.messages
        for sig in (s.name for s in m.signals)
    }
    # a signal several messages share (Sim_Time, Freshness ...) once per declaring class
    declarations = {
        sig: sum(
            sig in {f.metadata[C.SIGNAL] for f in dataclasses.fields(c)}
            for c in {cls for cls, _n, _m in ALL}
        )
        for sig in quoted
    }
    assert quoted == declarations
    assert not [sig for sig in quoted if f'"{sig}"' in engine]


def test_a_field_without_a_signal_is_refused_when_its_class_is_declared() -> None:
    with pytest.raises(TypeError, match=r"Loose\.speed_mps names no DBC signal"):

        @C.message("Loose_Frame")
        class Loose:
            speed_mps: float = 0.0


def test_value_tables_come_from_the_field_types_and_the_declared_enumerations() -> None:
    assert M.CHOICE_ENUMS["Axis_State"] is C.AxisState  # Heartbeat.axis_state: AxisState
    assert M.CHOICE_ENUMS["Opcode"] is C.SdoOpcode  # RxSdo.opcode: int, values=SdoOpcode
    assert set(M.FLAG_ENUMS) == {"Axis_Error", "Active_Errors", "Disarm_Reason"}


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('13 "INVALID_STATE"', '13 "WRONG_STATE"', "Procedure_Result choices differ"),
        ('2 "erase_configuration"', '2 "wipe"', "Action choices differ"),
    ],
)
def test_a_dbc_whose_value_table_drifted_from_its_enum_is_rejected(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    text = C.DBC_PATH.read_text()
    assert old in text
    p = tmp_path / "drift.dbc"
    p.write_text(text.replace(old, new))
    with pytest.raises(DbcError, match=message):
        C.Codec(p)


def test_procedure_result_and_reboot_action_decode_to_their_enums() -> None:
    for payload in (
        C.Heartbeat(0, C.AxisState.IDLE, C.ProcedureResult.INVALID_STATE),
        C.Reboot(C.RebootAction.ERASE_CONFIGURATION),
    ):
        node = C.Node.LEFT
        back = CODEC.decode(CODEC.encode(payload, node)).payload
        assert back == payload
    hb = CODEC.decode(
        CODEC.encode(C.Heartbeat(0, C.AxisState.IDLE, C.ProcedureResult.DISARMED), C.Node.LEFT)
    ).payload
    assert type(hb.procedure_result) is C.ProcedureResult
    # every value the DBC's ranges admit is a member: no frame a drive may send is refused
    for cls, field, enum_cls in (
        (C.Heartbeat, "procedure_result", C.ProcedureResult),
        (C.Reboot, "action", C.RebootAction),
    ):
        _res, lo, hi = CODEC.signal_scale(cls, field, C.Node.LEFT)
        assert {int(m) for m in enum_cls} == set(range(int(lo), int(hi) + 1))


def test_a_malformed_dbc_is_a_clear_error(tmp_path: Path) -> None:
    p = tmp_path / "bad.dbc"
    p.write_text("BO_ 1 Broken 8 Nobody\n SG_ x : 0|")
    with pytest.raises(DbcError, match=r"bad\.dbc: cannot load DBC"):
        C.Codec(p)


@settings(max_examples=400, deadline=None)
@given(
    aid=st.one_of(st.integers(0, 0x7FF), st.sampled_from([m.frame_id for m in CODEC.db.messages])),
    extended=st.booleans(),
    data=st.binary(min_size=0, max_size=8),
    remote=st.booleans(),
)
def test_arbitrary_frames_decode_or_raise_decode_error_only(
    aid: int, extended: bool, data: bytes, remote: bool
) -> None:
    if extended:
        aid |= 0x1CA00000 if aid < 0x100 else 0
    msg = can.Message(
        arbitration_id=aid & (0x1FFFFFFF if extended else 0x7FF),
        data=b"" if remote else data,
        dlc=len(data),
        is_extended_id=extended,
        is_remote_frame=remote,
    )
    try:
        frame = CODEC.decode(msg)
    except DecodeError as err:
        assert err.reason
        return
    for f in dataclasses.fields(frame.payload):
        v = getattr(frame.payload, f.name)
        if isinstance(v, float):
            assert math.isfinite(v)


def test_signal_scale_reads_resolution_and_range_from_the_contract() -> None:
    codec = C.Codec.default()
    assert codec.signal_scale(C.SetInputVelAuth, "stop_ref_revps", C.Node.LEFT) == (0.01, 0.0, 2.55)
    lsb, lo, hi = codec.signal_scale(C.SetInputVelAuth, "input_vel_revps", C.Node.RIGHT)
    assert lsb == 0.0001 and lo == -hi and hi > 3.0
    with pytest.raises(EncodeError, match="no field 'nope'"):
        codec.signal_scale(C.SetInputVelAuth, "nope", C.Node.LEFT)


@settings(max_examples=200, deadline=None)
@given(
    key=st.sampled_from(sorted(C.Codec.default()._by_key)),
    data=st.data(),
)
def test_the_fast_decoder_gives_the_checked_decoders_frame_or_steps_aside(
    key: tuple[int, bool], data: st.DataObject
) -> None:
    """Each message's generated decoder returns what the general decoder returns for a
    valid payload (the same values of the same types), and None where that one refuses."""
    codec = C.Codec.default()
    bound = codec._by_key[key]
    if bound.decoder is None:
        return
    payload = bytearray(data.draw(st.binary(min_size=bound.length, max_size=bound.length)))
    msg = can.Message(arbitration_id=key[0], is_extended_id=key[1], data=payload)
    try:
        checked: Any = codec._decode_checked(msg)
    except C.DecodeError as err:
        checked = err.reason
    try:
        fast: Any = bound.decoder(payload)
    except ValueError:  # a value that is no choice: the general decoder names it
        fast = None
    if fast is None:
        assert isinstance(checked, str)
        return
    assert fast == checked
    assert [type(getattr(fast.payload, f)) for f in fast.payload.__slots__] == [
        type(getattr(checked.payload, f)) for f in checked.payload.__slots__
    ]


@settings(max_examples=200, deadline=None)
@given(key=st.sampled_from(sorted(C.Codec.default()._by_key)), data=st.data())
def test_the_fast_encoder_gives_the_checked_encoders_bytes_or_steps_aside(
    key: tuple[int, bool], data: st.DataObject
) -> None:
    """Each message's generated encoder packs what the general encoder packs, and gives None
    (or raises) where that one refuses, for values in range, out of range and not finite."""
    codec = C.Codec.default()
    bound = codec._by_key[key]
    if bound.encoder is None:
        return
    values = {}
    for fname, _sname, lo, hi, _unit in bound.limits:
        span = max(1.0, float(hi) - float(lo))
        values[fname] = data.draw(
            st.one_of(
                st.integers(min_value=int(lo), max_value=int(hi)),
                st.floats(min_value=float(lo) - span, max_value=float(hi) + span),
                st.sampled_from([math.nan, math.inf, -math.inf]),
            ),
            label=fname,
        )
    payload = bound.cls(**values)
    try:
        checked: Any = bytes(codec._encode_checked(payload, bound.node).data)
    except C.EncodeError:
        checked = None
    try:
        fast: Any = bound.encoder(payload)
    except Exception:
        fast = None
    if checked is None:  # refused: never encoded by the fast path
        assert fast is None
    if fast is not None:
        assert bytes(fast) == checked
