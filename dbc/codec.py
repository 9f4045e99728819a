"""The codec of ``wheelchair.dbc``: :class:`Codec` binds the message types of
:mod:`dbc.messages` to the loaded DBC, checks them against it and turns payloads into
``can.Message`` objects and back:

* **encoding is strict**: a missing, non-finite or out-of-range value raises
  :class:`~dbc.errors.EncodeError` naming message, signal, bound and value.
  Saturation is the caller's explicit job, never a silent wrap-around;
* **decoding is strict**: an unknown ID, a wrong length, an RTR for a message
  that cannot be requested, a value outside the DBC's ``[min|max]`` (cantools
  itself does not range-check on decode) or an undefined choice
  raise :class:`~dbc.errors.DecodeError` whose ``reason`` says which.

Packing goes through :mod:`dbc.bitpack`: each message's layout is compiled from the
DBC once (cantools stays the reference for loading, checking and any layout the fast path
cannot express), which makes a frame several times cheaper to encode and decode.

At load time the DBC is checked against the message types (message names, frame IDs
``node << 5 | cmd``, signal sets, choice tables), so a DBC that drifts from the code fails
before anything moves.  Every name of :mod:`dbc.messages` is importable from here too.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import typing
from collections import Counter
from collections.abc import Iterable
from pathlib import Path
from typing import Any, ClassVar

import can
import cantools
import numpy as np

from dbc.bitpack import FLOAT_KINDS, compile_layout
from dbc.errors import DbcError, DecodeError, EncodeError
from dbc.messages import *  # noqa: F403 (the message types, re-exported: ``from dbc.codec import Node``)
from dbc.messages import (
    CHOICE_ENUMS,
    DRIVES,
    FLAG_ENUMS,
    NODE_PREFIX,
    ODRIVE_06_FREE_CMDS,
    SPECS,
    Frame,
    HostAuth,
    MessageSpec,
    Node,
    Payload,
    Request,
    SetInputVelAuth,
)
from dbc.runtime.busio import bare_message
from dbc.secoc import AUTH_FV_BITS, MAC_BYTES, SETPOINT_FV_BITS, Authenticator, contract_digest

DBC_PATH = Path(__file__).with_name("wheelchair.dbc")


def _compiled(lines: list[str], ns: dict[str, Any], name: str, what: str) -> Any:
    """The function ``name`` defined by ``lines`` with globals ``ns`` (``what`` names it in
    tracebacks)."""
    exec(compile("\n".join(lines) + "\n", f"<{what}>", "exec"), ns)
    return ns[name]


class _Bound:
    """One message of the loaded DBC bound to its payload class (precomputed for speed)."""

    __slots__ = (
        "choice_tables",
        "cls",
        "convert",
        "dec_fields",
        "decoder",
        "enc_checks",
        "encoder",
        "fields",
        "frame_id",
        "is_extended",
        "layout",
        "length",
        "limits",
        "message",
        "name",
        "node",
        "requestable",
    )

    def __init__(self, spec: MessageSpec, message: Any, node: Node | None) -> None:
        self.cls = spec.cls
        self.message = message
        self.name: str = message.name
        self.frame_id: int = message.frame_id
        self.is_extended: bool = bool(message.is_extended_frame)
        self.length: int = message.length
        self.layout = compile_layout(message)  # None: cantools packs this one
        self.node = node
        self.requestable = spec.requestable
        self.fields = spec.fields
        hints = typing.get_type_hints(spec.cls)
        self.convert: dict[str, Any] = {}
        for fname, _sig in spec.fields:
            t = hints[fname]
            self.convert[fname] = t if t in (int, float, bool) or isinstance(t, type) else float
        sigs = {s.name: s for s in message.signals}
        self.limits = tuple(
            (fname, sname, sigs[sname].minimum, sigs[sname].maximum, sigs[sname].unit or "")
            for fname, sname in spec.fields
        )
        self.choice_tables = tuple(
            (s.name, frozenset(int(k) for k in s.choices))
            for s in message.signals
            if s.choices and s.name not in FLAG_ENUMS
        )
        # The per-frame fast paths (Codec.encode/decode); None: the general path only.
        # encode: (field, min, max) in the layout's signal order;
        # decode: (signal index, min, max, converter) in the payload's field order.
        self.enc_checks: tuple[tuple[str, Any, Any], ...] | None = None
        self.dec_fields: tuple[tuple[int, Any, Any, Any], ...] | None = None
        layout = self.layout
        if layout is not None:
            by_sig = {sname: (fname, lo, hi) for fname, sname, lo, hi, _u in self.limits}
            self.enc_checks = tuple(by_sig[name] for name in layout.names)
            by_field = {fname: sname for fname, sname in spec.fields}
            order = [f.name for f in dataclasses.fields(spec.cls)]
            if sorted(order) == sorted(by_field):
                self.dec_fields = tuple(
                    (
                        layout.names.index(by_field[f]),
                        sigs[by_field[f]].minimum,
                        sigs[by_field[f]].maximum,
                        self.convert[f],
                    )
                    for f in order
                )
        self.encoder = None if self.enc_checks is None else self._encoder()
        self.decoder = None if self.dec_fields is None else self._decoder()

    def _encoder(self) -> Any:
        """``encoder(payload)``: the payload bytes of a payload whose every value is within its
        signal's range, ``None`` for any other (out of range, NaN); raises what packing raises
        (a value too wide for its bits).  :meth:`Codec.encode`'s fast path as straight-line
        code made for this message (:meth:`Layout.pack_source`): the same checks in the same
        order, the same bytes."""
        assert self.enc_checks is not None and self.layout is not None
        ns: dict[str, Any] = {}
        names = [f"v{i}" for i in range(len(self.enc_checks))]
        lines = ["def encoder(p):"]
        for i, (fname, lo, hi) in enumerate(self.enc_checks):
            ns[f"_lo{i}"], ns[f"_hi{i}"] = lo, hi
            lines += [f"    v{i} = p.{fname}", f"    if not _lo{i} <= v{i} <= _hi{i}: return None"]
        lines += [f"    {ln}" for ln in self.layout.pack_source(names, ns)]
        lines.append("    return data")
        return _compiled(lines, ns, "encoder", f"encode {self.name}")

    def _decoder(self) -> Any:
        """``decoder(data)``: the :class:`Frame` of a valid payload (the caller has checked its
        length), ``None`` if a value is outside its signal's range (or NaN); raises what a
        conversion raises (a value that is no choice of its enumeration).
        :meth:`Codec.decode`'s fast path as straight-line code made for this message."""
        assert self.dec_fields is not None and self.layout is not None
        ns: dict[str, Any] = {"_tuple_new": tuple.__new__, "_Frame": Frame}
        ns["_node"], ns["_cls"] = self.node, self.cls
        lines = ["def decoder(data):"]
        lines += [f"    {ln}" for ln in self.layout.unpack_source("data", ns)]
        checks, args = [], []
        kinds = [sig[1] for sig in self.layout.signals]
        for k, (i, lo, hi, conv) in enumerate(self.dec_fields):
            ns[f"_lo{k}"], ns[f"_hi{k}"], ns[f"_c{k}"] = lo, hi, conv
            checks.append(f"_lo{k} <= r{i} <= _hi{k}")
            # float() of a float is that float: skipped where the signal gives floats
            args.append(f"r{i}" if conv is float and kinds[i] in FLOAT_KINDS else f"_c{k}(r{i})")
        lines.append(f"    if not ({' and '.join(checks) or 'True'}): return None")
        lines.append(f"    return _tuple_new(_Frame, (_node, _cls({', '.join(args)})))")
        return _compiled(lines, ns, "decoder", f"decode {self.name}")


class Codec:
    """Encode payload dataclasses to ``can.Message`` and decode frames back.

    ``Codec()`` loads the project's DBC; ``Codec(path)`` another file with the
    same contract (it is validated and rejected with a :class:`DbcError` naming
    the file and the first mismatch).
    """

    _default: ClassVar[Codec | None] = None

    def __init__(self, dbc_path: str | Path = DBC_PATH) -> None:
        self.path = Path(dbc_path)
        if not self.path.is_file():
            raise DbcError(f"{self.path}: DBC file not found")
        try:
            db = cantools.database.load_file(str(self.path), database_format="dbc", strict=True)
        except Exception as err:  # cantools raises several types for a malformed file
            raise DbcError(f"{self.path}: cannot load DBC: {err}") from err
        if not isinstance(db, cantools.database.can.Database):
            raise DbcError(f"{self.path}: not a CAN database")
        self.db: cantools.database.can.Database = db
        self._by_key: dict[tuple[int, bool], _Bound] = {}
        self._by_type: dict[tuple[type, Node | None], _Bound] = {}
        for spec in SPECS:
            for node in spec.nodes or (None,):
                bound = self._bind(spec, node)
                key = (bound.message.frame_id, bound.message.is_extended_frame)
                self._by_key[key] = bound
                self._by_type[(spec.cls, node)] = bound
        self._check_choices()
        self._contract_hash: int | None = None

    @classmethod
    def default(cls) -> Codec:
        """The process-wide codec for the project's DBC (loaded once)."""
        if cls._default is None:
            cls._default = cls()
        return cls._default

    # ----------------------------------------------------------------- load checks

    def _bind(self, spec: MessageSpec, node: Node | None) -> _Bound:
        name = spec.suffix if node is None else f"{NODE_PREFIX[node]}_{spec.suffix}"
        try:
            message = self.db.get_message_by_name(name)
        except KeyError as err:
            raise DbcError(f"{self.path}: message {name!r} is missing") from err
        if node is None:
            if not message.is_extended_frame:
                raise DbcError(f"{self.path}: bench message {name} must use a 29-bit extended ID")
        else:
            cmd = spec.cmd
            assert cmd is not None
            if cmd not in ODRIVE_06_FREE_CMDS and node not in DRIVES:
                raise DbcError(
                    f"{self.path}: {name}: non-drive nodes may only use free command IDs"
                )
            expected = (int(node) << 5) | int(cmd)
            if message.is_extended_frame or message.frame_id != expected:
                raise DbcError(
                    f"{self.path}: {name} has ID {message.frame_id:#x}, expected "
                    f"node {int(node)} << 5 | cmd {int(cmd):#04x} = {expected:#05x}"
                )
        dbc_sigs = {s.name for s in message.signals}
        code_sigs = {sig: f"{spec.cls.__name__}.{f}" for f, sig in spec.fields}
        if dbc_sigs != set(code_sigs):
            missing = [f"{sig} ({code_sigs[sig]})" for sig in sorted(set(code_sigs) - dbc_sigs)]
            extra = sorted(dbc_sigs - set(code_sigs))
            raise DbcError(
                f"{self.path}: {name} signals differ from the codec: "
                f"missing {', '.join(missing) or 'none'}; unexpected {', '.join(extra) or 'none'}"
            )
        for s in message.signals:
            if s.minimum is None or s.maximum is None:
                raise DbcError(f"{self.path}: {name}.{s.name} has no [min|max] range")
        bound = _Bound(spec, message, node)
        return bound

    def _check_choices(self) -> None:
        for bound in self._by_key.values():
            for s in bound.message.signals:
                enum_cls: type[enum.Enum] | None = CHOICE_ENUMS.get(s.name) or FLAG_ENUMS.get(
                    s.name
                )
                if enum_cls is None:
                    continue
                # names compare in upper case: ODrive's DBC spells Reboot's Action choices
                # in lower case ("reboot"), the enums' members are upper case
                dbc_choices = {int(k): str(v).upper() for k, v in (s.choices or {}).items()}
                code_choices = {int(m.value): name for name, m in enum_cls.__members__.items()}
                if dbc_choices != code_choices:
                    raise DbcError(
                        f"{self.path}: {bound.name}.{s.name} choices differ from "
                        f"{enum_cls.__name__}"
                    )

    # ------------------------------------------------------------------- lookups

    def frame_id(self, cls: type, node: Node | None = None) -> int:
        """Arbitration ID of message ``cls`` for ``node`` (``None`` for bench frames)."""
        return self._bound(cls, node).message.frame_id

    def frame_key(self, name: str) -> tuple[int, bool]:
        """``(arbitration ID, is extended)`` of the DBC message called ``name``.

        Raises :class:`EncodeError` naming the message if the contract has no such frame.
        """
        for bound in self._by_key.values():
            if bound.name == name:
                return bound.message.frame_id, bool(bound.message.is_extended_frame)
        raise EncodeError(f"no message {name!r} in {self.path.name}")

    def message_name(self, cls: type, node: Node | None = None) -> str:
        """The DBC name of message ``cls`` for ``node`` (``Left_Heartbeat``, ``Bench_Step``)."""
        return self._bound(cls, node).name

    def signal_scale(
        self, cls: type, field: str, node: Node | None = None
    ) -> tuple[float, float, float]:
        """``(resolution, minimum, maximum)`` of the signal carrying ``field`` of ``cls``.

        For code that must round or bound a value as the frame will (constants that mirror
        a DBC scale or range are read here, never written twice).
        """
        bound = self._bound(cls, node)
        sname = dict(bound.fields).get(field)
        if sname is None:
            raise EncodeError(f"{bound.name} has no field {field!r}")
        sig = bound.message.get_signal_by_name(sname)
        if sig.minimum is None or sig.maximum is None:
            raise EncodeError(f"{bound.name}.{sname} has no range in {self.path.name}")
        return float(sig.scale), float(sig.minimum), float(sig.maximum)

    def cycle_time_ms(self, cls: type, node: Node | None = None) -> int | None:
        """The DBC cycle time (ms) of message ``cls`` for ``node``; None if it is not cyclic."""
        return self._bound(cls, node).message.cycle_time

    def sender(self, cls: type, node: Node | None = None) -> str:
        """The DBC node that sends message ``cls`` (for ``node``); the first of several."""
        return str(self._bound(cls, node).message.senders[0])

    def senders(self, cls: type, node: Node | None = None) -> tuple[str, ...]:
        """Every DBC node that sends message ``cls`` (Address: the host and the drive)."""
        return tuple(str(s) for s in self._bound(cls, node).message.senders)

    def is_known(self, msg: can.Message) -> bool:
        """Whether ``msg``'s ID and ID format (11 or 29 bits) are a message of the contract."""
        return (msg.arbitration_id, msg.is_extended_id) in self._by_key

    def filters(self, pairs: Iterable[tuple[type, Node | None]]) -> list[dict[str, Any]]:
        """python-can ``can_filters`` that pass exactly the given messages."""
        out = []
        for cls, node in pairs:
            m = self._bound(cls, node).message
            out.append(
                {
                    "can_id": m.frame_id,
                    "can_mask": 0x1FFFFFFF if m.is_extended_frame else 0x7FF,
                    "extended": m.is_extended_frame,
                }
            )
        return out

    def _bound(self, cls: type, node: Node | None) -> _Bound:
        try:
            return self._by_type[(cls, node)]
        except KeyError:
            raise EncodeError(
                f"no message {getattr(cls, '__name__', cls)} for node {node!r}"
            ) from None

    # -------------------------------------------------------------------- encode

    def encode(self, payload: Payload, node: Node | None = None) -> can.Message:
        """Encode ``payload`` for ``node`` into a ``can.Message`` (strict)."""
        bound = self._by_type.get((type(payload), node))
        encoder = None if bound is None else bound.encoder
        if encoder is None or bound is None:
            return self._encode_checked(payload, node)
        # The fast path: every value in range (NaN is not) and packed in one go.  Anything
        # else takes the general path, which names the first bad signal.
        try:
            data = encoder(payload)
        except Exception:
            data = None
        if data is None:
            return self._encode_checked(payload, node)
        return self._message(bound, data)

    def _encode_checked(self, payload: Payload, node: Node | None) -> can.Message:
        """The general encoder: each signal checked in turn, the first bad one named."""
        bound = self._bound(type(payload), node)
        values: dict[str, Any] = {}
        for fname, sname, lo, hi, unit in bound.limits:
            v = getattr(payload, fname)
            if isinstance(v, bool | enum.IntEnum):
                v = int(v)
            if isinstance(v, float) and not math.isfinite(v):
                raise EncodeError(f"{bound.name}.{sname} = {v} is not finite")
            try:
                outside = v < lo or v > hi
            except TypeError:
                raise EncodeError(f"{bound.name}.{sname} = {v!r} is not a number") from None
            if outside:
                raise EncodeError(
                    f"{bound.name}.{sname} = {v} {unit} is outside [{lo}, {hi}]".replace("  ", " ")
                )
            values[sname] = v
        try:
            if bound.layout is not None:
                data = bound.layout.pack(values)
            else:
                data = bytearray(
                    bound.message.encode(values, scaling=True, padding=False, strict=False)
                )
        except Exception as err:
            raise EncodeError(f"{bound.name}: {err}") from err
        return self._message(bound, data)

    def _message(self, bound: _Bound, data: bytearray) -> can.Message:
        # can.Message(arbitration_id=..., data=data, is_extended_id=..., dlc=len(data),
        # check=False): built from the DBC's own ID and length, nothing to check
        return bare_message(
            0.0, bound.frame_id, bound.is_extended, False, False, None, len(data), data,
            False, True, False, False,
        )  # fmt: skip

    def request(self, cls: type, node: Node) -> can.Message:
        """An RTR frame asking ``node`` for message ``cls`` (ODrive's way of polling)."""
        bound = self._bound(cls, node)
        if not bound.requestable:
            raise EncodeError(f"{bound.name} cannot be requested by RTR")
        return can.Message(
            arbitration_id=bound.message.frame_id,
            is_remote_frame=True,
            is_extended_id=False,
            dlc=bound.message.length,
        )

    def encode_secured(
        self, payload: Payload, node: Node, auth: Authenticator
    ) -> tuple[can.Message, ...]:
        """Encode a host command to drive ``node``, secured with the next freshness value.

        A :class:`SetInputVelAuth` carries its truncated freshness and MAC itself (the MAC
        covers its bytes 0..3); any other command is followed by a :class:`HostAuth` PDU whose
        MAC covers the command's whole payload (SecOC's secured PDU collection).  Raises
        :class:`EncodeError` like :meth:`encode`.
        """
        fv = auth.next_fv(int(node))
        if type(payload) is SetInputVelAuth:
            mask = (1 << SETPOINT_FV_BITS) - 1
            msg = self.encode(
                SetInputVelAuth(payload.input_vel_revps, payload.stop_ref_revps, fv & mask, 0),
                node,
            )
            data = msg.data
            # the Auth_MAC signal: the MAC's bytes as they are (the signal is little-endian)
            data[4 : 4 + MAC_BYTES] = auth.mac(msg.arbitration_id, data[:4], fv)
            return (msg,)
        msg = self.encode(payload, node)
        bound = self._by_type[(type(payload), node)]
        cmd = bound.frame_id & 0x1F
        tag = HostAuth(
            int(node),
            cmd,
            fv & ((1 << AUTH_FV_BITS) - 1),
            auth.sign(msg.arbitration_id, msg.data, fv),
        )
        return msg, self.encode(tag, Node.HOST)

    @property
    def contract_hash(self) -> int:
        """32-bit hash of the wire contract as loaded: every message's ID, name, length and
        cycle time and every signal's layout, scale, offset, range and choices (comments and
        formatting do not count).  Host and drives compare it before arming."""
        h = self._contract_hash
        if h is None:
            lines = []
            for m in sorted(self.db.messages, key=lambda m: (m.frame_id, m.is_extended_frame)):
                lines.append(
                    f"{m.frame_id:x} {int(m.is_extended_frame)} {m.name} {m.length} {m.cycle_time}"
                )
                for sg in sorted(m.signals, key=lambda sg: sg.start):
                    choices = sorted((int(k), str(v)) for k, v in (sg.choices or {}).items())
                    lines.append(
                        f" {sg.name} {sg.start} {sg.length} {sg.byte_order} {int(sg.is_signed)} "
                        f"{int(sg.is_float)} {sg.scale!r} {sg.offset!r} {sg.minimum!r} "
                        f"{sg.maximum!r} {choices}"
                    )
            h = self._contract_hash = contract_digest(lines)
        return h

    # -------------------------------------------------------------------- decode

    def decode(self, msg: can.Message) -> Frame:
        """Decode one frame; raise :class:`DecodeError` with a ``reason`` if it is not valid."""
        bound = self._by_key.get((msg.arbitration_id, msg.is_extended_id))
        decoder = None if bound is None else bound.decoder
        data = msg.data
        if (
            decoder is None
            or bound is None
            or msg.is_remote_frame
            or msg.is_error_frame
            or len(data) != bound.length
            or msg.dlc != bound.length
        ):
            return self._decode_checked(msg)
        # The fast path for a valid frame; anything else takes the general path, which
        # names what is wrong.
        try:
            frame: Frame | None = decoder(data)
        except Exception:
            frame = None
        return self._decode_checked(msg) if frame is None else frame

    def _decode_checked(self, msg: can.Message) -> Frame:
        """The general decoder: each check in turn, the first failure named."""
        bound, raw = self._validated(msg)
        if raw is None:
            return Frame(bound.node, Request(bound.cls))
        kwargs: dict[str, Any] = {}
        for fname, sname, _lo, _hi, _unit in bound.limits:
            v = raw[sname]
            conv = bound.convert[fname]
            try:
                kwargs[fname] = conv(v) if conv is not float else float(v)
            except ValueError as err:
                raise DecodeError(
                    f"{bound.name}.{sname} = {v} is not a defined choice", reason="choice"
                ) from err
        return Frame(bound.node, bound.cls(**kwargs))

    def decode_signals(self, msg: can.Message) -> tuple[str, dict[str, float | int]]:
        """Validate ``msg`` like :meth:`decode` and return its DBC name and signal values.

        Values are physical (scaled) numbers; choice signals stay integers.  An RTR
        request decodes to an empty dict.
        """
        bound, raw = self._validated(msg)
        if raw is None:
            return bound.name, {}
        for sname, choices in bound.choice_tables:
            if int(raw[sname]) not in choices:
                raise DecodeError(
                    f"{bound.name}.{sname} = {raw[sname]} is not a defined choice", reason="choice"
                )
        return bound.name, raw

    def decode_columns(
        self, key: tuple[int, bool], payloads: bytes, n: int
    ) -> tuple[str, dict[str, np.ndarray], np.ndarray, Counter[str]]:
        """:meth:`decode_signals` of ``n`` frames of one message at once, for a log's or a
        collector's columns: ``key`` is (arbitration id, extended), ``payloads`` the data
        bytes of the frames (each of the message's length), back to back.  Returns its DBC
        name, one array per signal holding the frames :meth:`decode_signals` accepts (the
        same values), which frames those are (a boolean mask), and the count of the others
        by :attr:`DecodeError.reason` (``range``, ``choice``).  Messages the fast path cannot
        express go frame by frame through :meth:`decode_signals`."""
        bound = self._by_key.get(key)
        if bound is None:
            raise DecodeError(f"unknown frame ID 0x{key[0]:X}", reason="unknown_id")
        layout = bound.layout
        if layout is None:
            return self._decode_columns_slowly(bound, key, payloads, n)
        cols = dict(zip(layout.names, layout.unpack_columns(payloads, n), strict=True))
        ok = np.ones(n, dtype=bool)
        rejected: Counter[str] = Counter()
        for _fname, sname, lo, hi, _unit in bound.limits:
            v = cols[sname]
            bad = ok & ~((v >= lo) & (v <= hi))  # NaN compares false: out of range
            rejected["range"] += int(bad.sum())
            ok &= ~bad
        for sname, choices in bound.choice_tables:
            bad = ok & ~np.isin(cols[sname], np.fromiter(choices, dtype=np.int64))
            rejected["choice"] += int(bad.sum())
            ok &= ~bad
        if not ok.all():
            cols = {k: v[ok] for k, v in cols.items()}
        return bound.name, cols, ok, +rejected

    def _decode_columns_slowly(
        self, bound: _Bound, key: tuple[int, bool], payloads: bytes, n: int
    ) -> tuple[str, dict[str, np.ndarray], np.ndarray, Counter[str]]:
        rejected: Counter[str] = Counter()
        rows: dict[str, list[Any]] = {}
        ok = np.zeros(n, dtype=bool)
        size = bound.length
        for j, i in enumerate(range(0, n * size, size)):
            msg = can.Message(
                arbitration_id=key[0],
                is_extended_id=key[1],
                data=payloads[i : i + size],
                dlc=size,
            )
            try:
                _name, values = self.decode_signals(msg)
            except DecodeError as err:
                rejected[err.reason] += 1
                continue
            ok[j] = True
            for k, v in values.items():
                rows.setdefault(k, []).append(v)
        return bound.name, {k: np.asarray(v) for k, v in rows.items()}, ok, rejected

    def _validated(self, msg: can.Message) -> tuple[_Bound, dict[str, Any] | None]:
        """Look up, length-, CRC- and range-check ``msg``; ``None`` values for an RTR request."""
        bound = self._by_key.get((msg.arbitration_id, msg.is_extended_id))
        if bound is None:
            width = 8 if msg.is_extended_id else 3
            raise DecodeError(
                f"unknown frame ID 0x{msg.arbitration_id:0{width}X}"
                f"{' (extended)' if msg.is_extended_id else ''}",
                reason="unknown_id",
            )
        if msg.is_remote_frame:
            if not bound.requestable:
                raise DecodeError(
                    f"{bound.name}: remote frame for a message that cannot be requested",
                    reason="rtr",
                )
            return bound, None
        if msg.is_error_frame:
            raise DecodeError(f"{bound.name}: error frame", reason="error_frame")
        data = msg.data
        if len(data) != bound.length or msg.dlc != bound.length:
            raise DecodeError(
                f"{bound.name}: {len(data)} data bytes (DLC {msg.dlc}), expected {bound.length}",
                reason="length",
            )
        try:
            if bound.layout is not None:
                raw = bound.layout.unpack(data)
            else:
                raw = bound.message.decode(bytes(data), decode_choices=False, scaling=True)
        except Exception as err:
            raise DecodeError(f"{bound.name}: {err}", reason="malformed") from err
        for _fname, sname, lo, hi, unit in bound.limits:
            v = raw[sname]
            if not (lo <= v <= hi):  # also catches NaN
                raise DecodeError(
                    f"{bound.name}.{sname} = {v} {unit} is outside [{lo}, {hi}]".replace("  ", " "),
                    reason="range",
                )
        return bound, raw

    def describe_signals(self, name: str) -> list[dict[str, Any]]:
        """Signals of DBC message ``name`` with unit, bounds and choices (for log schemas)."""
        m = self.db.get_message_by_name(name)
        return [
            {
                "name": s.name,
                "unit": s.unit or "",
                "minimum": s.minimum,
                "maximum": s.maximum,
                "choices": {int(k): str(v) for k, v in (s.choices or {}).items()},
                # a bit field: the choices name its bits, a value may combine them
                "flags": s.name in FLAG_ENUMS,
                "is_float": s.is_float,
                "comment": s.comment or "",
            }
            for s in m.signals
        ]

    def all_messages(self) -> list[tuple[type, Node | None, str]]:
        """Every (payload class, node, DBC name) the codec knows."""
        return [(b.cls, b.node, b.name) for b in self._by_key.values()]
