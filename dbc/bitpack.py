"""Precompiled packing of DBC messages: the codec's per-frame fast path.

cantools packs and unpacks through ``bitstruct`` and a conversion object per
signal, general enough for any DBC and about ten times slower than a frame
needs.  Every message of this contract is little-endian (ODrive's layouts), so
a message is one little-endian integer and each signal a shift and a mask.
:func:`compile_layout` turns a cantools message into such a :class:`Layout`
once, at load time; a message it cannot express (big-endian signals, floats
other than 32/64 bit, multiplexing) gets ``None`` and the codec keeps using
cantools for it.

The arithmetic mirrors cantools' exactly (same scaling expressions, same
rounding, same int/float result types), and ``tests/unit/dbc/test_bitpack.py``
checks that both agree on every message for arbitrary values and bytes.

AUTOSAR E2E profile 2's CRC (CRC-8, polynomial 0x2F, init and xor-out 0xFF,
over data bytes 1.. and the data ID) is table-driven here as well.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Any

import numpy as np

_F32 = struct.Struct("<f")
_F64 = struct.Struct("<d")

# Signal kinds.
_INT = 0  # integer raw value, no scaling (scale 1, offset 0): raw is the value
_SCALED_INT = 1  # integer raw value with integer scale and offset (cantools keeps ints)
_SCALED = 2  # integer raw value with a float scale or offset: a float value
_FLOAT32 = 3
_FLOAT64 = 4
#: The kinds whose values are floats.
FLOAT_KINDS = frozenset((_SCALED, _FLOAT32, _FLOAT64))


class Layout:
    """How one message's signals sit in its payload (little-endian, bit ``start``)."""

    __slots__ = ("_struct", "length", "names", "signals")

    def __init__(self, length: int, signals: tuple[tuple[Any, ...], ...]) -> None:
        self.length = length
        # (name, kind, start, length, mask, sign_bit, scale, offset); for a float signal,
        # length is in bytes and scale ``None`` means no scaling.
        self.signals = signals
        self.names = tuple(sig[0] for sig in signals)
        self._struct = _plain_struct(length, signals)

    def unpack(self, data: bytes | bytearray) -> dict[str, Any]:
        """Physical signal values of ``data`` (the caller has checked its length)."""
        return dict(zip(self.names, self.unpack_values(data), strict=True))

    def unpack_values(self, data: bytes | bytearray) -> list[Any]:
        """Like :meth:`unpack`, the values in the order of :attr:`signals` (the codec's path)."""
        if self._struct is not None:
            return list(self._struct.unpack(data))
        raw = int.from_bytes(data, "little")
        out: list[Any] = []
        for _name, kind, start, length, mask, sign_bit, scale, offset in self.signals:
            v = (raw >> start) & mask
            if kind >= _FLOAT32:
                f = (_F32 if kind == _FLOAT32 else _F64).unpack(v.to_bytes(length, "little"))[0]
                out.append(f if scale is None else f * scale + offset)
                continue
            if sign_bit and v & sign_bit:
                v -= mask + 1
            out.append(v if kind == _INT else v * scale + offset)
        return out

    def unpack_columns(self, data: bytes, n: int) -> list[np.ndarray]:
        """:meth:`unpack_values` of ``n`` payloads at once: ``data`` is the payloads of
        :attr:`length` bytes each, back to back; one array per signal (in the order of
        :attr:`signals`), the same numbers as frame by frame (ints as int64, scaled and float
        signals as float64: the same IEEE operations in the same order)."""
        if n * self.length != len(data):
            raise ValueError(f"{len(data)} bytes are not {n} whole payloads of {self.length}")
        frames = np.frombuffer(data, dtype=np.uint8).reshape(n, self.length)
        wide = np.zeros((n, 8), dtype=np.uint8)
        wide[:, : self.length] = frames
        raw = wide.view("<u8").ravel()
        out: list[np.ndarray] = []
        full = 0xFFFF_FFFF_FFFF_FFFF
        for _name, kind, start, _length, mask, sign_bit, scale, offset in self.signals:
            v = (raw >> np.uint64(start)) & np.uint64(mask)
            if kind >= _FLOAT32:
                with np.errstate(invalid="ignore"):  # a signalling NaN widens quietly, as in C
                    f = (
                        v.astype("<u4").view("<f4").astype(np.float64)
                        if kind == _FLOAT32
                        else v.view("<f8").astype(np.float64)
                    )
                out.append(f if scale is None else f * scale + offset)
                continue
            if mask == full:  # a 64-bit signal: two's complement if signed, else unsigned
                iv = v.view(np.int64) if sign_bit else v
            else:
                iv = v.astype(np.int64)
                if sign_bit:
                    iv = np.where(iv & sign_bit, iv - (mask + 1), iv)
            if kind == _INT:
                out.append(iv)
            elif kind == _SCALED_INT:
                out.append(iv * scale + offset)
            else:
                out.append(iv.astype(np.float64) * scale + offset)
        return out

    def pack(self, values: dict[str, Any]) -> bytearray:
        """The payload for physical ``values``; ``OverflowError`` if one does not fit its bits."""
        return self.pack_values([values[name] for name in self.names])

    def pack_values(self, values: Sequence[Any]) -> bytearray:
        """Like :meth:`pack`, the values in the order of :attr:`signals` (the codec's path)."""
        if self._struct is not None:
            try:
                return bytearray(self._struct.pack(*values))
            except struct.error:
                pass  # a float for an integer, a value too wide: the general path decides
        raw = 0
        for sig, v in zip(self.signals, values, strict=True):
            name, kind, start, length, mask, sign_bit, scale, offset = sig
            if kind >= _FLOAT32:
                f = v if scale is None else (v - offset) / scale
                r = int.from_bytes((_F32 if kind == _FLOAT32 else _F64).pack(f), "little")
            else:
                if kind == _INT:
                    r = round(v)
                elif kind == _SCALED_INT:
                    q, rem = divmod(v - offset, scale)
                    r = round(q if rem == 0 else (v - offset) / scale)
                else:
                    r = round((v - offset) / scale)
                lo, hi = (-sign_bit, sign_bit - 1) if sign_bit else (0, mask)
                if r < lo or r > hi:
                    raise OverflowError(f"{name}: raw value {r} does not fit {length} bits")
                r &= mask
            raw |= r << start
        return bytearray(raw.to_bytes(self.length, "little"))

    # -- straight-line code for one message (the codec's generated fast paths) --------------

    def unpack_source(self, data: str, ns: dict[str, Any]) -> list[str]:
        """Lines of Python that set ``r0``, ``r1``, ... to :meth:`unpack_values` of the bytes
        named ``data`` (the caller has checked their length): the same operations on the
        same values, without the loop over :attr:`signals`.  Constants go into ``ns`` (the
        generated function's globals)."""
        n = len(self.signals)
        if self._struct is not None:
            ns["_unpack"] = self._struct.unpack
            return [f"({''.join(f'r{i}, ' for i in range(n))}) = _unpack({data})"]
        ns["_from_bytes"] = int.from_bytes
        ns["_F32u"], ns["_F64u"] = _F32.unpack, _F64.unpack
        lines = [f"raw = _from_bytes({data}, 'little')"]
        for i, (_name, kind, start, length, mask, sign_bit, scale, offset) in enumerate(
            self.signals
        ):
            ns[f"_s{i}"], ns[f"_o{i}"] = scale, offset
            lines.append(f"v = (raw >> {start}) & {mask}")
            if kind >= _FLOAT32:
                fn = "_F32u" if kind == _FLOAT32 else "_F64u"
                f = f"{fn}(v.to_bytes({length}, 'little'))[0]"
                lines.append(f"r{i} = {f}" if scale is None else f"r{i} = {f} * _s{i} + _o{i}")
                continue
            if sign_bit:
                lines.append(f"if v & {sign_bit}: v -= {mask + 1}")
            lines.append(f"r{i} = v" if kind == _INT else f"r{i} = v * _s{i} + _o{i}")
        return lines

    def pack_source(self, values: Sequence[str], ns: dict[str, Any]) -> list[str]:
        """Lines of Python that set ``data`` to :meth:`pack_values` of the variables named
        ``values`` (in the order of :attr:`signals`): the same bytes, or the same
        ``OverflowError``, without the loop.  Constants go into ``ns``."""
        args = ", ".join(values)
        if self._struct is not None:
            # what struct refuses (a float for an integer, a value too wide) goes the
            # general way, as in pack_values
            ns["_pack"], ns["_struct_error"] = self._struct.pack, struct.error
            ns["_pack_values"] = self.pack_values
            return [
                "try:",
                f"    data = bytearray(_pack({args}))",
                "except _struct_error:",
                f"    data = _pack_values([{args}])",
            ]
        ns["_to_int"] = int.from_bytes
        ns["_F32p"], ns["_F64p"] = _F32.pack, _F64.pack
        ns["_divmod"], ns["_round"], ns["_Overflow"] = divmod, round, OverflowError
        lines = ["raw = 0"]
        for i, (v, (name, kind, start, length, mask, sign_bit, scale, offset)) in enumerate(
            zip(values, self.signals, strict=True)
        ):
            ns[f"_s{i}"], ns[f"_o{i}"], ns[f"_n{i}"] = scale, offset, name
            if kind >= _FLOAT32:
                fn = "_F32p" if kind == _FLOAT32 else "_F64p"
                f = v if scale is None else f"({v} - _o{i}) / _s{i}"
                lines.append(f"r = _to_int({fn}({f}), 'little')")
            else:
                if kind == _INT:
                    lines.append(f"r = _round({v})")
                elif kind == _SCALED_INT:
                    lines += [
                        f"q, rem = _divmod({v} - _o{i}, _s{i})",
                        f"r = _round(q if rem == 0 else ({v} - _o{i}) / _s{i})",
                    ]
                else:
                    lines.append(f"r = _round(({v} - _o{i}) / _s{i})")
                lo, hi = (-sign_bit, sign_bit - 1) if sign_bit else (0, mask)
                lines += [
                    f"if r < {lo} or r > {hi}:",
                    f"    raise _Overflow(f'{{_n{i}}}: raw value {{r}} does not fit {length} bits')",
                    f"r &= {mask}",
                ]
            lines.append(f"raw |= r << {start}")
        lines.append(f"data = bytearray(raw.to_bytes({self.length}, 'little'))")
        return lines


_INT_FORMATS = {8: "b", 16: "h", 32: "i", 64: "q"}


def _plain_struct(length: int, signals: tuple[tuple[Any, ...], ...]) -> struct.Struct | None:
    """A ``struct`` format for a message of whole-byte, unscaled signals in start order.

    Such a message (floats, plain 8/16/32/64-bit integers, gaps as pad bytes) packs and
    unpacks in one C call to the same bytes and values as the general path.  ``None``
    for any other.
    """
    fmt = "<"
    pos = 0
    for _name, kind, start, size, _mask, sign_bit, scale, _offset in signals:
        if start % 8 or start < pos:
            return None
        if kind in (_FLOAT32, _FLOAT64) and scale is None:
            code, nbits = ("f" if kind == _FLOAT32 else "d"), size * 8
        elif kind == _INT and size in _INT_FORMATS:
            code, nbits = _INT_FORMATS[size], size
            code = code if sign_bit else code.upper()
        else:
            return None
        fmt += "x" * ((start - pos) // 8) + code
        pos = start + nbits
    if pos > length * 8:
        return None
    fmt += "x" * (length - pos // 8)
    return struct.Struct(fmt)


def compile_layout(message: Any) -> Layout | None:
    """A :class:`Layout` for cantools ``message``, or ``None`` where cantools must do it."""
    if message.is_multiplexed():
        return None
    sigs = []
    for s in message.signals:
        if s.byte_order != "little_endian":
            return None
        scale, offset = s.scale, s.offset
        if s.is_float:
            if s.length not in (32, 64):
                return None
            kind = _FLOAT32 if s.length == 32 else _FLOAT64
            if (scale, offset) == (1, 0):
                scale = offset = None  # cantools' identity conversion: no arithmetic (keeps -0.0)
        elif isinstance(scale, int) and isinstance(offset, int):
            kind = _INT if (scale, offset) == (1, 0) else _SCALED_INT
        else:
            kind = _SCALED
        mask = (1 << s.length) - 1
        sign_bit = 1 << (s.length - 1) if s.is_signed and not s.is_float else 0
        length = s.length // 8 if s.is_float else s.length
        sigs.append((s.name, kind, s.start, length, mask, sign_bit, scale, offset))
    return Layout(message.length, tuple(sigs))


def _crc8_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_CRC8H2F = _crc8_table(0x2F)


def profile2_crc(data: bytes | bytearray, data_id: int) -> int:
    """AUTOSAR E2E profile 2 CRC of ``data`` (byte 0 is the CRC itself and is skipped)."""
    table = _CRC8H2F
    crc = 0xFF
    for b in data[1:]:
        crc = table[crc ^ b]
    return table[crc ^ data_id] ^ 0xFF
