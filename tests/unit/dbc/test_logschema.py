"""Log labels of the error bit fields: the names of the set bits."""

from __future__ import annotations

from dbc import logschema as ls
from dbc.codec import AxisError, Codec

BITS = {0: "NONE"} | {int(f): str(f.name) for f in AxisError if f.value}


def test_a_bit_field_label_names_every_set_bit_lowest_first() -> None:
    assert ls.flags_label(0, BITS) == "NONE"
    assert ls.flags_label(0x40, BITS) == "MISSING_INPUT"
    v = AxisError.ESTOP_REQUESTED | AxisError.WATCHDOG_TIMER_EXPIRED | AxisError.INITIALIZING
    assert ls.flags_label(v, BITS) == "INITIALIZING|WATCHDOG_TIMER_EXPIRED|ESTOP_REQUESTED"
    assert ls.flags_label(0x80 | 0x80000000, BITS) == "0x80|0x80000000"  # bits without a name
    assert ls.flags_label(0, {}) == "0"


def test_the_schema_of_a_bit_field_label_is_a_string_not_an_enum() -> None:
    codec = Codec.default()
    schema = ls.decoded_schema("Left_Heartbeat", codec.describe_signals("Left_Heartbeat"))
    props = schema["properties"]
    assert props["Axis_Error_label"]["type"] == "string"
    assert "enum" not in props["Axis_Error_label"]
    assert "SENSORLESS_CONTROL" in props["Axis_State_label"]["enum"]
