"""ODrive endpoint values in RxSdo/TxSdo's 32-bit Value: float32 bits, integers, bools."""

from __future__ import annotations

import math
import struct

import pytest

from dbc.endpoints import BY_ID, ODRIVE_ENDPOINTS, ValueKind, from_value, to_value


def test_a_float_endpoint_travels_as_its_float32_bits() -> None:
    raw = to_value(ValueKind.FLOAT, 24.5)
    assert raw.to_bytes(4, "little") == struct.pack("<f", 24.5)
    assert from_value(ValueKind.FLOAT, raw) == 24.5
    assert math.isnan(from_value(ValueKind.FLOAT, to_value(ValueKind.FLOAT, math.nan)))  # type: ignore[arg-type]


def test_integers_and_bools_round_trip() -> None:
    for kind, v in ((ValueKind.UINT, 0xFFFF_FFFF), (ValueKind.INT, -5), (ValueKind.BOOL, True)):
        assert from_value(kind, to_value(kind, v)) == v
    assert to_value(ValueKind.INT, -1) == 0xFFFF_FFFF
    assert from_value(ValueKind.BOOL, 0) is False


@pytest.mark.parametrize(
    ("kind", "value", "why"),
    [
        (ValueKind.UINT, -1, "does not fit a uint32"),
        (ValueKind.UINT, 1 << 32, "does not fit a uint32"),
        (ValueKind.INT, 1 << 31, "does not fit an int32"),
        (ValueKind.UINT, 1.5, "is not an integer"),
        (ValueKind.FLOAT, 1e39, "does not fit a float32"),
    ],
)
def test_a_value_that_does_not_fit_is_refused_with_the_reason(
    kind: ValueKind, value: float, why: str
) -> None:
    with pytest.raises(ValueError, match=why):
        to_value(kind, value)


def test_the_table_has_unique_ids_and_paths() -> None:
    assert len(BY_ID) == len(ODRIVE_ENDPOINTS)
    assert all(e.path == p for p, e in ODRIVE_ENDPOINTS.items())
    assert all(0 < e.id < 0xFF00 for e in ODRIVE_ENDPOINTS.values())
