"""Reading the project's MCAP logs, MCAP as a python-can log format, and merging logs.

* :func:`iter_records` / :func:`iter_messages` read a log **in file order** (which is
  bus order for ``/can/raw``), checking every chunk's CRC.  A truncated or damaged
  file (a killed recorder) is read as far as it is intact, with a
  :class:`TruncatedLogWarning` that names the file, the byte offset and the
  messages read.
* :class:`MCAPReader` and :class:`MCAPWriter` are python-can's ``MessageReader`` /
  ``MessageWriter`` for ``.mcap``, registered through the entry points
  ``can.io.message_reader`` / ``can.io.message_writer`` (pyproject.toml), so that
  ``can.LogReader("x.mcap")``, ``can_player x.mcap``, ``can_logger -f x.mcap`` and
  ``can_logconvert x.mcap x.asc`` work.  The writer produces the recorder's layout
  (raw, decoded and Foxglove channels).
* :func:`merge_into` rewrites a log with the channels, attachments and metadata of
  other logs interleaved by log time (:func:`tools.logs.runlog.finalize` puts the
  controller's log into ``run.mcap`` this way).
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import warnings
from collections.abc import Callable, Collection, Generator, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, cast

import can
from can.io.generic import BinaryIOMessageReader, BinaryIOMessageWriter
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    Footer,
    McapRecord,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import StreamReader

from dbc import logschema as ls
from dbc.codec import DBC_PATH, BenchStep, Codec
from dbc.errors import DecodeError
from dbc.runtime.errors import WheelchairError
from dbc.runtime.mcapwriter import LogWriter, chunk_records
from tools.logs.recorder import FrameLog, versions

PathOrFile = str | os.PathLike[str] | IO[bytes]


class TruncatedLogWarning(UserWarning):
    """The log ends before its footer or has a damaged record; the intact part was read."""


class LogFormatError(WheelchairError):
    """The file is not an MCAP log this project can read."""


# -------------------------------------------------------------------------- reading


class _FastStreamReader(StreamReader):
    """The mcap library's stream reader, told to skip message-index records.

    Reading in file order never needs them, and parsing their entries one by one was
    most of the time spent reading a log.  ``records`` reads the bytes a skipped
    record leaves unread (its "padding"), so the data-section CRC still covers them.
    """

    def _read_record(self, opcode: int, length: int) -> McapRecord | None:
        if opcode == Opcode.MESSAGE_INDEX:
            return None
        return cast(McapRecord | None, super()._read_record(opcode, length))


def iter_records(source: PathOrFile) -> Iterator[McapRecord]:
    """Every record of an MCAP file in file order (chunks opened, CRCs checked).

    Message-index records are not returned (nothing reading in file order needs them).
    Stops with a :class:`TruncatedLogWarning` where the file stops being intact.
    Raises :class:`LogFormatError` if it is not an MCAP file at all.
    """
    own = not hasattr(source, "read")
    fh = cast(IO[bytes], open(source, "rb") if own else source)  # type: ignore[arg-type]  # noqa: SIM115
    name = getattr(fh, "name", "<stream>")
    messages = 0

    def records() -> Iterator[McapRecord]:
        for rec in _FastStreamReader(fh, emit_chunks=True, validate_crcs=True).records:
            if isinstance(rec, Chunk):
                yield from chunk_records(rec)
            else:
                yield rec

    try:
        it = records()
        while True:
            try:
                rec = next(it)
            except StopIteration:
                break
            except Exception as err:  # truncated or damaged: keep what was intact
                if messages == 0 and fh.tell() <= 8:
                    raise LogFormatError(f"{name}: not an MCAP file ({err})") from err
                size = _size(fh)
                if type(err).__name__ == "EndOfFile" or fh.tell() >= size:
                    # the record in progress runs past the end (a killed writer), whichever
                    # of its fields the reader was at when the bytes ran out
                    where = f"is cut off: its last record is incomplete at the end of the file ({size} bytes)"
                else:
                    where = f"is damaged at byte {fh.tell()} of {size}"
                warnings.warn(
                    TruncatedLogWarning(
                        f"{name}: the log {where} "
                        f"({type(err).__name__}: {str(err) or 'unexpected end of file'}); read "
                        f"{messages} messages from its intact part (was the recorder killed?)"
                    ),
                    stacklevel=2,
                )
                break
            if isinstance(rec, Message):
                messages += 1
            yield rec
    finally:
        if own:
            fh.close()


def _size(fh: IO[bytes]) -> int:
    try:
        return os.fstat(fh.fileno()).st_size
    except (OSError, AttributeError, ValueError):
        return -1


def iter_messages(
    source: PathOrFile, topics: Collection[str] | None = None
) -> Iterator[tuple[Channel, Message]]:
    """``(channel, message)`` in file order, optionally only on ``topics`` (see :func:`iter_records`)."""
    channels: dict[int, Channel] = {}
    for rec in iter_records(source):
        if isinstance(rec, Message):
            ch = channels.get(rec.channel_id)
            if ch is not None and (topics is None or ch.topic in topics):
                yield ch, rec
        elif isinstance(rec, Channel):
            channels[rec.id] = rec


@dataclass
class LogContents:
    """Everything but the messages: channels, schemas, attachments and metadata of a log."""

    channels: dict[int, Channel] = field(default_factory=dict)
    schemas: dict[int, Schema] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)
    #: metadata records by name; records of the same name are merged, later keys win
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    message_count: int = 0
    complete: bool = False

    def topics(self) -> set[str]:
        return {c.topic for c in self.channels.values()}


def scan(
    source: PathOrFile,
    on_message: Callable[[Channel, Message], None] | None = None,
) -> LogContents:
    """Read the whole log once; call ``on_message`` for each message in file order."""
    out = LogContents()
    for rec in iter_records(source):
        if isinstance(rec, Message):
            out.message_count += 1
            if on_message is not None:
                ch = out.channels.get(rec.channel_id)
                if ch is not None:
                    on_message(ch, rec)
        elif isinstance(rec, Channel):
            out.channels[rec.id] = rec
        elif isinstance(rec, Schema):
            out.schemas[rec.id] = rec
        elif isinstance(rec, Attachment):
            out.attachments[rec.name] = bytes(rec.data)
        elif isinstance(rec, Metadata):
            out.metadata.setdefault(rec.name, {}).update(rec.metadata)
        elif isinstance(rec, Footer):
            out.complete = True
    return out


def read_contents(path: str | os.PathLike[str]) -> LogContents:
    """Channels, attachments and metadata of a log: from its summary when it is intact
    (fast), else by reading it through (:func:`scan`)."""

    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh)
            summary = reader.get_summary()
            if summary is None:
                raise LogFormatError("no summary")
            out = LogContents(
                channels=dict(summary.channels), schemas=dict(summary.schemas), complete=True
            )
            out.message_count = summary.statistics.message_count if summary.statistics else 0
            for att in reader.iter_attachments():
                out.attachments[att.name] = bytes(att.data)
            for md in reader.iter_metadata():
                out.metadata.setdefault(md.name, {}).update(md.metadata)
            return out
    except Exception:  # not intact (or not MCAP): read it through, which says why
        return scan(path)


def raw_frame_count(path: str | os.PathLike[str]) -> int | None:
    """How many ``/can/raw`` frames the log's summary counts (None without an intact summary)."""
    try:
        with open(path, "rb") as fh:
            summary = make_reader(fh).get_summary()
    except Exception:  # not intact: the count is unknown, the frames may still be readable
        return None
    if summary is None or summary.statistics is None:
        return None
    counts = summary.statistics.channel_message_counts
    ids = [c.id for c in summary.channels.values() if c.topic == ls.RAW_TOPIC]
    return sum(counts.get(i, 0) for i in ids) if ids else None


def raw_to_message(data: bytes, log_time_ns: int | None = None) -> can.Message:
    """A ``/can/raw`` record as a ``can.Message``; ``timestamp`` is ``log_time`` if given."""
    d = json.loads(data)
    return can.Message(
        timestamp=d["timestamp"] if log_time_ns is None else log_time_ns * 1e-9,
        arbitration_id=d["arbitration_id"],
        is_extended_id=d["is_extended_id"],
        is_remote_frame=d.get("is_remote_frame", False),
        is_error_frame=d.get("is_error_frame", False),
        is_fd=d.get("is_fd", False),
        dlc=d["dlc"],
        data=base64.b64decode(d["data"]),
        channel=d.get("channel"),
        check=False,
    )


def iter_frames(
    source: PathOrFile, *, timestamps: str = "log"
) -> Iterator[tuple[int, can.Message]]:
    """``(log_time_ns, frame)`` of ``/can/raw`` in bus order.

    ``timestamps="log"`` stamps frames with their log time (simulation time in
    lock-step recordings, receive time otherwise); ``"receive"`` with the recorded
    wall-clock receive time.
    """
    if timestamps not in ("log", "receive"):
        raise ValueError(f"timestamps={timestamps!r}: choose 'log' or 'receive'")
    use_log = timestamps == "log"
    seen_raw = False
    bad = 0
    first_bad: tuple[int, str] | None = None
    for _ch, m in iter_messages(source, topics={ls.RAW_TOPIC}):
        seen_raw = True
        try:
            msg = raw_to_message(m.data, m.log_time if use_log else None)
        except (ValueError, KeyError, TypeError, binascii.Error) as err:
            # a record whose chunk CRC holds but whose JSON does not: skipped, counted, said
            bad += 1
            if first_bad is None:
                first_bad = (m.log_time, f"{type(err).__name__}: {err}")
            continue
        yield m.log_time, msg
    name = getattr(source, "name", source)
    if first_bad is not None:
        warnings.warn(
            TruncatedLogWarning(
                f"{name}: {bad} {ls.RAW_TOPIC} messages are damaged (not a frame's JSON) and "
                f"were skipped; the first at log time {first_bad[0] / 1e9:.3f} s ({first_bad[1]})"
            ),
            stacklevel=2,
        )
    if not seen_raw:
        warnings.warn(f"{name}: no {ls.RAW_TOPIC} channel, no frames", stacklevel=2)


# --------------------------------------------------------------- python-can plugin


#: A log time before this (1973) is a lock-step recording's simulation time, not a date.
SIMULATION_TIME_BEFORE_NS = 10**17


def iter_decoded(
    source: PathOrFile, codec: Codec | None = None
) -> Iterator[tuple[int, int, Any, Any]]:
    """``(log_time_ns, sim_time_ns, node, payload)`` of every frame of ``/can/raw`` that the
    codec decodes, in bus order; ``sim_time_ns`` is the latest Bench_Step's (0 before the
    first).  Frames it cannot decode are passed over."""
    codec = codec or Codec.default()
    t = 0
    for lt, msg in iter_frames(source):
        try:
            node, p = codec.decode(msg)
        except DecodeError:
            continue
        if type(p) is BenchStep:
            t = p.sim_time_ns
        yield lt, t, node, p


class MCAPReader(BinaryIOMessageReader):
    """python-can reader of the frames on ``/can/raw`` of a recorder MCAP, in bus order.

    ``timestamps``: ``"dated"`` (default: the log time, and in a lock-step recording, whose log
    times are simulation time from 0, the simulation time from the wall-clock time at which
    its first frame was received: the chair's timing, on the day it ran, so ``can_player``
    replays with the chair's timing and ``can_logconvert`` writes a real date), ``"log"``
    (the log time as it is) or ``"receive"`` (wall clock of the recording machine).
    """

    def __init__(self, file: Any, timestamps: str = "dated", **kwargs: Any) -> None:
        if timestamps not in ("dated", "log", "receive"):
            raise ValueError(f"timestamps={timestamps!r}: choose 'dated', 'log' or 'receive'")
        super().__init__(file, mode="rb")
        self.timestamps = timestamps

    def __iter__(self) -> Generator[can.Message, None, None]:
        source = cast(IO[bytes], self.file)
        if self.timestamps != "dated":
            for _t, msg in iter_frames(source, timestamps=self.timestamps):
                yield msg
            self.stop()
            return
        offset_s: float | None = None
        for log_ns, msg in iter_frames(source, timestamps="receive"):
            if offset_s is None:  # the first frame: its receive time dates the recording
                dated = log_ns < SIMULATION_TIME_BEFORE_NS and msg.timestamp > 0
                offset_s = msg.timestamp - log_ns / 1e9 if dated else 0.0
            msg.timestamp = log_ns / 1e9 + offset_s
            yield msg
        self.stop()


class MCAPWriter(BinaryIOMessageWriter):
    """python-can writer of the recorder's layout (``can_logger -f x.mcap``).

    Options (``can_logger ... --lockstep=True``): ``lockstep`` stamps frames with the
    bench's simulation time like the recorder; ``dbc`` decodes with another DBC;
    ``chunk_size`` / ``flush_interval_s`` tune crash safety.  MCAP files cannot be
    appended to.
    """

    def __init__(
        self,
        file: Any,
        append: bool = False,
        lockstep: bool = False,
        dbc: str | None = None,
        chunk_size: int | None = None,
        flush_interval_s: float | None = None,
        **kwargs: Any,
    ) -> None:
        if append:
            raise ValueError("MCAP logs cannot be appended to; write a new file")
        super().__init__(file, mode="wb")

        opts: dict[str, Any] = {}
        if chunk_size is not None:
            opts["chunk_size"] = int(chunk_size)
        if flush_interval_s is not None:
            opts["flush_interval_s"] = float(flush_interval_s)
        self._w = LogWriter(
            cast(IO[bytes], self.file), library="wheelchair-hil python-can writer", **opts
        )
        codec = Codec(dbc) if dbc else Codec.default()
        self._w.add_attachment(Path(dbc).name if dbc else DBC_PATH.name, codec.path.read_bytes())
        self._w.add_metadata("versions", versions())
        self._log = FrameLog(self._w, lockstep=bool(lockstep), codec=codec, stamped=True)
        self._stopped = False

    def on_message_received(self, msg: can.Message) -> None:
        self._log.record(msg)

    def file_size(self) -> int:
        return self.file.tell()

    def stop(self) -> None:
        if self._stopped:
            return
        self._stopped = True
        self._log.close()
        super().stop()


# -------------------------------------------------------------------------- merging


class _Source:
    """One input of :func:`merge_into`: its records, with ids remapped into the writer."""

    def __init__(self, path: Path, w: LogWriter, contents: LogContents) -> None:
        self.it = iter_records(path)
        self.w = w
        self.contents = contents
        self.schemas: dict[int, int] = {0: 0}
        self.channels: dict[int, int] = {}

    def next_message(self) -> Message | None:
        for rec in self.it:
            if isinstance(rec, Message):
                cid = self.channels.get(rec.channel_id)
                if cid is not None:
                    rec.channel_id = cid
                    return rec
            elif isinstance(rec, Schema):
                if rec.id not in self.schemas:  # the summary section repeats them
                    self.schemas[rec.id] = self.w.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel):
                if rec.id in self.channels:
                    continue
                self.channels[rec.id] = self.w.register_channel(
                    rec.topic,
                    rec.message_encoding,
                    self.schemas.get(rec.schema_id, 0),
                    rec.metadata,
                )
            elif isinstance(rec, Attachment):
                self.contents.attachments[rec.name] = bytes(rec.data)
            elif isinstance(rec, Metadata):
                self.contents.metadata.setdefault(rec.name, {}).update(rec.metadata)
        return None


def merge_into(
    main: str | Path,
    extras: Sequence[str | Path],
    *,
    metadata: Mapping[str, Mapping[str, str]] | None = None,
    attachments: Mapping[str, bytes] | None = None,
    on_message: Callable[[Channel, Message], None] | None = None,
    contents: LogContents | None = None,
) -> int:
    """Rewrite ``main`` with the messages of ``extras`` interleaved by log time.

    The messages of ``main`` keep their file order (bus order); each extra log's
    messages are inserted before the first message of ``main`` with a later log
    time.  Attachments and metadata of all inputs are kept (records of the same
    name merged, later keys win), then ``metadata`` and ``attachments`` are added.
    The new file replaces ``main`` only once it is complete.  Returns the number of
    messages written.

    ``on_message(channel, message)`` sees every message as it is written (the merged
    log read in the same pass, e.g. by a :class:`tools.metrics.tracking.BusCollector`), and
    ``contents``, if given, receives the merged log's channels, attachments and metadata.
    """
    main = Path(main)
    tmp = main.with_name(main.name + ".tmp")
    contents = LogContents() if contents is None else contents
    w = LogWriter(tmp, library="wheelchair-hil merge", chunk_size=256 * 1024, flush_interval_s=0.0)
    n = 0
    try:
        src = _Source(main, w, contents)
        others = [_Source(Path(p), w, contents) for p in extras]
        heads = [o.next_message() for o in others]
        add = w.add_message
        channels = w.channels

        def emit(m: Message) -> None:
            add(m.channel_id, m.log_time, m.publish_time, m.data, m.sequence)
            if on_message is not None:
                on_message(channels[m.channel_id], m)

        while (m := src.next_message()) is not None:
            for i, o in enumerate(others):
                h = heads[i]
                while h is not None and h.log_time < m.log_time:
                    emit(h)
                    n += 1
                    h = o.next_message()
                heads[i] = h
            emit(m)
            n += 1
        for i, o in enumerate(others):
            h = heads[i]
            while h is not None:
                emit(h)
                n += 1
                h = o.next_message()
        for name, data in {**contents.attachments, **(attachments or {})}.items():
            w.add_attachment(name, data)
        merged = {k: dict(v) for k, v in contents.metadata.items()}
        for name, md in (metadata or {}).items():
            merged.setdefault(name, {}).update(md)
        for name, md in merged.items():
            w.add_metadata(name, md)
        w.close()
        contents.attachments = {**contents.attachments, **(attachments or {})}
        contents.metadata = merged
        contents.channels = dict(w.channels)
        contents.message_count = n
        contents.complete = True
    except BaseException:
        w.close()
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, main)
    return n
