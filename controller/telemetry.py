"""The controller's own log: its internals per tick, written to MCAP channels Foxglove reads.

The bus recorder sees every frame; only the controller knows its estimate, its
reference, its errors and the internals of the tracking law.  The node hands
:class:`McapTelemetry` one record per tracking tick on ``/controller/tick``; the
telemetry splits it into the log's channels (``docs/logs.md``):

* ``/controller/reference`` and ``/controller/estimate``: the numbers, plus
  ``.../pose`` (``foxglove.PoseInFrame``) and ``.../tf`` (``foxglove.FrameTransform``
  world -> chair_reference / chair_estimate) for the 3D panel;
* ``/controller/errors`` (x_e, y_e, phi_e), ``/controller/command`` (limited command,
  wheel speeds, and the raw command of the law);
* ``/controller/internals``: the law's ``internals()``; a key ``group.name`` goes to
  ``/controller/internals/group`` (sliding surfaces, QP status, filter-bank
  probabilities ... each on its own channel when the law names them so);
* any other nested mapping of the record on ``/controller/<key>``, the remaining
  scalars (route time, step duration) on ``/controller/tick``.

With :meth:`McapTelemetry.wrap_clock` it also sees every tick of the loop's clock:
``/controller/loop`` (tick duration; in real time the tick's lateness against its
schedule) for every tick, written when the next tick is awaited (outside the timed tick), and the controller package's log records (state
changes, safe stops, rejected frames, exceptions) as ``foxglove.Log`` on
``/controller/log``, stamped with the current tick.  Times are integer
nanoseconds: simulation time in lock-step; in real time the tick's schedule on the
wall clock (so that they line up with the recorder's receive times).

Writes go through :class:`dbc.runtime.mcapwriter.LogWriter` (small chunks with CRCs, flushed
as they close), after the tick's ack, off the lock-step critical path.
:class:`ForkedTelemetry` (what :func:`open_telemetry` gives where it can fork) moves
all of it to a forked process: the loop pickles each record and ships it, the child
runs this same class on it.  The tick record's
JSON is formatted by a plan worked out once per layout (``_Plan``: ``%``-templates that
give exactly the bytes of :func:`dbc.logschema.json_bytes`, at a fraction of its cost);
a record that does not fit its plan is written with ``json_bytes``.
:class:`NullTelemetry` is used when no log is wanted (benchmarks, replay).
"""

from __future__ import annotations

import logging
import math
import pickle
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from itertools import chain
from json.encoder import encode_basestring_ascii as _json_str
from operator import itemgetter
from pathlib import Path
from typing import Any, Protocol

from controller.clock import Clock, ClockStats, OnFrame
from dbc import logschema as ls
from dbc.runtime import stopping
from dbc.runtime.forked import ForkedWriter, ForkedWriterError
from dbc.runtime.mcapwriter import (
    DEFAULT_CHUNK_SIZE,
    DEFAULT_FLUSH_INTERVAL_S,
    LogWriter,
    Mirror,
)

log = logging.getLogger(__name__)

TICK_TOPIC = "/controller/tick"
LOOP_TOPIC = "/controller/loop"
LOG_TOPIC = "/controller/log"
#: Record keys of the node's tick record with a channel of their own (poses for ref and est).
_POSED = {
    "ref": ("/controller/reference", ls.REFERENCE_FRAME),
    "est": ("/controller/estimate", ls.ESTIMATE_FRAME),
}
_NAMED = {"err": "/controller/errors", "internals": "/controller/internals"}
#: A tick record that does not fit its plan is written by the general path and the plan
#: worked out again: at once for the first few misses, then every so many (values that
#: flip between layouts do not pay for a plan per tick).
_RETRIES = 8
_RETRY_EVERY = 64
_LEVELS = (
    (logging.CRITICAL, ls.LogLevel.FATAL),
    (logging.ERROR, ls.LogLevel.ERROR),
    (logging.WARNING, ls.LogLevel.WARNING),
    (logging.INFO, ls.LogLevel.INFO),
)


class Telemetry(Protocol):
    """What the controller logs through: records on topics, metadata records, and closing."""

    def log(self, topic: str, t_ns: int, record: Mapping[str, Any]) -> None:
        """Log ``record`` on the channel ``topic`` at tick time ``t_ns``."""

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Store the metadata record ``name`` (string values) in the log."""

    def close(self) -> None:
        """Write what is left and close the log; closing again does nothing."""


class NullTelemetry:
    """A telemetry that logs nothing (benchmarks, replay)."""

    def log(self, topic: str, t_ns: int, record: Mapping[str, Any]) -> None:
        """Drop the record."""

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Drop the metadata."""

    def attach(self, name: str, data: bytes) -> None:
        """Drop the file."""

    def wrap_clock(self, clock: Clock) -> Clock:
        """``clock`` itself: no tick is logged."""
        return clock

    def close(self) -> None:
        """Nothing to close."""


class _LoopLog:
    """What both controller logs share: the hooks :class:`ObservedClock` calls, the copy of
    the controller thread's log records (:class:`_LogHandler`), and closing once.

    A subclass writes a tick's loop record (``_loop``) and a log record (``_log_record``)
    its own way, and closes its file in ``_close_log``.
    """

    def __init__(self) -> None:
        self._offset_ns = 0  # tick time -> log time (real time: the wall clock at tick 0)
        self._tick_ns = 0
        self._handler: _LogHandler | None = None
        self._pending_loop: tuple[int, int, int | None] | None = None
        self._closed = False

    def wrap_clock(self, clock: Clock) -> Clock:
        """A clock that behaves like ``clock`` and logs every tick (``/controller/loop``)."""
        return ObservedClock(clock, self)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        stopping.at("flush")
        self._remove_handler()
        self._flush_loop()
        self._close_log()

    def _started(self, lockstep: bool) -> None:
        self._set_offset(0 if lockstep else time.time_ns())
        self._remove_handler()
        self._handler = _LogHandler(self, threading.get_ident())
        logging.getLogger("controller").addHandler(self._handler)

    def _set_offset(self, offset_ns: int) -> None:
        self._offset_ns = offset_ns

    def _remove_handler(self) -> None:
        if self._handler is not None:
            logging.getLogger("controller").removeHandler(self._handler)
            self._handler = None

    def _flush_loop(self) -> None:
        if self._pending_loop is not None:
            self._loop(*self._pending_loop)
            self._pending_loop = None

    def _loop(self, t_ns: int, tick_ns: int, lateness_ns: int | None) -> None:
        raise NotImplementedError

    def _log_record(self, record: logging.LogRecord) -> None:
        self._log_line(
            self._tick_ns,
            record.levelno,
            record.getMessage(),
            record.name,
            record.filename,
            record.lineno,
            time.time_ns(),
        )

    def _log_line(
        self,
        tick_ns: int,
        levelno: int,
        message: str,
        name: str,
        filename: str,
        lineno: int,
        now_ns: int,
    ) -> None:
        raise NotImplementedError

    def _close_log(self) -> None:
        raise NotImplementedError


class McapTelemetry(_LoopLog):
    """The controller's MCAP log (see the module doc for its channels)."""

    def __init__(
        self,
        path: str | Path,
        *,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        profile: str = "",
        pose_every: int = 10,
        mirror: Mirror | None = None,
    ) -> None:
        """``pose_every``: write the Foxglove pose/transform channels every this many ticks
        (10: 10 Hz at the 100 Hz loop, enough to watch the chair; the full-rate estimate and
        reference are in their JSON channels).  ``mirror`` sees every message the log gets
        (the caller's live view; :class:`dbc.runtime.mcapwriter.Mirror`)."""
        super().__init__()
        self.path = Path(path)
        self.pose_every = max(1, pose_every)
        self._ticks = 0
        self._w = LogWriter(
            self.path,
            profile=profile,
            library="wheelchair-hil controller",
            chunk_size=chunk_size,
            flush_interval_s=flush_interval_s,
            mirror=mirror,
        )
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._seq = 0
        self._now_ns = 0  # publish time of the record being written
        self._groups: dict[tuple[str, ...], tuple[tuple[str, str, str], ...]] = {}
        self._plans: dict[tuple[Any, ...], _Plan | None] = {}  # by the tick record's keys
        self._misses: dict[tuple[Any, ...], int] = {}

    # ------------------------------------------------------------------ writing

    def _channel(self, topic: str, schema_name: str, schema: bytes) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            sid = self._schemas.get(schema_name)
            if sid is None:
                sid = self._schemas[schema_name] = self._w.register_schema(
                    schema_name, "jsonschema", schema
                )
            cid = self._channels[topic] = self._w.register_channel(topic, "json", sid)
        return cid

    def _put(self, cid: int, t_ns: int, data: bytes) -> None:
        self._seq += 1
        self._w.add_message(cid, t_ns, self._now_ns, data, self._seq)

    def _json(self, topic: str, t_ns: int, record: Mapping[str, Any]) -> None:
        cid = self._channels.get(topic)
        if cid is None:
            title = topic.strip("/").replace("/", ".")
            schema = ls.json_bytes(ls.record_schema(title, record))
            cid = self._channel(topic, title, schema)
        self._put(cid, t_ns, ls.json_bytes(record))

    def _foxglove(self, topic: str, schema: str, t_ns: int, data: bytes) -> None:
        cid = self._channels.get(topic)
        if cid is None:
            cid = self._channel(topic, schema, ls.foxglove_schema(schema))
        self._put(cid, t_ns, data)

    # --------------------------------------------------------------- Telemetry

    def log(self, topic: str, t_ns: int, record: Mapping[str, Any]) -> None:
        """One record at tick time ``t_ns``; the node's tick record is split into channels."""
        self._log_at(topic, t_ns, record, time.time_ns())

    def _log_at(self, topic: str, t_ns: int, record: Mapping[str, Any], now_ns: int) -> None:
        """:meth:`log`, published at wall-clock time ``now_ns``."""
        t = t_ns + self._offset_ns
        self._now_ns = now_ns
        if topic != TICK_TOPIC:
            self._json(topic, t, record)
            return
        with_pose = self._ticks % self.pose_every == 0
        self._ticks += 1
        keys = tuple(record) if type(record) is dict else None
        plan = None if keys is None else self._plans.get(keys)
        if plan is not None:
            try:
                payloads = plan.encode(record)
            except Exception:  # whatever it is, the general path meets it as before
                payloads = None
            if payloads is not None:
                if with_pose:
                    self._write_posed(plan, payloads, t, record)
                    return
                add, now, seq = self._w.add_message, self._now_ns, self._seq
                try:
                    for cid, data in zip(plan.cids, payloads, strict=True):
                        seq += 1
                        add(cid, t, now, data, seq)
                finally:
                    self._seq = seq
                return
        for topic_, value, frame in self._route(record):
            self._json(topic_, t, value)
            if frame is not None and with_pose:
                self._pose(topic_, frame, t, value)
        if keys is not None:
            self._learn(keys, record)

    def _route(self, record: Mapping[str, Any]) -> Iterator[tuple[str, Any, str | None]]:
        """The channels of a tick record in the order they are written: (topic, values, the
        pose frame for ``ref`` and ``est``, else None).  Also run on placeholders (``_Node``,
        ``_Leaf``) to work out a :class:`_Plan`, so both paths split records alike."""
        scalars: dict[str, Any] = {}
        command: dict[str, Any] = {}
        for key, value in record.items():
            if not isinstance(value, Mapping):
                scalars[key] = value
            elif key in _POSED:
                base, frame = _POSED[key]
                yield base, value, frame
            elif key == "internals":
                groups = self._internals(value)
                for topic, values in groups.items():
                    yield topic, values, None
            elif key in _NAMED:
                yield _NAMED[key], value, None
            elif key == "cmd":
                command.update(value)
            elif key == "cmd_raw":
                command["raw"] = dict(value)
            else:
                yield f"/controller/{key}", value, None
        if command:
            yield "/controller/command", command, None
        if scalars:
            yield TICK_TOPIC, scalars, None

    def _write_posed(
        self, plan: _Plan, payloads: tuple[bytes, ...], t: int, record: Mapping[str, Any]
    ) -> None:
        payload = iter(payloads)
        for step in plan.steps:
            if isinstance(step, int):
                self._put(step, t, next(payload))
            else:
                base, frame, key = step
                self._pose(base, frame, t, record[key])

    def _learn(self, keys: tuple[Any, ...], record: Mapping[str, Any]) -> None:
        """Work out the plan of a tick record written by the general path (after its first
        record, and again when a record no longer fits: rarely once that happened often)."""
        misses = self._misses[keys] = self._misses.get(keys, 0) + 1
        if misses <= _RETRIES or misses % _RETRY_EVERY == 0:
            self._plans[keys] = _Plan.for_record(self, record)

    def _pose(self, base: str, frame: str, t: int, v: Mapping[str, Any]) -> None:
        try:
            x, y, h = float(v["x"]), float(v["y"]), float(v["heading"])
        except (KeyError, TypeError, ValueError):
            return
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(h)):
            return  # no pose to show (its JSON channel has the nulls); sin(inf) would raise
        self._foxglove(
            base + "/pose", "foxglove.PoseInFrame", t, ls.pose_in_frame(t, ls.WORLD_FRAME, x, y, h)
        )
        self._foxglove(
            base + "/tf",
            "foxglove.FrameTransform",
            t,
            ls.frame_transform(t, ls.WORLD_FRAME, frame, x, y, h),
        )

    def _internals(self, internals: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
        keys = tuple(internals)
        plan = self._groups.get(keys)
        if plan is None:  # (topic, field, key) per internal, worked out once per key set
            rows = []
            for key in keys:
                group, dot, name = key.partition(".")
                topic = f"/controller/internals/{group}" if dot else "/controller/internals"
                rows.append((topic, name if dot else key, key))
            plan = self._groups[keys] = tuple(rows)
        groups: dict[str, dict[str, Any]] = {}
        for topic, name, key in plan:
            groups.setdefault(topic, {})[name] = internals[key]
        return groups

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write the MCAP metadata record ``name``, its values as strings."""
        self._w.add_metadata(name, {k: str(v) for k, v in data.items()})

    def attach(self, name: str, data: bytes, now_ns: int | None = None) -> None:
        """Store a file (e.g. the controller's configuration) in the log."""
        now = time.time_ns() if now_ns is None else now_ns
        self._w.add_attachment(name, data, log_time=now, create_time=now)

    def _close_log(self) -> None:
        self._w.close()

    # ------------------------------------------------------------ clock hooks

    def _loop(
        self, t_ns: int, tick_ns: int, lateness_ns: int | None, now_ns: int | None = None
    ) -> None:
        self._now_ns = time.time_ns() if now_ns is None else now_ns
        rec: dict[str, Any] = {"tick_us": tick_ns / 1000.0}
        if lateness_ns is not None:
            rec["lateness_us"] = lateness_ns / 1000.0
        self._json(LOOP_TOPIC, t_ns + self._offset_ns, rec)

    def _log_line(
        self,
        tick_ns: int,
        levelno: int,
        message: str,
        name: str,
        filename: str,
        lineno: int,
        now_ns: int,
    ) -> None:
        level = next((lv for n, lv in _LEVELS if levelno >= n), ls.LogLevel.DEBUG)
        t = tick_ns + self._offset_ns
        self._now_ns = now_ns
        self._foxglove(
            LOG_TOPIC,
            "foxglove.Log",
            t,
            ls.log_message(t, level, message, name, filename, lineno),
        )


class ForkedTelemetry(_LoopLog):
    """:class:`McapTelemetry` written by a forked process (:class:`dbc.runtime.forked.ForkedWriter`).

    The loop only ships what it logs (each record pickled at once, so it may change
    afterwards; its publish time taken in the loop); the child runs a
    :class:`McapTelemetry` on it, so the file, its channels and their bytes are the same.
    Raises :class:`~dbc.runtime.forked.ForkedWriterError` if the writer cannot start
    (:func:`open_telemetry` then writes in the loop instead).  If the writer dies, records
    are counted in ``writer.lost`` and the loop goes on; :meth:`close` raises then.
    """

    def __init__(self, path: str | Path, *, batch: int = 64, **options: Any) -> None:
        super().__init__()
        self.path = Path(path)
        self.writer = ForkedWriter(
            f"telemetry {self.path}", lambda: _TelemetrySink(self.path, options), batch=batch
        )
        self.writer.start()
        self._put = self.writer.put

    def log(self, topic: str, t_ns: int, record: Mapping[str, Any]) -> None:
        """Ship ``record``, pickled now, and its publish time to the writer's McapTelemetry."""
        self._put(("log", topic, t_ns, pickle.dumps(record, 5), time.time_ns()))

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Ship the metadata record ``name``, its values as strings, to the writer."""
        self._put(("metadata", name, {k: str(v) for k, v in data.items()}))

    def attach(self, name: str, data: bytes) -> None:
        """Ship the file ``name`` to the writer, which stores it in the log (as an attachment)."""
        self._put(("attach", name, bytes(data), time.time_ns()))

    def _close_log(self) -> None:
        """Write the rest and close the log (waits for the writer)."""
        self.writer.stop()

    def _started(self, lockstep: bool) -> None:
        # real time: the loop never waits for the writer (dbc.runtime.forked); lock-step
        # runs keep the pipe's flow control, which loses nothing
        if not lockstep:
            self.writer.ship_from_thread()
        super()._started(lockstep)

    # The hooks of _LoopLog: shipped, to be written by the child's McapTelemetry.

    def _set_offset(self, offset_ns: int) -> None:
        self._offset_ns = offset_ns
        self._put(("offset", offset_ns))

    def _loop(self, t_ns: int, tick_ns: int, lateness_ns: int | None) -> None:
        self._put(("loop", t_ns, tick_ns, lateness_ns, time.time_ns()))

    def _log_line(
        self,
        tick_ns: int,
        levelno: int,
        message: str,
        name: str,
        filename: str,
        lineno: int,
        now_ns: int,
    ) -> None:
        self._put(("line", tick_ns, levelno, message, name, filename, lineno, now_ns))


class _TelemetrySink:
    """The writer process's side of :class:`ForkedTelemetry`."""

    def __init__(self, path: Path, options: dict[str, Any]) -> None:
        self.tel = McapTelemetry(path, **options)

    def take(self, ops: list[tuple[Any, ...]]) -> None:
        tel = self.tel
        loads = pickle.loads
        for op in ops:
            kind = op[0]
            if kind == "log":
                tel._log_at(op[1], op[2], loads(op[3]), op[4])
            elif kind == "loop":
                tel._loop(op[1], op[2], op[3], op[4])
            elif kind == "line":
                tel._log_line(*op[1:])
            elif kind == "offset":
                tel._offset_ns = op[1]
            elif kind == "metadata":
                tel.metadata(op[1], op[2])
            elif kind == "attach":
                tel.attach(op[1], op[2], op[3])

    def close(self) -> None:
        self.tel.close()


def open_telemetry(path: str | Path, **options: Any) -> McapTelemetry | ForkedTelemetry:
    """The controller's log at ``path``: written by a forked process where one can be
    started, else in the loop (logged)."""
    try:
        return ForkedTelemetry(path, **options)
    except ForkedWriterError as err:
        log.warning("writing the controller's log in the loop: %s", err)
        return McapTelemetry(path, **options)


class _Leaf:
    """Placeholder for a scalar of the tick record while a plan is worked out."""

    __slots__ = ("index", "key", "type", "var")

    def __init__(self, var: str, index: int, key: str, type_: type) -> None:
        self.var, self.index, self.key, self.type = var, index, key, type_


class _Node(dict[str, Any]):
    """Placeholder for a dict of the tick record: its keys, placeholders as values."""

    __slots__ = ("key", "var")

    def __init__(self, var: str, key: str) -> None:
        super().__init__()
        self.var, self.key = var, key


class _Null:
    """Formats as JSON ``null`` with ``%r``: stands in for a non-finite float."""

    __slots__ = ()

    def __repr__(self) -> str:
        return "null"


_NULL = _Null()
#: Scalars a plan formats itself (exact types: bool is not int, numpy floats are not float).
_SCALARS = frozenset({float, int, str, bool, type(None)})
#: Scalars a plan writes as JSON text of its own (``%s``), not with their ``repr`` (``%r``).
_CONVERT = frozenset({str, bool, type(None)})


def _nulls(values: tuple[Any, ...], floats: tuple[int, ...]) -> tuple[Any, ...]:
    out = list(values)
    for i in floats:
        if not math.isfinite(out[i]):
            out[i] = _NULL
    return tuple(out)


class _Plan:
    """How the tick records of one key set become their channels' JSON, worked out once.

    ``json_bytes`` (``json.dumps``) costs a few µs per channel before it formats a single
    number; a tick record is ~10 channels of floats.  A plan's encoder (:class:`_Encoder`)
    checks that a record still has the layout it was made for (the same keys in the same
    order, all the way down; the same exact type for every scalar), gathers its scalars in
    one tuple and ``%``-formats each channel with a template made from the layout:
    floats and ints with ``%r`` (``float.__repr__``/``int.__repr__``, what ``json.dumps``
    writes), strings through json's own ``encode_basestring_ascii``, non-finite floats as
    ``null`` (like :func:`dbc.logschema.json_bytes`).  A channel whose values equal the
    previous tick's (e.g. the diagnosis between two fixes) reuses its bytes, unless a value
    is zero (``0.0 == -0.0``).  The bytes are those of ``json_bytes`` on the channel's
    record; a record that does not fit (or any exception) takes the general path, which
    calls ``json_bytes``.

    The layout is split by :meth:`McapTelemetry._route` itself, run on placeholders, so the
    channels, their order and the command/internals merging are the general path's.
    """

    __slots__ = ("cids", "encode", "steps")

    def __init__(
        self,
        encode: Callable[[Mapping[str, Any]], tuple[bytes, ...] | None],
        cids: tuple[int, ...],
        steps: tuple[int | tuple[str, str, str], ...],
    ) -> None:
        self.encode = encode  # record -> the JSON channels' payloads, or None: does not fit
        self.cids = cids  # the JSON channels, in write order
        self.steps = steps  # cids and (base, frame, record key) of the poses, in write order

    @classmethod
    def for_record(cls, tel: McapTelemetry, record: Mapping[str, Any]) -> _Plan | None:
        """The plan of records laid out like ``record`` (just written by the general path,
        so that its channels exist); None if it has something a plan does not format."""
        checks: list[tuple[str, str, str, tuple[str, ...]]] = []  # var = parent[key], keys
        sizes = {"rec": len(record)}
        root = _placeholders(record, "rec", "", checks, sizes)
        if root is None:
            return None
        leaves: list[_Leaf] = []  # the scalars of all channels, in write order
        fmts: list[tuple[str, int, int]] = []  # per channel: template, its leaves [a, b)
        cids: list[int] = []
        steps: list[int | tuple[str, str, str]] = []
        for topic, value, frame in tel._route(root):
            cid = tel._channels.get(topic)
            if cid is None:
                return None
            a = len(leaves)
            fmts.append((_template(value, leaves), a, len(leaves)))
            cids.append(cid)
            steps.append(cid)
            if frame is not None:
                steps.append((topic, frame, value.key))

        encoder = _Encoder(checks, sizes, leaves, fmts)
        return cls(encoder, tuple(cids), tuple(steps))


def _placeholders(
    d: Mapping[Any, Any],
    var: str,
    key: str,
    checks: list[tuple[str, str, str, tuple[str, ...]]],
    sizes: dict[str, int],
) -> _Node | None:
    """``d`` with placeholders for its scalars and dicts (None: something else is in it)."""
    node = _Node(var, key)
    for i, (k, v) in enumerate(d.items()):
        if type(k) is not str:
            return None
        t = type(v)
        if t is dict:
            sub = f"d{len(checks)}"
            checks.append((sub, var, k, tuple(v)))
            sizes[sub] = len(v)
            child = _placeholders(v, sub, k, checks, sizes)
            if child is None:
                return None
            node[k] = child
        elif t in _SCALARS:
            node[k] = _Leaf(var, i, k, t)
        else:
            return None
    return node


def _template(value: Mapping[str, Any], leaves: list[_Leaf]) -> str:
    """The ``%``-format of a channel's JSON; appends its scalars' placeholders to ``leaves``."""
    parts = []
    for k, v in value.items():
        name = _json_str(k).replace("%", "%%") + ":"
        if isinstance(v, _Leaf):
            leaves.append(v)
            parts.append(name + ("%s" if v.type in _CONVERT else "%r"))
        else:
            parts.append(name + _template(v, leaves))
    return "{" + ",".join(parts) + "}"


class _Encoder:
    """A plan's encoder: a record laid out as the plan's, as its channels' JSON payloads.

    It checks every dict of the record against the layout (type and keys, in order), takes
    all of their values in one flat tuple (``dict.values`` chained) and picks the scalars in
    the channels' write order with one ``itemgetter``; checks their exact types; writes any
    non-finite float as ``null`` and strings, bools and None as JSON; then ``%``-formats each
    channel with its template, reusing the previous tick's bytes where its values are the
    same (none of them zero: ``0.0 == -0.0``).  None: the record does not fit the layout.
    """

    __slots__ = ("checks", "converted", "floats", "fmts", "memo", "pick", "sum_floats", "types")

    def __init__(
        self,
        checks: list[tuple[str, str, str, tuple[str, ...]]],
        sizes: dict[str, int],
        leaves: list[_Leaf],
        fmts: list[tuple[str, int, int]],
    ) -> None:
        index = {"rec": 0}  # each dict's place among the record's dicts (pre-order)
        ops = []
        for var, parent, key, keys in checks:
            ops.append((index[parent], key, keys))
            index[var] = len(index)
        self.checks: tuple[tuple[int, str, tuple[str, ...]], ...] = tuple(ops)
        offset, at = {}, 0  # where each dict's values start in the flat tuple
        for var in sorted(index, key=index.__getitem__):
            offset[var] = at
            at += sizes[var]
        where = [offset[leaf.var] + leaf.index for leaf in leaves]
        self.pick: Callable[[tuple[Any, ...]], tuple[Any, ...]] = (
            itemgetter(*where) if len(where) > 1 else (lambda flat: tuple(flat[i] for i in where))
        )
        self.types = tuple(leaf.type for leaf in leaves)
        self.floats = tuple(i for i, leaf in enumerate(leaves) if leaf.type is float)
        # the floats' sum (one non-finite float makes it non-finite), getter made once
        self.sum_floats: Callable[[tuple[Any, ...]], float] | None = None
        if len(self.floats) > 1:
            floats_of = itemgetter(*self.floats)
            self.sum_floats = lambda v: sum(floats_of(v))
        elif self.floats:
            only = self.floats[0]
            self.sum_floats = lambda v: v[only]
        self.converted = tuple(
            (i, leaf.type) for i, leaf in enumerate(leaves) if leaf.type in _CONVERT
        )
        self.fmts = tuple(fmts)
        self.memo: list[tuple[tuple[Any, ...] | None, bytes]] = [(None, b"")] * len(fmts)

    def __call__(self, rec: Mapping[str, Any]) -> tuple[bytes, ...] | None:
        nodes = [rec]
        for parent, key, keys in self.checks:
            d = nodes[parent][key]
            if type(d) is not dict or tuple(d) != keys:
                return None
            nodes.append(d)
        v = self.pick(tuple(chain.from_iterable([n.values() for n in nodes])))
        if tuple(map(type, v)) != self.types:
            return None
        if self.sum_floats is not None:
            s = self.sum_floats(v)
            if s - s != 0.0:  # IEEE: a nan or an inf makes the sum non-finite
                v = _nulls(v, self.floats)
        if self.converted:
            w = list(v)
            for i, t in self.converted:
                x = w[i]
                w[i] = (
                    _json_str(x)
                    if t is str
                    else ("true" if x else "false")
                    if t is bool
                    else "null"
                )
            v = tuple(w)
        memo = self.memo
        out = []
        for j, (fmt, a, b) in enumerate(self.fmts):
            x = v[a:b]
            last, data = memo[j]
            if x != last or 0.0 in x:
                data = (fmt % x).encode()
                memo[j] = (x, data)
            out.append(data)
        return tuple(out)


class _LogHandler(logging.Handler):
    """Copies the controller thread's log records into the telemetry (never raises)."""

    def __init__(self, tel: _LoopLog, thread: int) -> None:
        super().__init__()
        self._tel = tel
        self._thread = thread

    def emit(self, record: logging.LogRecord) -> None:
        if record.thread != self._thread:
            return
        try:
            self._tel._log_record(record)
        except Exception:  # a log line must never break a tick
            self.handleError(record)


class ObservedClock:
    """Wraps a :class:`~controller.clock.Clock`; tells the telemetry about every tick."""

    def __init__(self, inner: Clock, tel: _LoopLog) -> None:
        self.inner = inner
        self._tel = tel
        self.period_ns = inner.period_ns
        self.lockstep = inner.lockstep
        self.stats: ClockStats = inner.stats
        self._t0 = 0

    def __getattr__(self, name: str) -> Any:  # ended_by and anything else of the clock
        return getattr(self.inner, name)

    def start(self) -> None:
        """Start the inner clock; the telemetry then copies this thread's log records."""
        self.inner.start()
        self._tel._started(self.lockstep)

    def wait_tick(self, on_frame: OnFrame) -> int | None:
        """As the inner clock's ``wait_tick``, after writing the previous tick's loop record."""
        self._tel._flush_loop()  # the previous tick's record, outside the timed tick
        t = self.inner.wait_tick(on_frame)
        if t is not None and t >= 0:  # not NOT_DUE
            self._tel._tick_ns = t
            self._t0 = time.perf_counter_ns()
        return t

    def tick_done(self, t_ns: int) -> None:
        """Close the inner clock's tick; its duration and lateness go to ``/controller/loop``."""
        self.inner.tick_done(t_ns)
        dur = time.perf_counter_ns() - self._t0
        late = self.inner.stats.lateness_ns
        self._tel._pending_loop = (t_ns, dur, None if self.lockstep or not late else late[-1])
