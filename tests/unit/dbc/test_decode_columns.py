"""``Codec.decode_columns``, many frames of one message at once, is ``decode_signals`` frame by
frame: the same frames accepted, the same values (type, bits and sign of zero), the same
refusals by reason, on every message of the contract."""

from __future__ import annotations

import math
import random
import struct
from collections import Counter
from typing import Any

import can
import pytest

from dbc.codec import Codec
from dbc.errors import DecodeError

CODEC = Codec.default()
MESSAGES = sorted(CODEC.db.messages, key=lambda m: m.name)


def _same(a: Any, b: Any) -> bool:
    """Equal values of the same type; NaN equals NaN, and the sign of zero counts."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return struct.pack("<d", a) == struct.pack("<d", b) or (math.isnan(a) and math.isnan(b))
    return bool(a == b)


def _payloads(message: Any, rng: random.Random, n: int) -> list[bytes]:
    """``n`` random payloads (mostly refused) and ``n`` encodings of in-range values."""
    out = [rng.randbytes(message.length) for _ in range(n)]
    for _ in range(n):
        values = {}
        for s in message.signals:
            lo, hi = s.minimum, s.maximum
            if s.choices and rng.random() < 0.8:
                values[s.name] = int(rng.choice(sorted(s.choices)))
            elif s.is_float or not (isinstance(s.scale, int) and isinstance(s.offset, int)):
                values[s.name] = rng.uniform(lo, hi)
            else:
                values[s.name] = rng.randint(math.ceil(lo), math.floor(hi))
        out.append(message.encode(values, scaling=True, padding=False, strict=False))
    return out


@pytest.mark.parametrize("message", MESSAGES, ids=lambda m: m.name)
def test_decode_columns_is_decode_signals_frame_by_frame(message: Any) -> None:
    rng = random.Random(message.name)
    payloads = _payloads(message, rng, 200)
    key = (message.frame_id, bool(message.is_extended_frame))
    rows: dict[str, list[Any]] = {}
    refused: Counter[str] = Counter()
    taken = []
    for data in payloads:
        msg = can.Message(
            arbitration_id=key[0], is_extended_id=key[1], data=data, dlc=message.length
        )
        try:
            _name, values = CODEC.decode_signals(msg)
        except DecodeError as err:
            refused[err.reason] += 1
            taken.append(False)
            continue
        taken.append(True)
        for k, v in values.items():
            rows.setdefault(k, []).append(v)
    name, cols, accepted_mask, rejected = CODEC.decode_columns(
        key, b"".join(payloads), len(payloads)
    )
    assert name == message.name
    assert rejected == refused
    assert accepted_mask.tolist() == taken
    accepted = len(payloads) - sum(refused.values())
    assert accepted > 0  # the encoded in-range values are (mostly) accepted
    assert set(cols) == set(rows) == {s.name for s in message.signals}
    for sig, column in cols.items():
        got = column.tolist()
        assert len(got) == accepted
        want = rows[sig]
        bad = [(g, w) for g, w in zip(got, want, strict=True) if not _same(g, w)]
        assert bad == [], sig


def test_payloads_that_are_not_whole_frames_are_an_error() -> None:
    message = MESSAGES[0]
    layout = CODEC._by_key[(message.frame_id, bool(message.is_extended_frame))].layout
    assert layout is not None
    with pytest.raises(ValueError, match="not 2 whole payloads"):
        layout.unpack_columns(b"\x00" * (2 * message.length + 1), 2)
