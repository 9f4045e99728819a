"""A chunked MCAP writer for logs that must survive a killed process.

:class:`LogWriter` writes standard MCAP (readable by the ``mcap`` package, Foxglove
and the ``mcap`` CLI) with three properties the recorder needs:

* **small chunks, closed often**: a chunk is written out when it holds
  ``chunk_size`` bytes or when its first message is ``flush_interval_s`` (wall clock)
  old, and the file is flushed to the operating system after every chunk.  The age is
  checked at a chunk's first message, at every :data:`_CLOCK_EVERY`-th message after it and at
  :meth:`LogWriter.poll` (a writer's caller polls when idle): not at every message, as a
  clock read is a system call where there is no vDSO (a user-mode Linux guest: 90 us).  A
  process killed with SIGKILL loses at most the chunk in progress; everything
  before it is on disk (mcap's own writer keeps 1 MiB chunks in memory by default,
  so a killed recorder used to leave nothing readable);
* **CRCs** on every chunk (uncompressed data), on the data section (``DataEnd``)
  and on the summary, so a reader can tell where a damaged file stops being intact;
* **speed**: a message costs one header ``struct.pack`` and two list appends;
  mcap's ``Writer.add_message`` builds each record field by field (about 4.5 µs
  per message, the recorder writes two to three per frame).

Schema and channel records are written outside chunks, at registration, so a
streaming reader meets them before the first message that uses them.  The summary
section (schemas, channels, statistics, chunk, attachment and metadata indexes)
is written by :meth:`LogWriter.close`, exactly as mcap's writer does.

A :class:`Mirror` given to the writer sees every schema, channel and message as it is
written (the live view, ``tools/live``, serves a run's channels this way, with the
same names, schemas and bytes as the file).  The writer calls it on its own thread; a
mirror must return at once and never raise.
"""

from __future__ import annotations

import struct
import time
import zlib
from collections.abc import Iterator, Mapping
from io import BytesIO
from pathlib import Path
from typing import IO, Any, Protocol

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Message,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MAGIC = bytes((137, 77, 67, 65, 80, 48, 13, 10))
#: Message record header: opcode, record length, channel, sequence, log time, publish time.
_MSG = struct.Struct("<BQHIQQ")
_MSG_FIXED = 22  # record length without the payload
_OP_MESSAGE = int(Opcode.MESSAGE)
#: Message index record header: opcode, record length, channel, length of the entries.
_MSG_INDEX = struct.Struct("<BQHI")
DEFAULT_CHUNK_SIZE = 32 * 1024
#: Messages between two checks of a chunk's age (module doc).
_CLOCK_EVERY = 16
DEFAULT_FLUSH_INTERVAL_S = 0.05


def _compressor(compression: str) -> Any:
    if compression == "zstd":
        import zstandard  # lazy: the compressor asked for

        return zstandard.ZstdCompressor(level=1).compress
    if compression == "lz4":
        import lz4.frame  # lazy: the compressor asked for

        return lz4.frame.compress
    if compression == "":
        return None
    raise ValueError(f"MCAP compression {compression!r}: choose 'zstd', 'lz4' or ''")


class Mirror(Protocol):
    """Sees what a :class:`LogWriter` writes, as it writes it (ids are the file's)."""

    def schema(self, schema_id: int, name: str, encoding: str, data: bytes) -> None:
        """See a schema as it is registered."""

    def channel(self, channel_id: int, topic: str, message_encoding: str, schema_id: int) -> None:
        """See a channel as it is registered."""

    def message(self, channel_id: int, log_time: int, data: bytes) -> None:
        """See a message as it is written (``log_time`` in ns)."""

    def close(self) -> None:
        """The writer is closing: nothing more follows."""


class LogWriter:
    """Write an MCAP file chunk by chunk (see the module doc).

    ``output`` is a path or a binary stream (not closed by :meth:`close` if given as
    a stream).  ``flush_interval_s = 0`` closes chunks by size only.  ``mirror`` sees
    every schema, channel and message too (closed with the writer).
    """

    def __init__(
        self,
        output: str | Path | IO[bytes],
        *,
        profile: str = "",
        library: str = "wheelchair-hil",
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        compression: str = "zstd",
        mirror: Mirror | None = None,
    ) -> None:
        self.mirror = mirror
        if isinstance(output, str | Path):
            self._fh: IO[bytes] = Path(output).open("wb")  # noqa: SIM115 (closed by close())
            self._owns = True
        else:
            self._fh = output
            self._owns = False
        self.chunk_size = int(chunk_size)
        self.flush_interval_s = float(flush_interval_s)
        self.compression = compression
        self._compress = _compressor(compression)
        self._pos = 0
        self._crc = 0
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        # the summary's chunk indexes, serialized as they are made: a long log keeps one per
        # chunk until it closes (20 chunks/s in a real-time recording), ~90 bytes each this
        # way instead of ~600 as ChunkIndex objects
        self._chunk_indexes = bytearray()
        self._chunk_count = 0
        self._attachment_indexes: list[AttachmentIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = {}
        self._messages = 0
        self._t_min: int | None = None
        self._t_max = 0
        # the chunk in progress
        self._buf: list[bytes] = []
        self._size = 0
        self._index: dict[int, list[int]] = {}  # channel -> [log_time, offset, ...]
        self._c_min = 0
        self._c_max = 0
        self._deadline = 0.0
        self._since_clock = 0  # messages added since the flush deadline was last checked
        self._closed = False
        self._write(MAGIC)
        self._record(Header(profile=profile, library=library))

    # ------------------------------------------------------------------ records

    def _write(self, data: bytes) -> None:
        self._fh.write(data)
        self._crc = zlib.crc32(data, self._crc)
        self._pos += len(data)

    def _record(self, record: Any) -> int:
        rb = RecordBuilder()
        record.write(rb)
        data = rb.end()
        start = self._pos
        self._write(data)
        return start

    @property
    def channels(self) -> Mapping[int, Channel]:
        """The channels registered so far, by id."""
        return self._channels

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Write a schema record; returns its ID (from 1)."""
        sid = len(self._schemas) + 1
        schema = Schema(id=sid, data=data, encoding=encoding, name=name)
        self._schemas[sid] = schema
        self._record(schema)
        if self.mirror is not None:
            self.mirror.schema(sid, name, encoding, data)
        return sid

    def register_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: Mapping[str, str] | None = None,
    ) -> int:
        """Write a channel record on ``schema_id``; returns its ID (from 1)."""
        cid = len(self._channels) + 1
        channel = Channel(
            id=cid,
            topic=topic,
            message_encoding=message_encoding,
            schema_id=schema_id,
            metadata=dict(metadata or {}),
        )
        self._channels[cid] = channel
        self._counts[cid] = 0
        self._record(channel)
        if self.mirror is not None:
            self.mirror.channel(cid, topic, message_encoding, schema_id)
        return cid

    def add_message(
        self, channel_id: int, log_time: int, publish_time: int, data: bytes, sequence: int = 0
    ) -> None:
        """Add one message to the chunk in progress (the hot path)."""
        if self.mirror is not None:
            self.mirror.message(channel_id, log_time, data)
        buf, size = self._buf, self._size
        if not buf:
            self._c_min = self._c_max = log_time
            self._deadline = time.monotonic() + self.flush_interval_s
            self._since_clock = _CLOCK_EVERY - 1  # its first message reads the clock
        elif log_time < self._c_min:
            self._c_min = log_time
        elif log_time > self._c_max:
            self._c_max = log_time
        idx = self._index.get(channel_id)
        if idx is None:
            self._index[channel_id] = [log_time, size]
        else:
            idx += (log_time, size)
        n = len(data)
        buf += (
            _MSG.pack(
                _OP_MESSAGE,
                _MSG_FIXED + n,
                channel_id,
                sequence & 0xFFFFFFFF,
                log_time,
                publish_time,
            ),
            data,
        )
        self._size = size = size + 31 + n
        if size >= self.chunk_size:
            self.flush()
        elif self.flush_interval_s > 0:
            k = self._since_clock + 1
            if k >= _CLOCK_EVERY:
                k = 0
                if time.monotonic() >= self._deadline:
                    self.flush()
            self._since_clock = k

    def poll(self) -> None:
        """Close the chunk in progress if it is older than ``flush_interval_s`` (call when idle)."""
        if self._buf and time.monotonic() >= self._deadline:
            self.flush()

    def flush(self) -> None:
        """Write the chunk in progress (if any) and flush the file to the operating system."""
        if self._buf:
            self._finish_chunk()
        self._fh.flush()

    def _finish_chunk(self) -> None:
        data = b"".join(self._buf)
        compressed = self._compress(data) if self._compress is not None else data
        chunk = Chunk(
            compression=self.compression,
            data=compressed,
            message_start_time=self._c_min,
            message_end_time=self._c_max,
            uncompressed_crc=zlib.crc32(data),
            uncompressed_size=len(data),
        )
        start = self._record(chunk)
        chunk_length = self._pos - start
        index_start = self._pos
        offsets: dict[int, int] = {}
        parts: list[bytes] = []
        pos = index_start
        for cid, flat in self._index.items():
            offsets[cid] = pos
            n = len(flat)  # two numbers per message
            parts.append(_MSG_INDEX.pack(Opcode.MESSAGE_INDEX, 6 + 8 * n, cid, 8 * n))
            parts.append(struct.pack(f"<{n}Q", *flat))
            pos += 15 + 8 * n
            self._counts[cid] += n // 2
            self._messages += n // 2
        self._write(b"".join(parts))
        rb = RecordBuilder()
        ChunkIndex(
            message_start_time=self._c_min,
            message_end_time=self._c_max,
            chunk_start_offset=start,
            chunk_length=chunk_length,
            message_index_offsets=offsets,
            message_index_length=self._pos - index_start,
            compression=self.compression,
            compressed_size=len(compressed),
            uncompressed_size=len(data),
        ).write(rb)
        self._chunk_indexes += rb.end()
        self._chunk_count += 1
        self._t_min = self._c_min if self._t_min is None else min(self._t_min, self._c_min)
        self._t_max = max(self._t_max, self._c_max)
        self._buf = []
        self._index = {}
        self._size = 0

    def add_attachment(
        self,
        name: str,
        data: bytes,
        media_type: str = "text/plain",
        *,
        log_time: int = 0,
        create_time: int = 0,
    ) -> None:
        """Write an attachment after the chunk in progress, indexed in the summary (times in ns)."""
        self.flush()
        att = Attachment(
            create_time=create_time,
            log_time=log_time,
            name=name,
            media_type=media_type,
            data=data,
        )
        start = self._record(att)
        self._attachment_indexes.append(
            AttachmentIndex(
                offset=start,
                length=self._pos - start,
                log_time=log_time,
                create_time=create_time,
                data_size=len(data),
                name=name,
                media_type=media_type,
            )
        )

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write a metadata record (values as strings), indexed in the summary."""
        self.flush()
        start = self._record(Metadata(name=name, metadata={k: str(v) for k, v in data.items()}))
        self._metadata_indexes.append(
            MetadataIndex(offset=start, length=self._pos - start, name=name)
        )
        self._fh.flush()

    @property
    def message_count(self) -> int:
        """Messages written so far (including the chunk in progress)."""
        return self._messages + sum(len(v) for v in self._index.values()) // 2

    # ------------------------------------------------------------------- finish

    def close(self) -> None:
        """Write the last chunk, the summary and the footer (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self.mirror is not None:
            self.mirror.close()
        if self._buf:
            self._finish_chunk()
        self._record(DataEnd(data_section_crc=self._crc))
        summary_start = self._pos
        rb = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: int, records: list[Any]) -> None:
            if not records:
                return
            begin = rb.count
            for r in records:
                r.write(rb)
            offsets.append(SummaryOffset(opcode, summary_start + begin, rb.count - begin))

        group(Opcode.SCHEMA, list(self._schemas.values()))
        group(Opcode.CHANNEL, list(self._channels.values()))
        group(
            Opcode.STATISTICS,
            [
                Statistics(
                    attachment_count=len(self._attachment_indexes),
                    channel_count=len(self._channels),
                    channel_message_counts={k: v for k, v in self._counts.items() if v},
                    chunk_count=self._chunk_count,
                    message_count=self._messages,
                    metadata_count=len(self._metadata_indexes),
                    message_start_time=self._t_min or 0,
                    message_end_time=self._t_max,
                    schema_count=len(self._schemas),
                )
            ],
        )
        if self._chunk_indexes:  # serialized as each chunk was written
            begin = rb.count
            rb.write(self._chunk_indexes)
            offsets.append(
                SummaryOffset(Opcode.CHUNK_INDEX, summary_start + begin, rb.count - begin)
            )
        group(Opcode.ATTACHMENT_INDEX, list(self._attachment_indexes))
        group(Opcode.METADATA_INDEX, list(self._metadata_indexes))
        offset_start = summary_start + rb.count
        for o in offsets:
            o.write(rb)
        summary = rb.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offset_start), crc)
        self._write(summary)
        self._record(
            Footer(summary_start=summary_start, summary_offset_start=offset_start, summary_crc=crc)
        )
        self._write(MAGIC)
        self._fh.flush()
        if self._owns:
            self._fh.close()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------- reading

_RECORD_HEAD = struct.Struct("<BQ")
_MESSAGE_HEAD = struct.Struct("<HIQQ")


def chunk_records(chunk: Chunk) -> Iterator[McapRecord]:
    """The channel, schema and message records of one chunk, its CRC checked.

    The reading counterpart of :class:`LogWriter`'s chunks: messages are parsed with
    ``struct`` in one pass over the decompressed bytes (the mcap library's per-field
    reads made this most of the time spent reading a log).  Raises ``ValueError`` on a
    CRC mismatch or a record that overruns the chunk.
    """
    if chunk.compression == "zstd":
        import zstandard  # lazy: the compressor asked for

        data = zstandard.decompress(chunk.data, chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        import lz4.frame  # lazy: the compressor asked for

        data = lz4.frame.decompress(chunk.data)
    elif chunk.compression == "":
        data = bytes(chunk.data)
    else:
        raise ValueError(f"unsupported chunk compression {chunk.compression!r}")
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError(
            f"crc validation failed in a chunk: expected {chunk.uncompressed_crc:#010x}, "
            f"calculated {zlib.crc32(data):#010x}"
        )
    end = len(data)
    off = 0
    record_head, message_head = _RECORD_HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
    while off < end:
        opcode, length = record_head(data, off)
        body = off + 9
        off = body + length
        if off > end:
            raise ValueError(f"a record of {length} bytes overruns its chunk")
        if opcode == _OP_MESSAGE:
            channel_id, sequence, log_time, publish_time = message_head(data, body)
            # positional: channel_id, log_time, data, publish_time, sequence
            yield Message(channel_id, log_time, data[body + 22 : off], publish_time, sequence)
        elif opcode == Opcode.CHANNEL:
            yield Channel.read(ReadDataStream(BytesIO(data[body:off])))
        elif opcode == Opcode.SCHEMA:
            yield Schema.read(ReadDataStream(BytesIO(data[body:off])))
