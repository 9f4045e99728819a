"""Record every frame on the bus to MCAP: raw, decoded per DBC message, and for Foxglove.

Channels (``docs/logs.md`` has the whole layout, the controller's channels included):

* ``/can/raw``: every frame as received, a JSON mirror of python-can's ``Message``
  (payload base64), including frames the codec rejects;
* ``/can/<DBC message name>``: the decoded signals (numbers; choice signals get a
  ``<signal>_label`` string too), schema descriptions carry the units.  RTR
  requests and rejected frames are only on ``/can/raw``;
* ``/truth/pose`` (``foxglove.PoseInFrame``) and ``/truth/tf``
  (``foxglove.FrameTransform`` world -> chair_truth) from ``Bench_Truth_Pose``;
* ``/wheels/joint_states`` (``foxglove.JointStates``): both wheels' angle and speed
  (rad, rad/s) once both drives have sent a new ``Get_Encoder_Estimates``;
* ``/events`` (``foxglove.Log``): host state changes (from ``Host_Heartbeat``), drive
  state and error changes (drive ``Heartbeat``), e-stops, bench fault frames
  (``Bench_Fault_*``, whatever their signals), the first rejected frame of each
  reason, and the end of the run.

``log_time`` is integer nanoseconds.  In lock-step runs it is simulation time:
frames after ``Bench_Step(t)`` up to the host's ``Bench_Step_Ack(t)`` belong to
the host's tick at ``t``; frames after the ack belong to the bench's next step
``t + T``, except the ground truth (``Bench_Truth_*``), which the bench sends right
after the ack and which describes time ``t``.  In real-time runs it is the receive
time.  ``publish_time`` is always the wall-clock receive time.  The sequence number
of both the raw and the decoded message is the frame's index in the recording, so
file order is bus order.

Crash safety comes from :class:`dbc.runtime.mcapwriter.LogWriter`: chunks of at most
``chunk_size`` bytes or ``flush_interval_s`` of wall time, each with a CRC, flushed
to the operating system as they close.  :class:`FrameLog` is the part that turns
frames into messages; :class:`BusRecorder` feeds it from a bus, and the python-can
log writer (``tools.logs.mcap_io.MCAPWriter``) from ``can_logger``.
"""

from __future__ import annotations

import base64
import json
import logging
import platform
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

import can

from controller.kinematics import TWO_PI
from dbc import logschema as ls
from dbc.codec import (
    DRIVES,
    AxisError,
    AxisState,
    BenchEnd,
    BenchStep,
    BenchStepAck,
    Codec,
    EncoderEstimates,
    Estop,
    Heartbeat,
    HostHeartbeat,
    HostState,
    Node,
    RecordAck,
    StopReason,
    TruthPose,
    TruthTwist,
    TruthWheels,
)
from dbc.errors import CodecError, DecodeError
from dbc.runtime import jsonsafe, stopping
from dbc.runtime.busio import recv_dropping
from dbc.runtime.mcapwriter import (
    DEFAULT_CHUNK_SIZE,
    DEFAULT_FLUSH_INTERVAL_S,
    LogWriter,
    Mirror,
)
from tools.bus.busload import frame_bits

log = logging.getLogger(__name__)


TRUTH_POSE_TOPIC = "/truth/pose"
TRUTH_TF_TOPIC = "/truth/tf"
JOINT_STATES_TOPIC = "/wheels/joint_states"
EVENTS_TOPIC = "/events"
#: Frames taken from a busy bus between two reads of the clock (the run loop's comment).
_CLOCK_EVERY = 32

_RAW_FMT = (
    '{"timestamp":%r,"arbitration_id":%d,"is_extended_id":%s,"is_remote_frame":%s,'
    '"is_error_frame":%s,"is_fd":%s,"dlc":%d,"data":"%s"%s}'
)
_JSON_BOOL = {False: "false", True: "true"}
_b64 = base64.b64encode


class _FlagLabels(dict[int, str]):
    """JSON labels of a bit-field signal by value, each computed once (any combination of
    bits is a valid value, so the table cannot be listed in advance)."""

    def __init__(self, bits: Mapping[int, str]) -> None:
        super().__init__()
        self._bits = dict(bits)

    def __missing__(self, value: int) -> str:
        label = self[value] = json.dumps(ls.flags_label(value, self._bits))
        return label


@dataclass
class RecorderStats:
    frames: int = 0
    decoded: int = 0
    requests: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    by_name: Counter[str] = field(default_factory=Counter)
    bits: int = 0
    first_ns: int | None = None
    last_ns: int = 0
    ended_by: str = ""
    #: Bench_Step periods missing between consecutive steps: frames lost before the
    #: recorder read them (a recorder starved of CPU overflows its socket buffer)
    missed_steps: int = 0
    #: frames the kernel dropped from the recorder's full receive queue (tools.bus.rxloss)
    rx_dropped: int = 0
    rx_buffer_bytes: int = 0

    def bus_load_pct(self, bitrate: int) -> float:
        if self.first_ns is None or self.last_ns <= self.first_ns:
            return 0.0
        return 100.0 * self.bits / ((self.last_ns - self.first_ns) * 1e-9 * bitrate)

    def as_dict(self) -> dict[str, Any]:
        """What ``recorder_stats.json`` and the ``recorder`` metadata record hold."""
        return {
            "frames": self.frames,
            "decoded": self.decoded,
            "requests": self.requests,
            "rejected": dict(self.rejected),
            "bits": self.bits,
            "ended_by": self.ended_by,
            "missed_steps": self.missed_steps,
            "rx_dropped": self.rx_dropped,
            "rx_buffer_bytes": self.rx_buffer_bytes,
            "by_name": dict(self.by_name),
        }


def versions() -> dict[str, str]:
    """Versions of Python and the packages a log depends on (the ``versions`` metadata record)."""
    out = {"python": platform.python_version()}
    for pkg in ("wheelchair-hil", "python-can", "cantools", "mcap", "numpy", "scipy", "osqp"):
        try:
            out[pkg] = importlib_metadata.version(pkg)
        except importlib_metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


class LogClock:
    """The ``log_time`` of each frame of a run, in bus order (the module doc's rule).

    Lock-step: a frame belongs to the bench's step whose ``Bench_Step`` came last, until the
    host's ``Bench_Step_Ack``, after which it belongs to the next step; the ground truth
    (``Bench_Truth_*``) to the step it describes.  Real time: the receive time.  Gaps
    between consecutive ``Bench_Step`` frames are reported to ``on_missed(missed, event_ns,
    step_ns)``: frames lost before the log saw them.  Shared by the recorder
    (:class:`FrameLog`) and the in-process collector of a run without a log
    (:class:`tools.logs.collect.FrameCollector`), so both stamp a frame alike.
    """

    def __init__(
        self,
        codec: Codec,
        lockstep: bool,
        on_missed: Callable[[int, int, int], None] | None = None,
    ) -> None:
        self.codec = codec
        self.lockstep = lockstep
        self.on_missed = on_missed
        self.step_id = codec.frame_id(BenchStep)
        self.ack_id = codec.frame_id(BenchStepAck)
        self.period_ns = int((codec.cycle_time_ms(BenchStep) or 10) * 1_000_000)
        self.truth_ids = frozenset(codec.frame_id(k) for k in (TruthPose, TruthTwist, TruthWheels))
        #: the extended IDs whose frames :meth:`stamp` or :meth:`acked` read: any other frame's
        #: log time is :attr:`sim_ns` in lock-step (its receive time in real time), and
        #: :meth:`acked` of it returns False, so a caller with many frames may skip both
        #: calls for it (:class:`tools.logs.collect.FrameCollector`)
        self.clock_ids = self.truth_ids | {self.step_id, self.ack_id}
        self.sim_ns = 0
        self.step_ns = 0
        self.last_step_ns: int | None = None

    def stamp(self, msg: can.Message, wall_ns: int) -> int:
        """The log time of ``msg`` (received at ``wall_ns``); call before :meth:`acked`."""
        aid = msg.arbitration_id
        ext = msg.is_extended_id
        if ext and aid == self.step_id:
            self._bench_step(msg, wall_ns)
        if self.lockstep:
            return self.step_ns if (ext and aid in self.truth_ids) else self.sim_ns
        return wall_ns

    def acked(self, msg: can.Message) -> bool:
        """After ``msg`` is logged: True if it was the host's ack of a lock-step step (the
        frames after it are the bench's next step)."""
        if not (self.lockstep and msg.arbitration_id == self.ack_id and msg.is_extended_id):
            return False
        self.sim_ns = self._sim_time(msg, self.sim_ns - self.period_ns) + self.period_ns
        return True

    def _bench_step(self, msg: can.Message, wall_ns: int) -> None:
        """Track the bench's clock: lock-step stamping, and steps that never arrived."""
        t = self._sim_time(msg, -1)
        if t < 0:
            return
        last = self.last_step_ns
        if last is not None and t > last + self.period_ns and self.on_missed is not None:
            missed = (t - last) // self.period_ns - 1
            self.on_missed(missed, self.sim_ns if self.lockstep else wall_ns, t)
        if last is None or t > last:
            self.last_step_ns = t
        if self.lockstep:
            self.sim_ns = self.step_ns = t

    def _sim_time(self, msg: can.Message, default: int) -> int:
        try:
            return int(self.codec.decode(msg).payload.sim_time_ns)
        except DecodeError:
            return default


class FrameLog:
    """Turns frames into the log's channels in a :class:`LogWriter` (see the module doc)."""

    def __init__(
        self,
        writer: LogWriter,
        *,
        lockstep: bool,
        codec: Codec | None = None,
        stamped: bool = False,
    ) -> None:
        self.w = writer
        self.lockstep = lockstep
        #: frames carry their receive time even when it is 0.0 (a log being converted);
        #: otherwise a frame without a timestamp is stamped with the wall clock
        self.stamped = stamped
        self.codec = codec or Codec.default()
        # the wire contract the frames were decoded with (host and drives confirm the same
        # hash before arming, docs/safety.md)
        writer.add_metadata(
            "contract",
            {"dbc_hash": f"{self.codec.contract_hash:08x}", "dbc": str(self.codec.path)},
        )
        self.stats = RecorderStats()
        self.clock = LogClock(self.codec, lockstep, on_missed=self._missed)
        w = writer
        raw_schema = w.register_schema(
            "can.Message", "jsonschema", json.dumps(ls.RAW_SCHEMA).encode()
        )
        self._raw = w.register_channel(ls.RAW_TOPIC, "json", raw_schema)
        self._fox: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str, tuple[str, ...], tuple[Any, ...]]] = {}
        c = self.codec
        self._end_id = c.frame_id(BenchEnd)
        # derived channels by DBC message name
        self._derive: dict[str, Callable[[int, str, Mapping[str, Any], can.Message], None]] = {
            c.message_name(TruthPose): self._truth_pose,
            c.message_name(HostHeartbeat, Node.HOST): self._host_heartbeat,
        }
        self._wheel_of: dict[str, int] = {}
        for i, n in enumerate(DRIVES):
            self._derive[c.message_name(EncoderEstimates, n)] = self._encoder
            self._wheel_of[c.message_name(EncoderEstimates, n)] = i
            self._derive[c.message_name(Heartbeat, n)] = self._drive_heartbeat
            self._derive[c.message_name(Estop, n)] = self._estop
        for m in c.db.messages:
            if m.name.startswith(ls.FAULT_MESSAGE_PREFIX):
                self._derive[m.name] = self._fault
        self._wheels: list[tuple[float, float] | None] = [None, None]
        self._host: tuple[int, int] | None = None
        self._drive: dict[Node | None, tuple[int, int]] = {}
        self._seq = 0
        self._chan_json: dict[Any, str] = {}

    # --------------------------------------------------------------- channels

    def _foxglove(self, topic: str, schema: str) -> int:
        cid = self._fox.get(topic)
        if cid is None:
            sid = self._fox.get(schema)
            if sid is None:
                sid = self._fox[schema] = self.w.register_schema(
                    schema, "jsonschema", ls.foxglove_schema(schema)
                )
            cid = self._fox[topic] = self.w.register_channel(topic, "json", sid)
        return cid

    def _decoded_channel(self, name: str) -> tuple[int, str, tuple[str, ...], tuple[Any, ...]]:
        entry = self._channels.get(name)
        if entry is None:
            sigs = self.codec.describe_signals(name)
            schema = ls.decoded_schema(name, sigs)
            sid = self.w.register_schema(name, "jsonschema", json.dumps(schema).encode())
            cid = self.w.register_channel(ls.DECODED_PREFIX + name, "json", sid)
            names = tuple(s["name"] for s in sigs)
            parts = [f'"{n}":%r' for n in names]
            labels = []
            for s in sigs:
                if s["choices"]:
                    parts.append(f'"{s["name"]}_label":%s')
                    table: dict[int, str] = (
                        _FlagLabels(s["choices"])
                        if s["flags"]
                        else {k: json.dumps(v) for k, v in s["choices"].items()}
                    )
                    labels.append((s["name"], table))
            entry = (cid, "{" + ",".join(parts) + "}", names, tuple(labels))
            self._channels[name] = entry
        return entry

    def event(self, t_ns: int, level: ls.LogLevel, message: str, name: str) -> None:
        """Write one foxglove.Log on ``/events``."""
        cid = self._foxglove(EVENTS_TOPIC, "foxglove.Log")
        self.w.add_message(cid, t_ns, time.time_ns(), ls.log_message(t_ns, level, message, name))

    # ----------------------------------------------------------------- frames

    def record(self, msg: can.Message) -> None:
        """Write one frame (raw and, when valid, decoded and derived)."""
        st = self.stats
        wall_ns = int(msg.timestamp * 1e9) if (msg.timestamp or self.stamped) else time.time_ns()
        aid = msg.arbitration_id
        ext = msg.is_extended_id
        log_ns = self.clock.stamp(msg, wall_ns)
        st.frames += 1
        data = bytes(msg.data)
        st.bits += frame_bits(len(data), ext)
        if st.first_ns is None:
            st.first_ns = log_ns
        st.last_ns = log_ns
        self._seq += 1
        seq = self._seq
        w = self.w
        # The python-can Message mirror, formatted directly (json.dumps is 3x slower here).
        raw = _RAW_FMT % (
            msg.timestamp,
            aid,
            _JSON_BOOL[ext],
            _JSON_BOOL[msg.is_remote_frame],
            _JSON_BOOL[msg.is_error_frame],
            _JSON_BOOL[msg.is_fd],
            msg.dlc,
            _b64(data).decode("ascii"),
            self._channel_json(msg.channel),
        )
        w.add_message(self._raw, log_ns, wall_ns, raw.encode(), seq)
        try:
            name, values = self.codec.decode_signals(msg)
        except DecodeError as err:
            st.rejected[err.reason] += 1
            if st.rejected[err.reason] == 1:
                self.event(log_ns, ls.LogLevel.WARNING, f"rejected frame: {err}", "recorder")
        else:
            if msg.is_remote_frame:
                st.requests += 1
            else:
                cid, fmt, names, labels = self._decoded_channel(name)
                vals = [values[n] for n in names]
                for sig, table in labels:
                    vals.append(table[int(values[sig])])
                w.add_message(cid, log_ns, wall_ns, (fmt % tuple(vals)).encode(), seq)
                st.decoded += 1
                st.by_name[name] += 1
                derive = self._derive.get(name)
                if derive is not None:
                    derive(log_ns, name, values, msg)
        self.clock.acked(msg)
        if ext and aid == self._end_id:
            self.event(
                log_ns, ls.LogLevel.INFO, f"bench ended the run at {log_ns / 1e9:.3f} s", "bench"
            )

    @property
    def bench_seen(self) -> bool:
        """Whether a bench's Bench_Step has been recorded."""
        return self.clock.last_step_ns is not None

    @property
    def last_step_ns(self) -> int | None:
        """Simulation time of the latest Bench_Step recorded."""
        return self.clock.last_step_ns

    def _missed(self, missed: int, event_ns: int, step_ns: int) -> None:
        """``missed`` Bench_Step periods never arrived before the step at ``step_ns``."""
        if self.stats.missed_steps == 0:
            self.event(
                event_ns,
                ls.LogLevel.WARNING,
                f"recorder missed {missed} Bench_Step(s) before {step_ns / 1e9:.3f} s: frames were "
                "lost before the recorder read them (too slow, or the bus dropped them)",
                "recorder",
            )
        self.stats.missed_steps += missed

    def _channel_json(self, channel: Any) -> str:
        """The raw record's ``"channel"`` member, or nothing for a frame without a channel
        (the schema's ``channel`` is a string: Foxglove refuses a channel whose schema
        gives a field a list of types, such as string or null)."""
        text = self._chan_json.get(channel)
        if text is None:
            text = "" if channel is None else ',"channel":' + json.dumps(str(channel))
            if len(self._chan_json) < 64:
                self._chan_json[channel] = text
        return text

    # --------------------------------------------------------- derived channels

    def _truth_pose(self, t_ns: int, name: str, v: Mapping[str, Any], msg: can.Message) -> None:
        x, y, h = (float(v[s]) for s in ls.TRUTH_POSE_SIGNALS)
        now = time.time_ns()
        self.w.add_message(
            self._foxglove(TRUTH_POSE_TOPIC, "foxglove.PoseInFrame"),
            t_ns,
            now,
            ls.pose_in_frame(t_ns, ls.WORLD_FRAME, x, y, h),
        )
        self.w.add_message(
            self._foxglove(TRUTH_TF_TOPIC, "foxglove.FrameTransform"),
            t_ns,
            now,
            ls.frame_transform(t_ns, ls.WORLD_FRAME, ls.TRUTH_FRAME, x, y, h),
        )

    def _encoder(self, t_ns: int, name: str, v: Mapping[str, Any], msg: can.Message) -> None:
        pos_key, vel_key = ls.ENCODER_SIGNALS
        self._wheels[self._wheel_of[name]] = (
            float(v[pos_key]) * TWO_PI,
            float(v[vel_key]) * TWO_PI,
        )
        left, right = self._wheels
        if left is not None and right is not None:
            self._wheels = [None, None]
            self.w.add_message(
                self._foxglove(JOINT_STATES_TOPIC, "foxglove.JointStates"),
                t_ns,
                time.time_ns(),
                ls.joint_states(
                    t_ns,
                    (
                        (ls.WHEEL_JOINTS[0], left[0], left[1]),
                        (ls.WHEEL_JOINTS[1], right[0], right[1]),
                    ),
                ),
            )

    def _host_heartbeat(self, t_ns: int, name: str, v: Mapping[str, Any], msg: can.Message) -> None:
        p = self._typed(msg)
        if not isinstance(p, HostHeartbeat):
            return
        key = (int(p.state), int(p.stop_reason))
        if key == self._host:
            return
        old = self._host
        self._host = key
        reason = _stop_reason(p.stop_reason)
        text = f"host state {HostState(old[0]).name if old else '-'} -> {p.state.name}"
        if p.stop_reason:
            text += f" (stop reason {reason})"
        level = (
            ls.LogLevel.WARNING
            if p.state in (HostState.SAFE_STOP, HostState.FAULT)
            else ls.LogLevel.INFO
        )
        self.event(t_ns, level, text, "host")

    def _drive_heartbeat(
        self, t_ns: int, name: str, v: Mapping[str, Any], msg: can.Message
    ) -> None:
        frame = self._typed_frame(msg)
        if frame is None or not isinstance(frame.payload, Heartbeat):
            return
        p = frame.payload
        key = (int(p.axis_state), int(p.axis_error))
        old = self._drive.get(frame.node)
        if key == old:
            return
        self._drive[frame.node] = key
        who = f"drive {frame.node.name if frame.node is not None else '?'}"
        if old is None or old[0] != key[0]:
            prev = AxisState(old[0]).name if old else "-"
            self.event(t_ns, ls.LogLevel.INFO, f"{who} state {prev} -> {p.axis_state.name}", who)
        if old is None or old[1] != key[1]:
            if p.axis_error:
                self.event(
                    t_ns,
                    ls.LogLevel.ERROR,
                    f"{who} error {p.axis_error:#x} ({_flags(p.axis_error)})",
                    who,
                )
            elif old is not None:
                self.event(t_ns, ls.LogLevel.INFO, f"{who} errors cleared", who)

    def _estop(self, t_ns: int, name: str, v: Mapping[str, Any], msg: can.Message) -> None:
        frame = self._typed_frame(msg)
        node = frame.node.name if frame is not None and frame.node is not None else "?"
        self.event(t_ns, ls.LogLevel.ERROR, f"e-stop sent to drive {node}", "host")

    def _fault(self, t_ns: int, name: str, v: Mapping[str, Any], msg: can.Message) -> None:
        labels = {s["name"]: s["choices"] for s in self.codec.describe_signals(name)}
        parts = []
        for sig, val in v.items():
            choice = labels.get(sig, {}).get(int(val)) if labels.get(sig) else None
            parts.append(f"{sig}={choice if choice is not None else val}")
        self.event(t_ns, ls.LogLevel.WARNING, f"{name}: {' '.join(parts)}", "bench")

    def _typed_frame(self, msg: can.Message) -> Any:
        try:
            return self.codec.decode(msg)
        except DecodeError:
            return None

    def _typed(self, msg: can.Message) -> Any:
        frame = self._typed_frame(msg)
        return None if frame is None else frame.payload

    # ------------------------------------------------------------------ close

    def close(self, extra: Mapping[str, str] | None = None) -> None:
        """Write the ``recorder`` metadata record and finish the file."""
        st = self.stats
        md = {k: jsonsafe.dumps(v) for k, v in st.as_dict().items()}
        md["lockstep"] = str(self.lockstep)
        md.update(extra or {})
        self.w.add_metadata("recorder", md)
        self.w.close()


def _stop_reason(code: int) -> str:
    try:
        return StopReason(code).name
    except ValueError:
        return str(code)


def _flags(bits: int) -> str:
    names = [f.name for f in AxisError if f.value and bits & f.value and f.name]
    return "|".join(n for n in names if n) or "unknown bits"


class BusRecorder:
    """Writes frames from ``bus`` into ``path`` until Bench_End, ``stop_event`` or ``duration_s``.

    ``mirror`` sees every message the log gets (a live view, :mod:`tools.live.feed`).
    """

    def __init__(
        self,
        bus: can.BusABC,
        path: str | Path,
        *,
        lockstep: bool,
        codec: Codec | None = None,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        stop_event: threading.Event | None = None,
        attachments: dict[str, bytes] | None = None,
        metadata: dict[str, dict[str, str]] | None = None,
        ack_every_steps: int = 10,
        mirror: Mirror | None = None,
    ) -> None:
        self.bus = bus
        self.path = Path(path)
        self.lockstep = lockstep
        self.stop_event = stop_event or threading.Event()
        self._w = LogWriter(
            self.path,
            library="wheelchair-hil recorder",
            chunk_size=chunk_size,
            flush_interval_s=flush_interval_s,
            mirror=mirror,
        )
        now = time.time_ns()
        for name, data in (attachments or {}).items():
            self._w.add_attachment(name, data, log_time=now, create_time=now)
        self._w.add_metadata("versions", versions())
        for name, md in (metadata or {}).items():
            self._w.add_metadata(name, md)
        self.frames = FrameLog(self._w, lockstep=lockstep, codec=codec)
        self.codec = self.frames.codec
        self.stats = self.frames.stats
        self._end_id = self.codec.frame_id(BenchEnd)
        self._step_id = self.codec.frame_id(BenchStep)
        self._record_ack_id = self.codec.frame_id(RecordAck)
        #: lock-step flow control: acknowledge every this many steps (0: never)
        self.ack_every_steps = ack_every_steps if lockstep else 0
        self._period_ns = self.frames.clock.period_ns
        self._closed = False

    def record(self, msg: can.Message) -> None:
        """Write one frame (raw and, when valid, decoded)."""
        self.frames.record(msg)

    def run(
        self,
        *,
        duration_s: float | None = None,
        on_ready: Callable[[], None] | None = None,
        drain_s: float = 0.3,
        bench_silent_s: float = 5.0,
    ) -> RecorderStats:
        """Record until Bench_End (then ``drain_s`` more), the stop event, or ``duration_s`` (wall).

        A recorder that has seen the bench's steps also ends once the bus has been silent
        for ``bench_silent_s`` (its Bench_End was lost), instead of waiting forever.
        """
        if on_ready:
            on_ready()
        t_end = None if duration_s is None else time.monotonic() + duration_s
        drain_until: float | None = None
        last_rx = time.monotonic()
        record = self.frames.record
        bus, rejected = self.bus, self.stats.rejected

        def recv(timeout: float) -> can.Message | None:
            # a datagram that is no frame is counted by reason (rx_*) and skipped
            return recv_dropping(bus, timeout, rejected)

        end_id, step_id, ack_id = self._end_id, self._step_id, self._record_ack_id
        # The clock is read when the queue is empty and every CLOCK_EVERY frames, not per
        # frame: where a clock read is a system call (a user-mode Linux guest: 90 us) the
        # recorder's reads cost more than its frames.  ``last_rx`` is then the last idle
        # moment after a frame: at most one wait (50 ms) late for a 5 s silence.
        since_clock = 0
        got = False
        try:
            while True:
                if self.stop_event.is_set():
                    self.stats.ended_by = self.stats.ended_by or "stopped"
                    break
                msg = recv(0.0)
                if msg is None or since_clock >= _CLOCK_EVERY:
                    since_clock = 0
                    now = time.monotonic()
                    if got:
                        last_rx, got = now, False
                    if t_end is not None and now >= t_end:
                        self.stats.ended_by = "duration"
                        break
                    if drain_until is not None and now >= drain_until:
                        break
                if msg is None:
                    msg = recv(0.05)
                if msg is None:
                    self._w.poll()
                    if self.frames.bench_seen and now - last_rx > bench_silent_s:
                        self.stats.ended_by = f"bus silent for {bench_silent_s:g} s, no Bench_End"
                        log.warning("recorder: %s", self.stats.ended_by)
                        break
                    continue
                since_clock += 1
                got = True
                if msg.is_extended_id and msg.arbitration_id == ack_id:
                    continue  # flow control: our own echo (logged when sent) or another recorder's
                try:
                    record(msg)
                except Exception as err:  # a frame the log cannot hold must not end the log
                    rejected["internal"] += 1
                    if rejected["internal"] == 1:
                        log.exception("recorder: cannot record %r: %s", msg, err)
                    continue
                if msg.is_extended_id and msg.arbitration_id == step_id and self.ack_every_steps:
                    self._acknowledge()
                if msg.arbitration_id == end_id and msg.is_extended_id and drain_until is None:
                    self.stats.ended_by = "Bench_End"
                    drain_until = time.monotonic() + drain_s
                    stopping.at("bench-end")
        finally:
            self.close()
        return self.stats

    def _acknowledge(self) -> None:
        """Lock-step flow control: tell the bench how far the log is written (Bench_Record_Ack)."""
        t = self.frames.last_step_ns
        if t is None or (t // self._period_ns) % self.ack_every_steps:
            return
        try:
            msg = self.codec.encode(RecordAck(t))
            self.bus.send(msg)
        except (can.CanError, OSError, CodecError) as err:
            log.warning("recorder: cannot send Bench_Record_Ack: %s", err)
            return
        msg.timestamp = time.time()
        self.frames.record(msg)  # every frame on the bus is in the log, ours too

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        stopping.at("flush")
        self.frames.close()
