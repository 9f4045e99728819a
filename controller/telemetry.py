"""The controller's own log: its internals per tick, written to MCAP as JSON.

The bus recorder sees every frame; only the controller knows its estimate, its
reference, its errors and the internals of the tracking law.  :class:`McapTelemetry`
writes them with integer-nanosecond ``log_time`` in small chunks (a killed
process loses at most the last chunk).  :class:`NullTelemetry` is used when no
log is wanted (benchmarks).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, BinaryIO, Protocol

from mcap.writer import CompressionType, Writer


class Telemetry(Protocol):
    def log(self, topic: str, t_ns: int, record: Mapping[str, Any]) -> None: ...

    def metadata(self, name: str, data: Mapping[str, str]) -> None: ...

    def close(self) -> None: ...


class NullTelemetry:
    def log(self, topic: str, t_ns: int, record: Mapping[str, Any]) -> None:
        pass

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        pass

    def close(self) -> None:
        pass


def _schema_for(record: Mapping[str, Any]) -> dict[str, Any]:
    props: dict[str, Any] = {}
    for k, v in record.items():
        if isinstance(v, bool):
            props[k] = {"type": "boolean"}
        elif isinstance(v, int | float):
            props[k] = {"type": "number"}
        elif isinstance(v, str):
            props[k] = {"type": "string"}
        elif isinstance(v, Mapping):
            props[k] = _schema_for(v)
        else:
            props[k] = {}
    return {"type": "object", "properties": props}


class McapTelemetry:
    """JSON channels in an MCAP file, one schema per topic derived from its first record."""

    def __init__(self, path: str | Path, *, chunk_size: int = 64 * 1024, profile: str = "") -> None:
        self.path = Path(path)
        self._fh: BinaryIO = self.path.open("wb")
        self._w = Writer(self._fh, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._w.start(profile=profile, library="wheelchair-hil")
        self._channels: dict[str, int] = {}
        self._seq = 0
        self._closed = False

    def log(self, topic: str, t_ns: int, record: Mapping[str, Any]) -> None:
        ch = self._channels.get(topic)
        if ch is None:
            schema = self._w.register_schema(
                topic.strip("/").replace("/", "."),
                "jsonschema",
                json.dumps(_schema_for(record)).encode(),
            )
            ch = self._w.register_channel(topic, "json", schema)
            self._channels[topic] = ch
        self._seq += 1
        self._w.add_message(
            ch,
            log_time=t_ns,
            publish_time=t_ns,
            sequence=self._seq,
            data=json.dumps(record, separators=(",", ":")).encode(),
        )

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        self._w.add_metadata(name, {k: str(v) for k, v in data.items()})

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._w.finish()
        self._fh.close()
