"""Offline verification: a fresh controller fed the recorded drive feedback, every frame it
sends compared with the recorded one (``replay --verify``; what-if's open loop runs another
controller the same way).

The controller runs its real loop (``LockstepClock`` + ``DriveLink`` on a private virtual
bus); a replayer plays the bench: for each recorded tick it sends ``Bench_Step(t)``, waits for
the controller's ``Bench_Step_Ack(t)``, compares the frames it received meanwhile with the
host's recorded frames of that tick, and then sends the bench's frames that followed the step
in the recording (the controller reads them in its next tick, as it did then).  Steps the
recorded controller never acknowledged are not fed.  Needs a lock-step recording.
"""

from __future__ import annotations

import contextlib
import json
import threading
import time
import uuid
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

from controller.telemetry import McapTelemetry, NullTelemetry, Telemetry
from controller.types import Pose
from dbc.codec import (
    BenchEnd,
    BenchStep,
    BenchStepAck,
    Codec,
    SetInputVel,
    SetInputVelAuth,
)
from dbc.errors import DecodeError
from dbc.runtime.mcapwriter import LogWriter
from tools.logs import mcap_io, runlog
from tools.logs.mcap_io import TruncatedLogWarning, iter_frames, read_contents
from tools.logs.recorder import FrameLog
from tools.replay import ReplayError
from tools.run import build

#: How long (wall) the replayer waits for the fresh controller's ack of one step.
ACK_TIMEOUT_S = 30.0


@dataclass
class Mismatch:
    """The first frame where the fresh controller differs from the recording."""

    t_ns: int
    tick: int
    index: int
    recorded: can.Message | None
    replayed: can.Message | None

    def describe(self, codec: Codec) -> str:
        return (
            f"tick {self.tick} at t = {self.t_ns / 1e9:.3f} s, frame {self.index + 1} of the tick: "
            f"recorded {_frame_text(codec, self.recorded)}, replayed {_frame_text(codec, self.replayed)}"
        )


@dataclass
class OfflineResult:
    controller: str
    ticks: int = 0
    frames_compared: int = 0
    setpoints_compared: int = 0
    mismatched_ticks: int = 0
    first_mismatch: Mismatch | None = None
    steps_skipped: int = 0
    #: per wheel (node name): (t_ns, recorded rev/s, replayed rev/s) for ticks where both sent one
    setpoints: dict[str, list[tuple[int, float, float]]] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.mismatched_ticks == 0 and self.ticks > 0


def _frame_text(codec: Codec, msg: can.Message | None) -> str:
    if msg is None:
        return "nothing"
    raw = f"0x{msg.arbitration_id:X} [{msg.dlc}] {bytes(msg.data).hex(' ')}"
    try:
        name, values = codec.decode_signals(msg)
    except DecodeError:
        return raw
    sig = ", ".join(f"{k}={v}" for k, v in values.items())
    return f"{name}({sig}) {raw}"


def _key(msg: can.Message) -> tuple[int, bool, bool, int, bytes]:
    return (
        msg.arbitration_id,
        msg.is_extended_id,
        msg.is_remote_frame,
        msg.dlc,
        bytes(msg.data),
    )


@dataclass
class _Segment:
    """A recorded ``Bench_Step(t)`` and the frames that followed it until the next step."""

    step: can.Message | None
    t_ns: int
    host: list[can.Message] = field(default_factory=list)  # the host's frames before its ack
    acked: bool = False
    rest: list[can.Message] = field(default_factory=list)  # non-host frames, fed after the tick


def _segments(path: Path, codec: Codec) -> Iterator[_Segment]:

    host_ids = frozenset(
        codec.frame_id(cls, node)
        for cls, node, _n in codec.all_messages()
        if node is not None and codec.senders(cls, node) == ("Host",)
    )
    step_id, ack_id = codec.frame_id(BenchStep), codec.frame_id(BenchStepAck)
    seg = _Segment(None, -1)
    for _t, msg in iter_frames(path):
        aid, ext = msg.arbitration_id, msg.is_extended_id
        if ext and aid == step_id:
            yield seg
            seg = _Segment(msg, _sim_time(codec, msg))
        elif ext and aid == ack_id:
            if seg.step is not None and _sim_time(codec, msg) == seg.t_ns and not seg.acked:
                seg.acked = True
        elif not ext and aid in host_ids:
            if seg.step is not None and not seg.acked:
                seg.host.append(msg)
            # host frames outside a tick (none in lock-step) are not compared
        else:
            seg.rest.append(msg)
    yield seg


def _sim_time(codec: Codec, msg: can.Message) -> int:
    try:
        return int(codec.decode(msg).payload.sim_time_ns)
    except (DecodeError, AttributeError):
        return -1


def replay_offline(
    path: str | Path,
    controller: str | None = None,
    *,
    telemetry_path: Path | None = None,
    frames_path: Path | None = None,
    stop_at_first: bool = False,
) -> OfflineResult:
    """Run a fresh controller against the recorded inputs (see the module doc).

    ``controller``: another controller than the recorded one (what-if).  The
    recorded one is rebuilt with the recorded configuration and gains.
    ``telemetry_path`` / ``frames_path``: keep its internals / its bus traffic.
    """

    path = Path(path)
    contents = mcap_io.read_contents(path)
    md = contents.metadata
    run = md.get("run", {})
    if run.get("mode") == "realtime" or md.get("recorder", {}).get("lockstep") == "False":
        raise ReplayError(
            f"{path}: a real-time recording has no tick boundaries on the bus; "
            "replay --verify and what-if need a lock-step recording"
        )
    cc = md.get("controller_config", {})
    recorded = cc.get("controller") or run.get("controller")
    name = controller or recorded
    if not name:
        raise ReplayError(f"{path}: the log does not say which controller ran; pass --controller")
    cfg = runlog.recorded_config(md)
    trajectory = runlog.recorded_trajectory(contents.attachments)
    overrides = json.loads(cc["gains"]) if ("gains" in cc and name == recorded) else None
    ctl = build.law(name, cfg, trajectory, overrides=overrides)
    codec = Codec.default()
    s0 = trajectory.sample(0.0)
    channel = f"replay-{uuid.uuid4()}"
    result = OfflineResult(controller=name)
    stop = threading.Event()
    tel: Telemetry = McapTelemetry(telemetry_path) if telemetry_path else NullTelemetry()
    frame_log = _frame_log(frames_path, codec) if frames_path else None
    errors: list[BaseException] = []
    with (
        can.Bus(interface="virtual", channel=channel, preserve_timestamps=False) as ctl_bus,
        can.Bus(interface="virtual", channel=channel, preserve_timestamps=False) as feed,
    ):
        clock = build.clock(
            ctl_bus, cfg, realtime=False, codec=codec, idle_timeout_s=ACK_TIMEOUT_S, stop_event=stop
        )
        if isinstance(tel, McapTelemetry):
            clock = tel.wrap_clock(clock)
        node = build.node(
            ctl_bus,
            cfg,
            ctl,
            trajectory,
            clock,
            codec=codec,
            telemetry=tel,
            start_pose=Pose(s0.x_m, s0.y_m, s0.heading_rad),
            stop_event=stop,
        )

        def run_node() -> None:
            try:
                node.run()
            except BaseException as err:  # surfaced below
                errors.append(err)

        th = threading.Thread(target=run_node, name="replay-controller", daemon=True)
        th.start()
        try:
            _drive(path, codec, feed, result, frame_log, stop_at_first, errors)
        finally:
            stop.set()
            th.join(10.0)
            tel.close()
            if frame_log is not None:
                frame_log.close()
    if errors:
        raise ReplayError(f"the replayed controller failed: {errors[0]!r}") from errors[0]
    return result


def _frame_log(path: Path, codec: Codec) -> Any:

    return FrameLog(LogWriter(path, library="wheelchair-hil replay"), lockstep=True, codec=codec)


def _drive(
    path: Path,
    codec: Codec,
    feed: can.BusABC,
    result: OfflineResult,
    frame_log: Any,
    stop_at_first: bool,
    errors: list[BaseException],
) -> None:
    """The replayer's side: feed segment by segment, compare the controller's frames."""
    ack_id = codec.frame_id(BenchStepAck)
    end_id = codec.frame_id(BenchEnd)
    sp_types = (SetInputVel, SetInputVelAuth)
    ended = False
    last_t = 0

    def send(msg: can.Message) -> None:
        feed.send(msg)
        if frame_log is not None:
            frame_log.record(msg)

    for seg in _segments(path, codec):
        last_t = max(last_t, seg.t_ns)
        if seg.step is not None and seg.acked:
            send(seg.step)
            got: list[can.Message] = []
            deadline = time.monotonic() + ACK_TIMEOUT_S
            while True:
                if errors:
                    return
                msg = feed.recv(min(0.5, max(0.0, deadline - time.monotonic())))
                if msg is None:
                    if time.monotonic() >= deadline:
                        raise ReplayError(
                            f"the replayed controller did not acknowledge the step at "
                            f"{seg.t_ns / 1e9:.3f} s within {ACK_TIMEOUT_S:.0f} s"
                        )
                    continue
                if frame_log is not None:
                    frame_log.record(msg)
                if msg.is_extended_id and msg.arbitration_id == ack_id:
                    if _sim_time(codec, msg) == seg.t_ns:
                        break
                    continue
                got.append(msg)
            _compare(codec, seg, got, result, sp_types)
            if stop_at_first and result.first_mismatch is not None:
                return
        elif seg.step is not None:
            result.steps_skipped += 1
        for msg in seg.rest:
            send(msg)
            if msg.is_extended_id and msg.arbitration_id == end_id:
                ended = True
    if not ended:  # a truncated log: end the controller's run like the bench would
        send(codec.encode(BenchEnd(last_t)))


def _compare(
    codec: Codec,
    seg: _Segment,
    got: list[can.Message],
    result: OfflineResult,
    sp_types: tuple[type, ...],
) -> None:
    result.ticks += 1
    rec = seg.host
    bad = None
    for i in range(max(len(rec), len(got))):
        a = rec[i] if i < len(rec) else None
        b = got[i] if i < len(got) else None
        result.frames_compared += 1
        if bad is None and (a is None or b is None or _key(a) != _key(b)):
            bad = Mismatch(seg.t_ns, result.ticks, i, a, b)
    if bad is not None:
        result.mismatched_ticks += 1
        if result.first_mismatch is None:
            result.first_mismatch = bad
    rec_sp = _setpoints(codec, rec, sp_types)
    got_sp = _setpoints(codec, got, sp_types)
    for wheel, v in rec_sp.items():
        if wheel in got_sp:
            result.setpoints_compared += 1
            result.setpoints.setdefault(wheel, []).append((seg.t_ns, v, got_sp[wheel]))


def _setpoints(
    codec: Codec, frames: list[can.Message], sp_types: tuple[type, ...]
) -> dict[str, float]:
    out: dict[str, float] = {}
    for m in frames:
        try:
            node, p = codec.decode(m)
        except DecodeError:
            continue
        if isinstance(p, SetInputVel | SetInputVelAuth) and node is not None:
            out[node.name] = float(p.input_vel_revps)
    return out


def recorded_ticks(path: Path) -> tuple[int | None, str]:
    """How many ticks the log's own records say were recorded, and which record says so."""

    md = read_contents(path).metadata
    ticks = md.get("controller_stats", {}).get("ticks")
    if ticks is not None:
        with contextlib.suppress(ValueError, TypeError):
            return int(json.loads(ticks)), "the controller's statistics (controller_stats)"
    by_name = md.get("recorder", {}).get("by_name")
    if by_name is not None:
        with contextlib.suppress(ValueError, TypeError, AttributeError):
            return int(json.loads(by_name).get("Bench_Step_Ack", 0)), (
                "the recorder's count of Bench_Step_Ack frames"
            )
    return None, ""


@dataclass
class Verification:
    """What ``replay --verify`` found: the replay, how many ticks the log says were recorded
    (and which record says so), and the damage the log's reader met."""

    result: OfflineResult
    expected_ticks: int | None
    expected_from: str
    damage: list[str]


def verify(
    path: str | Path, controller: str | None = None, *, frames_path: Path | None = None
) -> Verification:
    """Replay ``path`` offline (:func:`replay_offline`; ``frames_path`` keeps the replay's
    bus traffic) and read how many ticks it should have had; a damaged log is read as far as
    it is intact, its damage listed."""
    path = Path(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TruncatedLogWarning)
        res = replay_offline(path, controller, frames_path=frames_path)
        expected, source = recorded_ticks(path)
    damage = sorted({str(w.message) for w in caught if issubclass(w.category, TruncatedLogWarning)})
    return Verification(res, expected, source, damage)
