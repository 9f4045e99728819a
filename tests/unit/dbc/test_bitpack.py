"""The codec's precompiled packing agrees with cantools on every message of the contract."""

from __future__ import annotations

import functools
import math
import struct
from typing import Any

import cantools
import pytest
from cantools.autosar.end_to_end import compute_profile2_crc
from hypothesis import given, settings
from hypothesis import strategies as st

from dbc.bitpack import compile_layout, profile2_crc
from dbc.codec import DBC_PATH

# make test starts the heaviest files first (tests/conftest.py)
pytestmark = pytest.mark.heavy(seconds=25)

DB = cantools.database.load_file(str(DBC_PATH), database_format="dbc", strict=True)
MESSAGES = sorted(DB.messages, key=lambda m: m.name)


def _same(a: Any, b: Any) -> bool:
    """Equal values of the same type; NaN equals NaN, and the sign of zero counts."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return struct.pack("<d", a) == struct.pack("<d", b) or (math.isnan(a) and math.isnan(b))
    return bool(a == b)


def test_every_message_of_the_contract_has_a_fast_layout() -> None:
    missing = [m.name for m in MESSAGES if compile_layout(m) is None]
    assert missing == []


@pytest.mark.parametrize("message", MESSAGES, ids=lambda m: m.name)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_unpack_equals_cantools_decode_for_any_payload(message: Any, data: st.DataObject) -> None:
    layout = compile_layout(message)
    assert layout is not None
    payload = data.draw(st.binary(min_size=message.length, max_size=message.length))
    ours = layout.unpack(payload)
    theirs = message.decode(payload, decode_choices=False, scaling=True)
    assert list(ours) == list(theirs)
    bad = {k: (ours[k], theirs[k]) for k in ours if not _same(ours[k], theirs[k])}
    assert bad == {}


def _value(signal: Any) -> st.SearchStrategy[Any]:
    lo, hi = signal.minimum, signal.maximum
    if signal.is_float or not (isinstance(signal.scale, int) and isinstance(signal.offset, int)):
        return st.floats(min_value=lo, max_value=hi, allow_nan=False)
    return st.integers(min_value=math.ceil(lo), max_value=math.floor(hi))


@pytest.mark.parametrize("message", MESSAGES, ids=lambda m: m.name)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_pack_equals_cantools_encode_for_any_in_range_value(
    message: Any, data: st.DataObject
) -> None:
    layout = compile_layout(message)
    assert layout is not None
    values = {s.name: data.draw(_value(s), label=s.name) for s in message.signals}
    ours = bytes(layout.pack(values))
    theirs = message.encode(values, scaling=True, padding=False, strict=False)
    assert ours == theirs


def test_a_raw_value_that_does_not_fit_its_bits_is_refused_not_wrapped() -> None:
    message = next(m for m in MESSAGES if any(s.length == 8 and not s.is_float for s in m.signals))
    sig = next(s for s in message.signals if s.length == 8 and not s.is_float)
    layout = compile_layout(message)
    assert layout is not None
    values = {s.name: 0 for s in message.signals}
    values[sig.name] = 256 * (sig.scale or 1) + (sig.offset or 0)
    with pytest.raises(OverflowError, match=sig.name):
        layout.pack(values)


@settings(max_examples=300, deadline=None)
@given(payload=st.binary(min_size=2, max_size=8), data_id=st.integers(0, 255))
def test_profile2_crc_equals_cantools(payload: bytes, data_id: int) -> None:
    assert profile2_crc(payload, data_id) == compute_profile2_crc(payload, data_id)


WHOLE_BYTE = [m for m in MESSAGES if compile_layout(m)._struct is not None]  # type: ignore[union-attr]


def test_whole_byte_messages_pack_in_one_struct_call() -> None:
    names = {m.name for m in WHOLE_BYTE}
    # the per-step frames of a run: encoder feedback, setpoints, step and ack
    assert {"Left_Get_Encoder_Estimates", "Right_Set_Input_Vel", "Bench_Step"} <= names
    assert "Bench_Truth_Pose" not in names  # scaled 24-bit signals: the general path


@pytest.mark.parametrize(
    "message",
    [m for m in WHOLE_BYTE if not all(s.is_float for s in m.signals)],
    ids=lambda m: m.name,
)
def test_a_whole_byte_message_handles_what_struct_refuses_like_cantools(message: Any) -> None:
    layout = compile_layout(message)
    assert layout is not None
    ints = [s for s in message.signals if not s.is_float]
    values = {s.name: (1.6 if not s.is_float else 0.5) for s in message.signals}  # 1.6 -> 2
    assert bytes(layout.pack(values)) == message.encode(
        values, scaling=True, padding=False, strict=False
    )
    values[ints[0].name] = 1 << ints[0].length  # one past the widest raw value
    with pytest.raises(OverflowError, match=ints[0].name):
        layout.pack(values)


def _generated(lines: list[str], ns: dict[str, Any], args: str, result: str) -> Any:
    src = f"def f({args}):\n" + "".join(f"    {ln}\n" for ln in lines) + f"    return {result}\n"
    exec(src, ns)
    return ns["f"]


@functools.cache
def _straight_line(name: str) -> tuple[Any, Any, Any]:
    """(layout, generated unpack, generated pack) of the message ``name``: generated once per
    message, not per drawn example (the code depends on the layout alone)."""
    layout = compile_layout(DB.get_message_by_name(name))
    assert layout is not None
    n = len(layout.signals)
    ns: dict[str, Any] = {}
    unpack = _generated(
        layout.unpack_source("data", ns), ns, "data", f"[{', '.join(f'r{i}' for i in range(n))}]"
    )
    names = [f"v{i}" for i in range(n)]
    ns = {}
    pack = _generated(layout.pack_source(names, ns), ns, ", ".join(names), "data")
    return layout, unpack, pack


@pytest.mark.parametrize("message", MESSAGES, ids=lambda m: m.name)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_the_straight_line_unpack_gives_the_loops_values(message: Any, data: st.DataObject) -> None:
    layout, unpack, _ = _straight_line(message.name)
    payload = data.draw(st.binary(min_size=message.length, max_size=message.length))
    ours, loop = unpack(payload), layout.unpack_values(payload)
    assert len(ours) == len(loop)
    assert all(_same(a, b) for a, b in zip(ours, loop, strict=True)), (ours, loop)


def _any_value(signal: Any) -> st.SearchStrategy[Any]:
    """In range, out of range and too wide for the bits, ints and floats alike."""
    span = 2.0**signal.length * abs(signal.scale or 1)
    return st.one_of(
        _value(signal),
        st.integers(min_value=-(1 << (signal.length + 1)), max_value=1 << (signal.length + 1)),
        st.floats(min_value=-2 * span, max_value=2 * span, allow_nan=False),
    )


@pytest.mark.parametrize("message", MESSAGES, ids=lambda m: m.name)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_the_straight_line_pack_gives_the_loops_bytes_or_its_error(
    message: Any, data: st.DataObject
) -> None:
    layout, _, pack = _straight_line(message.name)
    by_name = {s.name: s for s in message.signals}
    values = [data.draw(_any_value(by_name[name]), label=name) for name in layout.names]
    try:
        loop: Any = bytes(layout.pack_values(values))
    except (OverflowError, struct.error, ValueError) as err:
        loop = (type(err), str(err))
    try:
        ours: Any = bytes(pack(*values))
    except (OverflowError, struct.error, ValueError) as err:
        ours = (type(err), str(err))
    assert ours == loop
