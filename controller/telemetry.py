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

Writes go through :class:`dbc.mcaplog.LogWriter` (small chunks with CRCs, flushed
as they close), after the tick's ack, off the lock-step critical path.
:class:`NullTelemetry` is used when no log is wanted (benchmarks, replay).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

from controller.clock import Clock, ClockStats, OnFrame
from dbc import logschema as ls
from dbc.mcaplog import DEFAULT_CHUNK_SIZE, DEFAULT_FLUSH_INTERVAL_S, LogWriter

TICK_TOPIC = "/controller/tick"
LOOP_TOPIC = "/controller/loop"
LOG_TOPIC = "/controller/log"
#: Record keys of the node's tick record with a channel of their own (poses for ref and est).
_POSED = {
    "ref": ("/controller/reference", ls.REFERENCE_FRAME),
    "est": ("/controller/estimate", ls.ESTIMATE_FRAME),
}
_NAMED = {"err": "/controller/errors", "internals": "/controller/internals"}
_LEVELS = (
    (logging.CRITICAL, ls.LogLevel.FATAL),
    (logging.ERROR, ls.LogLevel.ERROR),
    (logging.WARNING, ls.LogLevel.WARNING),
    (logging.INFO, ls.LogLevel.INFO),
)


class Telemetry(Protocol):
    def log(self, topic: str, t_ns: int, record: Mapping[str, Any]) -> None: ...

    def metadata(self, name: str, data: Mapping[str, str]) -> None: ...

    def close(self) -> None: ...


class NullTelemetry:
    def log(self, topic: str, t_ns: int, record: Mapping[str, Any]) -> None:
        pass

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        pass

    def attach(self, name: str, data: bytes) -> None:
        pass

    def wrap_clock(self, clock: Clock) -> Clock:
        return clock

    def close(self) -> None:
        pass


class McapTelemetry:
    """The controller's MCAP log (see the module doc for its channels)."""

    def __init__(
        self,
        path: str | Path,
        *,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        profile: str = "",
        pose_every: int = 10,
    ) -> None:
        """``pose_every``: write the Foxglove pose/transform channels every this many ticks
        (10: 10 Hz at the 100 Hz loop, enough to watch the chair; the full-rate estimate and
        reference are in their JSON channels)."""
        self.path = Path(path)
        self.pose_every = max(1, pose_every)
        self._ticks = 0
        self._w = LogWriter(
            self.path,
            profile=profile,
            library="wheelchair-hil controller",
            chunk_size=chunk_size,
            flush_interval_s=flush_interval_s,
        )
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._seq = 0
        self._offset_ns = 0  # tick time -> log time (real time: the wall clock at tick 0)
        self._tick_ns = 0
        self._now_ns = 0  # publish time of the record being written
        self._groups: dict[tuple[str, ...], tuple[tuple[str, str, str], ...]] = {}
        self._handler: _LogHandler | None = None
        self._pending_loop: tuple[int, int, int | None] | None = None
        self._closed = False

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
        t = t_ns + self._offset_ns
        self._now_ns = time.time_ns()
        if topic != TICK_TOPIC:
            self._json(topic, t, record)
            return
        scalars: dict[str, Any] = {}
        command: dict[str, Any] = {}
        with_pose = self._ticks % self.pose_every == 0
        self._ticks += 1
        for key, value in record.items():
            if not isinstance(value, Mapping):
                scalars[key] = value
            elif key in _POSED:
                base, frame = _POSED[key]
                self._json(base, t, value)
                if with_pose:
                    self._pose(base, frame, t, value)
            elif key == "internals":
                self._internals(t, value)
            elif key in _NAMED:
                self._json(_NAMED[key], t, value)
            elif key == "cmd":
                command.update(value)
            elif key == "cmd_raw":
                command["raw"] = dict(value)
            else:
                self._json(f"/controller/{key}", t, value)
        if command:
            self._json("/controller/command", t, command)
        if scalars:
            self._json(TICK_TOPIC, t, scalars)

    def _pose(self, base: str, frame: str, t: int, v: Mapping[str, Any]) -> None:
        try:
            x, y, h = float(v["x"]), float(v["y"]), float(v["heading"])
        except (KeyError, TypeError, ValueError):
            return
        self._foxglove(
            base + "/pose", "foxglove.PoseInFrame", t, ls.pose_in_frame(t, ls.WORLD_FRAME, x, y, h)
        )
        self._foxglove(
            base + "/tf",
            "foxglove.FrameTransform",
            t,
            ls.frame_transform(t, ls.WORLD_FRAME, frame, x, y, h),
        )

    def _internals(self, t: int, internals: Mapping[str, Any]) -> None:
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
        for topic, values in groups.items():
            self._json(topic, t, values)

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        self._w.add_metadata(name, {k: str(v) for k, v in data.items()})

    def attach(self, name: str, data: bytes) -> None:
        """Store a file (e.g. the controller's configuration) in the log."""
        now = time.time_ns()
        self._w.add_attachment(name, data, log_time=now, create_time=now)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._remove_handler()
        self._flush_loop()
        self._w.close()

    # ------------------------------------------------------------ clock hooks

    def wrap_clock(self, clock: Clock) -> Clock:
        """A clock that behaves like ``clock`` and logs every tick (``/controller/loop``)."""
        return ObservedClock(clock, self)

    def _started(self, lockstep: bool) -> None:
        self._offset_ns = 0 if lockstep else time.time_ns()
        self._remove_handler()
        self._handler = _LogHandler(self, threading.get_ident())
        logging.getLogger("controller").addHandler(self._handler)

    def _remove_handler(self) -> None:
        if self._handler is not None:
            logging.getLogger("controller").removeHandler(self._handler)
            self._handler = None

    def _flush_loop(self) -> None:
        if self._pending_loop is not None:
            self._loop(*self._pending_loop)
            self._pending_loop = None

    def _loop(self, t_ns: int, tick_ns: int, lateness_ns: int | None) -> None:
        self._now_ns = time.time_ns()
        rec: dict[str, Any] = {"tick_us": tick_ns / 1000.0}
        if lateness_ns is not None:
            rec["lateness_us"] = lateness_ns / 1000.0
        self._json(LOOP_TOPIC, t_ns + self._offset_ns, rec)

    def _log_record(self, record: logging.LogRecord) -> None:
        level = next((lv for n, lv in _LEVELS if record.levelno >= n), ls.LogLevel.DEBUG)
        t = self._tick_ns + self._offset_ns
        self._now_ns = time.time_ns()
        self._foxglove(
            LOG_TOPIC,
            "foxglove.Log",
            t,
            ls.log_message(
                t, level, record.getMessage(), record.name, record.filename, record.lineno
            ),
        )


class _LogHandler(logging.Handler):
    """Copies the controller thread's log records into the telemetry (never raises)."""

    def __init__(self, tel: McapTelemetry, thread: int) -> None:
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

    def __init__(self, inner: Clock, tel: McapTelemetry) -> None:
        self.inner = inner
        self._tel = tel
        self.period_ns = inner.period_ns
        self.lockstep = inner.lockstep
        self.stats: ClockStats = inner.stats
        self._t0 = 0

    def __getattr__(self, name: str) -> Any:  # ended_by and anything else of the clock
        return getattr(self.inner, name)

    def start(self) -> None:
        self.inner.start()
        self._tel._started(self.lockstep)

    def wait_tick(self, on_frame: OnFrame) -> int | None:
        self._tel._flush_loop()  # the previous tick's record, outside the timed tick
        t = self.inner.wait_tick(on_frame)
        if t is not None:
            self._tel._tick_ns = t
            self._t0 = time.perf_counter_ns()
        return t

    def tick_done(self, t_ns: int) -> None:
        self.inner.tick_done(t_ns)
        dur = time.perf_counter_ns() - self._t0
        late = self.inner.stats.lateness_ns
        self._tel._pending_loop = (t_ns, dur, None if self.lockstep or not late else late[-1])
