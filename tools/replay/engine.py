"""``wheelchair-hil replay LOG.mcap`` and ``wheelchair-hil summarize LOG.mcap``.

replay has three modes:

* ``--bus ... [--speed K]``: re-transmit the recorded frames (``/can/raw``, in bus
  order) with their original timing, or K times faster: to drive a bench (the
  bench ignores its own frames and acts on the host's) or a viewer.  Lock-step
  recordings replay on simulation time.
* ``--verify``: feed the recorded drive feedback to a fresh controller of the
  recorded kind, offline, and check that every frame it sends equals the recorded
  one.  The controller runs its real loop (``LockstepClock`` + ``DriveLink`` on a
  private virtual bus); a replayer plays the bench: for each recorded tick it sends
  ``Bench_Step(t)``, waits for the controller's ``Bench_Step_Ack(t)``, compares
  the frames it received meanwhile with the host's recorded frames of that tick,
  and then sends the bench's frames that followed the step in the recording (the
  controller reads them in its next tick, as it did then).  Steps the recorded
  controller never acknowledged are not fed.  Exits 1 and names the first
  differing frame if any differs.  Needs a lock-step recording.
* ``--controller NAME``: what-if.  Open loop: NAME's response to the same recorded
  inputs (setpoint differences per wheel; ``--out`` keeps its frames and internals
  in an MCAP).  Closed loop: the recorded scenario (from the log's attachments)
  re-run with NAME on the virtual bus, summaries side by side.

summarize recomputes ``summary.json`` from the log alone (``tools.logs.runlog.summarize``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import tempfile
import threading
import time
import tomllib
import uuid
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can

from controller.planner import load_route, plan
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
from dbc.runtime import jsonsafe, params, stopping
from dbc.runtime.errors import WheelchairError
from dbc.runtime.mcapwriter import LogWriter
from tools import extras
from tools.bus import transport
from tools.bus.transport import resolve
from tools.cli import from_args
from tools.console.progress import Progress
from tools.logs import mcap_io, runlog
from tools.logs.mcap_io import TruncatedLogWarning, iter_frames, merge_into, read_contents
from tools.logs.recorder import FrameLog
from tools.run import build, in_process
from tools.run import scenario as scenario_mod
from tools.run.plan import make_plan
from tools.run.scenario import Scenario, ScenarioParams
from tools.run.summary import build_summary, format_summary

if TYPE_CHECKING:
    from tools.live.view import LiveView

#: How long (wall) the replayer waits for the fresh controller's ack of one step.
ACK_TIMEOUT_S = 30.0


class ReplayError(WheelchairError):
    """The log cannot be replayed as asked."""


# ------------------------------------------------------------------ offline replay


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


# ----------------------------------------------------------------- re-transmission


def retransmit(
    path: str | Path,
    bus: can.BusABC,
    *,
    speed: float = 1.0,
    stop_event: threading.Event | None = None,
    on_frame: Callable[[can.Message], None] | None = None,
) -> int:
    """Send the recorded frames on ``bus`` at their log times divided by ``speed``.

    Frames whose log time is earlier than an already sent one (lock-step ground
    truth) go out at once.  Returns the number of frames sent.
    """

    if not (speed > 0 and math.isfinite(speed)):
        raise ReplayError(f"--speed {speed}: must be a finite number > 0")
    stop = stop_event or threading.Event()
    sent = 0
    first: int | None = None
    start = time.monotonic()
    for log_ns, msg in iter_frames(path):
        if stop.is_set():
            break
        if first is None:
            first = log_ns
        delay = start + (log_ns - first) * 1e-9 / speed - time.monotonic()
        if delay > 0 and stop.wait(delay):
            break
        bus.send(msg)
        sent += 1
        if on_frame is not None:
            on_frame(msg)
    return sent


# ------------------------------------------------------------------------ what-if


def scenario_from_log(contents: Any) -> Any:
    """The recorded scenario, rebuilt from the log's scenario and route attachments."""

    atts = contents.attachments
    scen_names = [n for n in atts if n.startswith("scenario/")]
    route_names = [n for n in atts if n.startswith("route/")]
    if not scen_names or not route_names:
        raise ReplayError("the log has no scenario/route attachments; cannot re-run it")
    tmp = Path(tempfile.mkdtemp(prefix="wheelchair-replay-"))
    scen_path = tmp / Path(scen_names[0]).name
    route_path = tmp / Path(route_names[0]).name
    scen_path.write_bytes(atts[scen_names[0]])
    route_path.write_bytes(atts[route_names[0]])
    table = tomllib.loads(scen_path.read_text())
    sp = params.load(
        ScenarioParams, table.get("scenario", {}), source=str(scen_path), prefix="scenario"
    )
    return Scenario(
        scen_path,
        sp,
        load_route(route_path),
        route_path,
        table.get("bench", {}),
        table.get("faults", []),
    )


def closed_loop(path: Path, controller: str, out: Path) -> dict[str, Any]:
    """Re-run the recorded scenario with ``controller`` (lock-step, virtual bus)."""

    contents = mcap_io.read_contents(path)
    run = contents.metadata.get("run", {})
    scen = scenario_from_log(contents)
    duration = float(run["duration_s"]) if "duration_s" in run else None
    seed = int(run["seed"]) if run.get("seed", "").isdigit() else None
    plan_ = make_plan(scen, controller, realtime=False, duration_s=duration, seed=seed)
    spec = resolve("virtual", f"whatif-{uuid.uuid4()}")
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    in_process.run_threads(spec, plan_, out, Codec.default())
    summary = build_summary(out, plan_, spec, time.monotonic() - t0)
    (out / "summary.json").write_text(jsonsafe.dumps(summary, indent=2, default=str) + "\n")
    return summary


# ---------------------------------------------------------------------- commands


def cmd_summarize(args: argparse.Namespace, argv: list[str]) -> int:

    path = _existing(args.log)
    trajectory = None
    supplied = None
    if args.scenario:
        supplied = scenario_mod.load(args.scenario)
        trajectory = plan(supplied.route, source=str(supplied.route_path))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TruncatedLogWarning)
        try:
            summary = runlog.summarize(path, trajectory=trajectory)
        except runlog.RunLogError as err:
            raise ReplayError(f"{path}: {err}") from err
        damage = sorted(
            {str(w.message) for w in caught if issubclass(w.category, TruncatedLogWarning)}
        )
        missing = runlog.completeness(path, summary, damage)
    if supplied is not None:
        missing = [m for m in missing if m not in ("no route attachment", "no scenario attachment")]
        summary["route_from"] = f"{supplied.path} (given with --scenario)"
        if summary.get("scenario") is None:
            summary["scenario"] = supplied.name
    if summary.get("lost_frames"):
        missing.append(runlog.loss_message(summary["lost_frames"]))
    summary["complete"] = not missing
    summary["missing"] = missing
    text = jsonsafe.dumps(summary, indent=2, default=str) + "\n"
    if args.out:
        Path(args.out).write_text(text)
    print(text if args.json else format_summary(summary), end="" if args.json else "\n")
    if missing and not args.partial:
        print(
            f"summarize: {path} is not whole ({len(missing)} gaps, listed above); the figures "
            "cover only what was readable. Pass --partial to accept that.",
            file=sys.stderr,
        )
        return 1
    return 0


def _existing(p: str) -> Path:
    path = Path(p)
    if not path.is_file():
        raise ReplayError(f"{path}: no such log file")
    return path


def cmd_replay(args: argparse.Namespace, argv: list[str]) -> int:
    path = _existing(args.log)
    if args.live is not None and (args.verify or args.controller):
        raise WheelchairError(
            "replay --live serves a log; it does not go with --verify or --controller"
        )
    if args.verify or args.controller:
        stopping.raise_on_stop()  # a computation, no loop to end: a stop signal interrupts it
    if args.verify:
        return _verify(path, args)
    if args.controller:
        return _what_if(path, args)
    if args.live is not None:
        return _serve_live(path, args)

    spec = from_args.bus_spec(args)
    stop = from_args.stop_on_signals()
    t0 = time.monotonic()
    total = mcap_io.raw_frame_count(path)
    bus = transport.open_bus(spec)
    try:
        with Progress(total, "replay", "frame", enabled=not args.no_progress) as bar:
            n = retransmit(
                path, bus, speed=args.speed, stop_event=stop, on_frame=lambda _m: bar.update()
            )
    finally:
        bus.shutdown()
    print(f"replayed {n} frames on {spec.describe()} in {time.monotonic() - t0:.1f} s")
    return 0


def _serve_live(path: Path, args: argparse.Namespace) -> int:
    """``replay LOG --live [HOST:]PORT [--bus ...]``: serve the log, re-transmit it too if asked."""
    extras.require("replay --live", "live")
    from tools.live.playback import serve_log  # lazy: the [live] extra, with --live only

    stop = from_args.stop_on_signals()
    bus = None
    if args.bus is not None:
        bus = transport.open_bus(from_args.bus_spec(args))
    sender: threading.Thread | None = None
    sent: list[int] = []

    def ready(view: LiveView) -> None:
        print(f"live: {view.url} (open it in Foxglove)", file=sys.stderr, flush=True)

    def started() -> None:
        nonlocal sender
        if bus is not None:
            sender = threading.Thread(
                target=lambda: sent.append(
                    retransmit(path, bus, speed=args.speed, stop_event=stop)
                ),
                name="retransmit",
                daemon=True,
            )
            sender.start()

    t0 = time.monotonic()
    try:
        counts = serve_log(
            path,
            args.live,
            speed=args.speed,
            wait_for_client=not args.no_wait,
            stop_event=stop,
            on_ready=ready,
            on_start=started,
        )
        if sender is not None:
            sender.join()
    finally:
        if bus is not None:
            bus.shutdown()
    print(
        f"served {sum(counts.values())} messages on {len(counts)} channels in "
        f"{time.monotonic() - t0:.1f} s"
        + (f"; replayed {sent[0]} frames on {args.bus}" if sent else "")
    )
    return 0


def _recorded_ticks(path: Path) -> tuple[int | None, str]:
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


def _verify(path: Path, args: argparse.Namespace) -> int:
    """Exit 0 only if every tick the log says was recorded was replayed and matched."""

    codec = Codec.default()
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TruncatedLogWarning)
        res = replay_offline(
            path,
            args.controller,
            frames_path=out / "verify.mcap" if out else None,
        )
        expected, source = _recorded_ticks(path)
    damage = sorted({str(w.message) for w in caught if issubclass(w.category, TruncatedLogWarning)})
    print(
        f"{res.controller}: {res.ticks} ticks, {res.frames_compared} frames compared "
        f"({res.setpoints_compared} setpoints), {res.steps_skipped} unacknowledged steps skipped"
    )
    if res.first_mismatch is not None:
        if damage:  # say first that the log itself is damaged: differences may be its holes
            print(f"verify: the log is damaged: {'; '.join(damage)}", file=sys.stderr)
        print(
            f"verify: FAILED in {res.mismatched_ticks} ticks"
            + (
                " (the log is damaged: a difference may be a frame it could not read)"
                if damage
                else ""
            )
            + f"; first difference: {res.first_mismatch.describe(codec)}",
            file=sys.stderr,
        )
        return 1
    why = list(damage)
    if expected is None:
        why.append(
            "the log has no record of how many ticks were recorded (no controller_stats or "
            "recorder metadata: the run did not end cleanly)"
        )
    elif res.ticks < expected:
        why.append(f"{expected - res.ticks} recorded ticks are not in the readable part of the log")
    if res.ticks == 0:
        why.append("no tick was replayed")
    if why:
        total = "?" if expected is None else str(expected)
        print(
            f"verify: INCOMPLETE: {res.ticks} of {total} ticks verified"
            + (f" ({total} from {source})" if source else "")
            + "; the rest were not: "
            + "; ".join(why),
            file=sys.stderr,
        )
        return 1
    print(
        f"verify: OK, all {res.ticks} of {expected} ticks ({source}): every frame equals the recorded one"
    )
    return 0


def _what_if(path: Path, args: argparse.Namespace) -> int:

    name = args.controller
    out = Path(args.out) if args.out else Path(f"whatif-{name}")
    out.mkdir(parents=True, exist_ok=True)
    frames = out / f"open-loop-{name}.mcap"
    internals = out / f"open-loop-{name}-controller.mcap"
    res = replay_offline(path, name, telemetry_path=internals, frames_path=frames)

    merge_into(frames, [internals])
    internals.unlink()
    print(f"open loop: {name} on the recorded inputs ({res.ticks} ticks) -> {frames}")
    for wheel, rows in sorted(res.setpoints.items()):
        d = [b - a for _t, a, b in rows]
        rms = math.sqrt(sum(x * x for x in d) / len(d)) if d else math.nan
        big = max((abs(x) for x in d), default=math.nan)
        print(f"  {wheel:<5} setpoint difference: RMS {rms:.4f} rev/s, max {big:.4f} rev/s")
    recorded = runlog.summarize(path)
    new = closed_loop(path, name, out / f"closed-loop-{name}")
    print("closed loop, recorded run:")
    print(format_summary(recorded))
    print(f"closed loop, re-run with {name} -> {out / f'closed-loop-{name}'}:")
    print(format_summary(new))
    return 0
