"""Record every frame on the bus to MCAP: raw, and decoded per DBC message.

Channels:

* ``/can/raw``: every frame as received, a JSON mirror of python-can's ``Message``
  (payload base64), including frames the codec rejects;
* ``/can/<DBC message name>``: the decoded signals (numbers; choice signals get a
  ``<signal>_label`` string too), schema descriptions carry the units.

``log_time`` is integer nanoseconds.  In lock-step runs it is simulation time:
frames after ``Bench_Step(t)`` up to the host's ``Bench_Step_Ack(t)`` belong to
the host's tick at ``t``; frames after the ack belong to the bench's next step
``t + T``, except the ground truth (``Bench_Truth_*``), which the bench sends right
after the ack and which describes time ``t``.  In real-time runs it is the receive time.  ``publish_time`` is always
the wall-clock receive time.  Small chunks keep a killed recorder's file readable
up to its last chunk.
"""

from __future__ import annotations

import base64
import json
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
from mcap.writer import CompressionType, Writer

from dbc.codec import BenchEnd, BenchStep, BenchStepAck, Codec, TruthPose, TruthTwist, TruthWheels
from dbc.errors import DecodeError
from tools.busload import frame_bits

log = logging.getLogger(__name__)

RAW_SCHEMA = {
    "title": "can.Message",
    "description": "A CAN frame as python-can's Message; data is base64",
    "type": "object",
    "properties": {
        "timestamp": {"type": "number", "description": "receive time, s since the epoch"},
        "arbitration_id": {"type": "integer"},
        "is_extended_id": {"type": "boolean"},
        "is_remote_frame": {"type": "boolean"},
        "is_error_frame": {"type": "boolean"},
        "is_fd": {"type": "boolean"},
        "dlc": {"type": "integer"},
        "data": {"type": "string", "contentEncoding": "base64"},
        "channel": {"type": ["string", "null"]},
    },
}


_RAW_FMT = (
    '{"timestamp":%r,"arbitration_id":%d,"is_extended_id":%s,"is_remote_frame":%s,'
    '"is_error_frame":%s,"is_fd":%s,"dlc":%d,"data":"%s","channel":%s}'
)
_JSON_BOOL = {False: "false", True: "true"}


@dataclass
class RecorderStats:
    frames: int = 0
    decoded: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    by_name: Counter[str] = field(default_factory=Counter)
    bits: int = 0
    first_ns: int | None = None
    last_ns: int = 0
    ended_by: str = ""

    def bus_load_pct(self, bitrate: int) -> float:
        if self.first_ns is None or self.last_ns <= self.first_ns:
            return 0.0
        return 100.0 * self.bits / ((self.last_ns - self.first_ns) * 1e-9 * bitrate)


class BusRecorder:
    """Writes frames from ``bus`` into ``path`` until Bench_End, ``stop_event`` or ``duration_s``."""

    def __init__(
        self,
        bus: can.BusABC,
        path: str | Path,
        *,
        lockstep: bool,
        codec: Codec | None = None,
        chunk_size: int = 64 * 1024,
        stop_event: threading.Event | None = None,
        attachments: dict[str, bytes] | None = None,
        metadata: dict[str, dict[str, str]] | None = None,
    ) -> None:
        self.bus = bus
        self.path = Path(path)
        self.lockstep = lockstep
        self.codec = codec or Codec.default()
        self.stop_event = stop_event or threading.Event()
        self.stats = RecorderStats()
        self._fh = self.path.open("wb")
        self._w = Writer(self._fh, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._w.start(profile="", library="wheelchair-hil recorder")
        raw_schema = self._w.register_schema(
            "can.Message", "jsonschema", json.dumps(RAW_SCHEMA).encode()
        )
        self._raw = self._w.register_channel("/can/raw", "json", raw_schema)
        self._channels: dict[str, tuple[int, tuple[tuple[str, dict[int, str]], ...]]] = {}
        now = time.time_ns()
        for name, data in (attachments or {}).items():
            self._w.add_attachment(now, now, name, "text/plain", data)
        for name, md in (metadata or {}).items():
            self._w.add_metadata(name, md)
        self._step_id = self.codec.frame_id(BenchStep)
        self._ack_id = self.codec.frame_id(BenchStepAck)
        self._end_id = self.codec.frame_id(BenchEnd)
        self._period_ns = int((self.codec.cycle_time_ms(BenchStep) or 10) * 1_000_000)
        self._truth_ids = frozenset(
            self.codec.frame_id(c) for c in (TruthPose, TruthTwist, TruthWheels)
        )
        self._sim_ns = 0
        self._step_ns = 0
        self._seq = 0
        self._closed = False

    def _decoded_channel(self, name: str) -> tuple[int, tuple[tuple[str, dict[int, str]], ...]]:
        entry = self._channels.get(name)
        if entry is None:
            sigs = self.codec.describe_signals(name)
            props: dict[str, Any] = {}
            for s in sigs:
                unit = f" [{s['unit']}]" if s["unit"] else ""
                props[s["name"]] = {
                    "type": "number",
                    "description": f"{s['comment']}{unit} range {s['minimum']}..{s['maximum']}".strip(),
                }
                if s["choices"]:
                    props[s["name"] + "_label"] = {
                        "type": "string",
                        "enum": sorted(set(s["choices"].values())),
                    }
            schema = {"title": name, "type": "object", "properties": props}
            sid = self._w.register_schema(name, "jsonschema", json.dumps(schema).encode())
            cid = self._w.register_channel(f"/can/{name}", "json", sid)
            choices = tuple((s["name"], s["choices"]) for s in sigs if s["choices"])
            entry = (cid, choices)
            self._channels[name] = entry
        return entry

    def record(self, msg: can.Message) -> None:
        """Write one frame (raw and, when valid, decoded)."""
        st = self.stats
        wall_ns = int(msg.timestamp * 1e9) if msg.timestamp else time.time_ns()
        aid = msg.arbitration_id
        if self.lockstep:
            if msg.is_extended_id and aid == self._step_id:
                self._sim_ns = self._step_ns = self._sim_time(msg, self._sim_ns)
            log_ns = (
                self._step_ns if (msg.is_extended_id and aid in self._truth_ids) else self._sim_ns
            )
        else:
            log_ns = wall_ns
        st.frames += 1
        st.bits += frame_bits(len(msg.data), msg.is_extended_id)
        if st.first_ns is None:
            st.first_ns = log_ns
        st.last_ns = log_ns
        self._seq += 1
        # The python-can Message mirror, formatted directly (json.dumps is 3x slower here).
        raw = _RAW_FMT % (
            msg.timestamp,
            aid,
            _JSON_BOOL[msg.is_extended_id],
            _JSON_BOOL[msg.is_remote_frame],
            _JSON_BOOL[msg.is_error_frame],
            _JSON_BOOL[msg.is_fd],
            msg.dlc,
            base64.b64encode(bytes(msg.data)).decode("ascii"),
            "null" if msg.channel is None else json.dumps(str(msg.channel)),
        )
        self._w.add_message(
            self._raw, log_time=log_ns, publish_time=wall_ns, sequence=self._seq, data=raw.encode()
        )
        try:
            name, signals = self.codec.decode_signals(msg)
            values: dict[str, Any] | None = dict(signals)
        except DecodeError as err:
            st.rejected[err.reason] += 1
            values = None
        if values is not None:
            cid, choices = self._decoded_channel(name)
            for sig, table in choices:
                values[sig + "_label"] = table.get(int(values[sig]), str(values[sig]))
            self._w.add_message(
                cid,
                log_time=log_ns,
                publish_time=wall_ns,
                sequence=self._seq,
                data=json.dumps(values, separators=(",", ":")).encode(),
            )
            st.decoded += 1
            st.by_name[name] += 1
        if self.lockstep and msg.is_extended_id and aid == self._ack_id:
            # frames after the host's ack are the bench's next step
            self._sim_ns = self._sim_time(msg, self._sim_ns - self._period_ns) + self._period_ns

    def _sim_time(self, msg: can.Message, default: int) -> int:
        try:
            return int(self.codec.decode(msg).payload.sim_time_ns)
        except DecodeError:
            return default

    def run(
        self,
        *,
        duration_s: float | None = None,
        on_ready: Callable[[], None] | None = None,
        drain_s: float = 0.3,
    ) -> RecorderStats:
        """Record until Bench_End (then ``drain_s`` more), the stop event, or ``duration_s`` (wall)."""
        if on_ready:
            on_ready()
        t_end = None if duration_s is None else time.monotonic() + duration_s
        drain_until: float | None = None
        try:
            while True:
                if self.stop_event.is_set():
                    self.stats.ended_by = self.stats.ended_by or "stopped"
                    break
                now = time.monotonic()
                if t_end is not None and now >= t_end:
                    self.stats.ended_by = "duration"
                    break
                if drain_until is not None and now >= drain_until:
                    break
                msg = self.bus.recv(0.1)
                if msg is None:
                    continue
                self.record(msg)
                if (
                    msg.is_extended_id
                    and msg.arbitration_id == self._end_id
                    and drain_until is None
                ):
                    self.stats.ended_by = "Bench_End"
                    drain_until = time.monotonic() + drain_s
        finally:
            self.close()
        return self.stats

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        st = self.stats
        self._w.add_metadata(
            "recorder",
            {
                "frames": str(st.frames),
                "decoded": str(st.decoded),
                "rejected": json.dumps(dict(st.rejected)),
                "ended_by": st.ended_by,
                "lockstep": str(self.lockstep),
            },
        )
        self._w.finish()
        self._fh.close()
