"""Our DBC against ODrive's own CAN Simple 0.6 definition, frame for frame, both ways.

ODrive's file is the ``odrive-cansimple-0.6.10.dbc`` that the ``odrive-can`` package ships
(a test dependency, ``pip install -e '.[dev]'``); it is read from the installed package,
never copied here.  It defines 28 messages for each of the axes 0..7 (every command ID but the four
ODrive leaves free); the chair's drives are nodes 1 and 2, so the 56 messages of ``Axis1_*`` and ``Axis2_*`` are compared:

* layout: every ODrive message is in our DBC on the same ID with the same name after the
  node prefix, the same length, the same senders (ODrive's ``Master`` is our ``Host``, its
  ``ODrive_Axis1/2`` our ``Drive_Left/Right``), and the same signals with the same bits,
  byte order, signedness (of integers: a float's sign bit is its own), float type, scale,
  offset, multiplexer flag and value table; units are
  compared without spaces and without the documentation footnotes ODrive's file carries in
  some (``"rev/s (default) [#vel-ff-scale]_"``);
* ODrive -> ours: values encoded by cantools with ODrive's file decode with our codec
  (:meth:`Codec.decode_signals` and the typed :meth:`Codec.decode`) to the values cantools
  decodes with ODrive's file;
* ours -> ODrive: our codec encodes the same values to the same bytes, and cantools decodes
  them with ODrive's file to the same values;
* our extensions sit on IDs ODrive's file leaves free.

The values cover each signal's bounds in our DBC, a middle value, zero, every entry of its
value table and, for the error bit fields, combinations of bits and a bit no table names.
Our DBC bounds every signal (a plausibility range the codec enforces on decode); ODrive's
file bounds none.  That is the one kind of difference left, :data:`NARROWER_RANGE` lists its
messages.  ``python -m tests.unit.dbc.test_odrive_cansimple`` prints the comparison.
"""

from __future__ import annotations

import enum
import importlib.util
import json
import math
import re
import struct
import typing
from collections import defaultdict
from pathlib import Path
from typing import Any

import can
import cantools
import pytest

from dbc import codec as C

CODEC = C.Codec.default()
_PREFIX = {C.Node.LEFT: "Left", C.Node.RIGHT: "Right"}


def odrive_dbc_path() -> Path:
    """ODrive's 0.6.10 CAN Simple DBC inside the installed ``odrive-can`` package."""
    spec = importlib.util.find_spec("odrive_can")
    assert spec is not None and spec.submodule_search_locations, (
        "the odrive-can package (a dev dependency in pyproject.toml) is not installed: "
        "pip install -e '.[dev]'"
    )
    path = Path(next(iter(spec.submodule_search_locations))) / "dbc" / "odrive-cansimple-0.6.10.dbc"
    assert path.is_file(), f"{path}: not in the installed odrive-can package"
    return path


ODRIVE = cantools.database.load_file(str(odrive_dbc_path()), database_format="dbc", strict=True)
#: ODrive's messages on the chair's drive nodes, as (node, ODrive message).
COMPARED = [(node, m) for m in ODRIVE.messages for node in C.DRIVES if m.frame_id >> 5 == int(node)]

#: Messages (name after the node prefix) whose signals our DBC bounds more tightly than their
#: raw type: a float by a plausibility range, an integer by its value table or node-ID space.
NARROWER_RANGE = sorted(
    {
        "Get_Bus_Voltage_Current",
        "Get_Encoder_Estimates",
        "Get_Iq",
        "Get_Powers",
        "Get_Temperature",
        "Get_Torques",
        "Heartbeat",
        "Address",
        "Set_Axis_State",
        "Set_Controller_Mode",
        "Set_Input_Pos",
        "Set_Input_Torque",
        "Set_Input_Vel",
        "Set_Limits",
        "Set_Traj_Accel_Limits",
        "Set_Traj_Inertia",
        "Set_Traj_Vel_Limit",
        "Set_Absolute_Position",
        "Set_Pos_Gain",
        "Set_Vel_Gains",
        "Reboot",
        "Clear_Errors",
        "RxSdo",
    }
)


def _suffix(name: str) -> str:
    return name.split("_", 1)[1]


def _unit(u: str | None) -> str:
    u = re.sub(r"\s*\(default\).*$", "", u or "")
    return u.replace(" ", "")


def _raw_bounds(sig: Any) -> tuple[float, float]:
    if sig.is_float:
        return -struct.unpack("<f", b"\xff\xff\x7f\x7f")[0], struct.unpack(
            "<f", b"\xff\xff\x7f\x7f"
        )[0]
    lo, hi = (
        (-(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1)
        if sig.is_signed
        else (0, (1 << sig.length) - 1)
    )
    return lo * sig.scale + sig.offset, hi * sig.scale + sig.offset


def compare() -> tuple[int, dict[str, list[str]]]:
    """The number of ODrive messages compared and, by kind, the messages that differ."""
    diffs: dict[str, set[str]] = defaultdict(set)
    for node, theirs in COMPARED:
        suffix = _suffix(theirs.name)
        try:
            ours = CODEC.db.get_message_by_frame_id(theirs.frame_id)
        except KeyError:
            diffs["missing"].add(suffix)
            continue
        if ours.is_extended_frame or ours.name != f"{_PREFIX[node]}_{suffix}":
            diffs["name"].add(suffix)
        if ours.length != theirs.length:
            diffs["length"].add(suffix)
        senders = {"Master": "Host", "ODrive_Axis1": "Drive_Left", "ODrive_Axis2": "Drive_Right"}
        if list(ours.senders) != [senders.get(s, s) for s in theirs.senders]:
            diffs["senders"].add(suffix)
        a = {s.name: s for s in ours.signals}
        b = {s.name: s for s in theirs.signals}
        if set(a) != set(b):
            diffs["signals"].add(suffix)
            continue
        for name, sb in b.items():
            sa = a[name]
            layout = ("start", "length", "byte_order", "is_float", "scale", "offset")
            if any(getattr(sa, k) != getattr(sb, k) for k in layout) or (
                not sb.is_float and sa.is_signed != sb.is_signed
            ):
                diffs["layout"].add(suffix)
            if sa.is_multiplexer != sb.is_multiplexer:
                diffs["multiplexer"].add(suffix)
            if {int(k): str(v) for k, v in (sa.choices or {}).items()} != {
                int(k): str(v) for k, v in (sb.choices or {}).items()
            }:
                diffs["value table"].add(suffix)
            if _unit(sa.unit) != _unit(sb.unit):
                diffs["unit"].add(suffix)
            lo, hi = _raw_bounds(sb)
            if sa.minimum > lo or sa.maximum < hi:
                diffs["narrower range"].add(suffix)
    return len(COMPARED), {k: sorted(v) for k, v in sorted(diffs.items())}


# ------------------------------------------------------------------------- values


def _f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


def _candidates(ours: Any) -> list[Any]:
    """Values of one of our signals: bounds, middle, zero, value table (and bit mixes)."""
    lo, hi = ours.minimum, ours.maximum
    if ours.is_float:
        vals = [_f32(lo), _f32(hi), 0.0, _f32(lo + (hi - lo) * 0.37), _f32(-0.0)]
        return [v for v in vals if lo <= v <= hi]
    if not isinstance(ours.scale, int):
        raw_lo, raw_hi = math.ceil(lo / ours.scale), math.floor(hi / ours.scale)
        raws = [raw_lo, raw_hi, 0, (raw_lo + raw_hi) // 3]
        return [r * ours.scale for r in raws]
    ilo, ihi = math.ceil(lo), math.floor(hi)
    vals = [ilo, ihi, (ilo + ihi) // 2, 0]
    choices = sorted(int(k) for k in (ours.choices or {}))
    vals += choices
    if ours.name in C.FLAG_ENUMS:
        bits = [c for c in choices if c]
        vals += [bits[0] | bits[-1], bits[3] | bits[7] | bits[-3], 0x80000000, 0xFFFFFFFF]
    if choices and ours.name not in C.FLAG_ENUMS:
        vals = [v for v in vals if v in choices]
    return list(dict.fromkeys(v for v in vals if ilo <= v <= ihi))


def value_sets(ours: Any) -> list[dict[str, Any]]:
    """Enough signal-value dicts for ``ours`` that each signal takes each of its candidates."""
    if not ours.signals:
        return [{}]
    cands = {s.name: _candidates(s) for s in ours.signals}
    n = max(len(v) for v in cands.values())
    return [{k: v[i % len(v)] for k, v in cands.items()} for i in range(n)]


def _payload(cls: type, node: C.Node, values: dict[str, Any]) -> Any:
    bound = CODEC._bound(cls, node)
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for fname, sname in bound.fields:
        t = hints[fname]
        v = values[sname]
        kwargs[fname] = t(v) if isinstance(t, type) and issubclass(t, enum.Enum | bool) else v
    return cls(**kwargs)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return struct.pack("<d", float(a)) == struct.pack("<d", float(b))
    return bool(a == b)


CASES = [
    pytest.param(node, m, id=m.name.replace("Axis1", "Left").replace("Axis2", "Right"))
    for node, m in COMPARED
]


# -------------------------------------------------------------------------- tests


def test_every_odrive_06_message_of_the_chairs_drives_is_compared() -> None:
    assert len(ODRIVE.messages) == 8 * 28
    assert len(COMPARED) == 56
    assert {m.frame_id & 0x1F for _n, m in COMPARED} == C.ODRIVE_06_CMDS


def test_the_only_difference_left_is_our_plausibility_ranges() -> None:
    count, diffs = compare()
    assert count == 56
    assert diffs == {"narrower range": NARROWER_RANGE}


@pytest.mark.parametrize(("node", "theirs"), CASES)
def test_odrive_encodes_and_our_codec_decodes_the_same_values(node: C.Node, theirs: Any) -> None:
    ours = CODEC.db.get_message_by_frame_id(theirs.frame_id)
    for values in value_sets(ours):
        data = theirs.encode(values, scaling=True, padding=False, strict=True)
        msg = can.Message(
            arbitration_id=theirs.frame_id, data=data, dlc=len(data), is_extended_id=False
        )
        expected = theirs.decode(data, decode_choices=False, scaling=True)
        name, got = CODEC.decode_signals(msg)
        assert name == ours.name
        assert set(got) == set(expected)
        bad = {k: (got[k], expected[k]) for k in expected if not _same(got[k], expected[k])}
        assert bad == {}, values
        frame = CODEC.decode(msg)
        assert frame.node == node
        fields = dict(CODEC._bound(type(frame.payload), node).fields)
        typed = {s: getattr(frame.payload, f) for f, s in fields.items()}
        bad = {k: (typed[k], expected[k]) for k in expected if not _same(typed[k], expected[k])}
        assert bad == {}, values


@pytest.mark.parametrize(("node", "theirs"), CASES)
def test_our_codec_encodes_the_bytes_odrive_defines(node: C.Node, theirs: Any) -> None:
    ours = CODEC.db.get_message_by_frame_id(theirs.frame_id)
    cls = next(b.cls for b in CODEC._by_key.values() if b.frame_id == theirs.frame_id)
    for values in value_sets(ours):
        msg = CODEC.encode(_payload(cls, node, values), node)
        assert (msg.arbitration_id, msg.is_extended_id, msg.dlc) == (
            theirs.frame_id,
            False,
            theirs.length,
        )
        assert bytes(msg.data) == theirs.encode(values, scaling=True, padding=False, strict=True)
        back = theirs.decode(bytes(msg.data), decode_choices=False, scaling=True)
        bad = {k: (back[k], v) for k, v in values.items() if not _same(back[k], v)}
        assert bad == {}, values


def test_our_extensions_are_on_ids_odrive_leaves_free() -> None:
    for cls, node, name in CODEC.all_messages():
        if node is None:
            assert CODEC.db.get_message_by_name(name).is_extended_frame  # bench frames
            continue
        frame_id = CODEC.frame_id(cls, node)
        if frame_id & 0x1F in C.ODRIVE_06_FREE_CMDS:
            with pytest.raises(KeyError):
                ODRIVE.get_message_by_frame_id(frame_id)
        else:
            assert _suffix(ODRIVE.get_message_by_frame_id(frame_id).name) == _suffix(name)


def test_value_sets_cover_every_value_table_entry() -> None:
    for _node, theirs in COMPARED:
        ours = CODEC.db.get_message_by_frame_id(theirs.frame_id)
        seen: dict[str, set[int]] = defaultdict(set)
        for values in value_sets(ours):
            for k, v in values.items():
                seen[k].add(v)
        for s in theirs.signals:
            assert {int(k) for k in (s.choices or {})} <= seen[s.name], (theirs.name, s.name)


def narrower_signals() -> dict[str, str]:
    """``Message.Signal``: our bounds, where they are tighter than the raw type's."""
    out = {}
    for node, theirs in COMPARED:
        if node != C.Node.LEFT:
            continue
        ours = CODEC.db.get_message_by_frame_id(theirs.frame_id)
        for sb in theirs.signals:
            sa = ours.get_signal_by_name(sb.name)
            lo, hi = _raw_bounds(sb)
            if sa.minimum > lo or sa.maximum < hi:
                out[f"{_suffix(ours.name)}.{sa.name}"] = f"[{sa.minimum:g}, {sa.maximum:g}]"
    return dict(sorted(out.items()))


def main() -> None:
    n, found = compare()
    frames = sum(
        len(value_sets(CODEC.db.get_message_by_frame_id(m.frame_id))) for _n, m in COMPARED
    )
    report = {
        "odrive_dbc": str(odrive_dbc_path()),
        "messages_compared": n,
        "frames_per_direction": frames,
        "differences": found,
        "our_bounds_where_narrower": narrower_signals(),
    }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
