"""The soak's report and verdict, from its directory (:mod:`tools.soak.orchestrate`'s layout).

It owns what is judged and by which rule (docs/safety.md, "Soak"):

* **every stop of a controller has a reason that the evidence explains**: the stop and its
  reason are the Host_Heartbeat state and Stop_Reason frames in the recorders' logs (the
  controller's own statistics where no recorder ran); the evidence is an injected event that
  can cause that reason (:data:`CAUSES`), active at the stop or ended at most
  :data:`GRACE_S` before it, or, for the staleness reasons, a gap in the drives' feedback of
  the log itself (a late bench on a loaded machine: the rule of docs/safety.md § 3);
* **no frame lost without a count**: every receiver's kernel drops are counted by the part;
  every Bench_Step period missing inside a log must be counted by its recorder, and the steps
  between two recorders are counted here as the recorder's downtime;
* **no wheel moves after a stop**: bench truth (Bench_Truth_Twist) from
  :data:`SETTLE_S` after the stop until the next controller arms, each wheel's rim below
  :data:`STILL_MPS`;
* **memory does not grow**: each part's resident memory, sampled once a second, after each
  process's first :data:`RSS_WARMUP_S`, grows with the process's age (pooled over the part's
  processes) by less than :data:`RSS_SLOPE_MIB_PER_MIN`.

Per minute it reports each part's memory and the controllers' p99 lateness, with their slope
over the run.  The judging functions take plain data (:class:`LogView`, dicts), so the rules
can be tested on small synthetic inputs; :func:`analyse` reads the directory.  Nothing here
prints.
"""

from __future__ import annotations

import itertools
import json
import math
import statistics
import subprocess
import warnings
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dbc.codec import (
    DRIVES,
    BenchEnd,
    BenchStep,
    EncoderEstimates,
    HostHeartbeat,
    HostState,
    SetInputVel,
    SetInputVelAuth,
    StopReason,
    TruthTwist,
)
from firmware_sim.config import default_config
from firmware_sim.faultspec import KINDS
from tools.bus import transport
from tools.logs.mcap_io import TruncatedLogWarning, iter_decoded, iter_messages
from tools.safety.attacks.analysis import STILL_REVPS
from tools.soak.schedule import SIGNALS

REPORT = "soak.json"
#: How long after an event ends it may still explain a stop (s): detection (at most 0.5 s
#: for the slowest detector, an encoder frozen while commanded), the coordinated stop ramp
#: (at most 1.3 s from the top speed at 1.0 m/s^2), and the estimator pulling back after a
#: biased localizer or a slipping wheel, which takes a few fixes more.
GRACE_S = 5.0
#: The drives' feedback is stale after 3 periods (docs/safety.md § 3): a gap beyond this in
#: the log explains a staleness stop.
STALE_GAP_MS = 30.0
#: A drive trips when no fresh setpoint came for its watchdog timeout.
SETPOINT_GAP_MS = 100.0
#: The host's heartbeat goes out every 100 ms: a host silent this long has ended.
HOST_SILENT_S = 0.5
#: From a stop until the wheels are judged still (s): the coordinated ramp from the top speed
#: (1.3 s at 1.0 m/s^2) and the drives' disarming.
SETTLE_S = 2.0
#: A still wheel's rim (m/s): the attack suite's bound (0.02 rev/s) at the nominal radius.
STILL_MPS = STILL_REVPS * 2.0 * math.pi * default_config().chair.wheel_radius_m
#: Memory is judged from this age of a process on (s): imports, first ticks and caches.
RSS_WARMUP_S = 20.0
#: A part is judged only over at least this span (s, its processes' after their warm-up
#: together): over less, one step of the allocator (1 MiB) reads as several MiB/min.
RSS_MIN_SPAN_S = 60.0
#: ... and fails only if it grew by more than this over its judged span (MiB, the fitted
#: slope times the span): less is the allocator's granularity, not a leak.
RSS_MIN_GROWTH_MIB = 4.0
#: The bound on memory growth (MiB per minute): a controller on a chair runs a day (16 h);
#: 1 MiB/min is about 1 GiB in that day, a tenth of what a wheelchair's onboard computer
#: (8-16 GiB) can spare before the controller's own tick could be delayed by reclaim.
RSS_SLOPE_MIB_PER_MIN = 1.0

_STALENESS = frozenset({"ENCODER_STALE", "DRIVE_LOST", "DRIVE_ERROR", "ARMING_TIMEOUT"})
_BUS = frozenset(k for k in KINDS if k.startswith("bus-"))
_NODES = frozenset({"node-silent", "node-reboot"})
_ENCODERS = frozenset(k for k in KINDS if k.startswith("encoder-"))
_WHEEL = frozenset({"flat-tire", "shaft-bump", "slip", "torque-loss", "dead-motor"})
_LOCALIZER = frozenset(k for k in KINDS if k.startswith("localizer-"))
_ATTACKS = frozenset({"forge-both", "forge-left", "replay"})
#: Which injected events can cause a stop for each reason.  ROUTE_DONE is the route's end;
#: a controller stopped by SIGTERM ends with whatever it was doing (its heartbeat falls
#: silent).  Attacks explain a stop only without authentication (with it, their frames are
#: refused and must change nothing).  CONTRACT_MISMATCH has one: a drive's answer to the
#: contract-hash read with bits flipped by ``bus-corrupt`` (a 60-minute soak met it: the
#: hash read back one bit off while the fault was active; the controller refused to arm, as
#: it must).  NON_FINITE, TICK_EXCEPTION and BUS_DOWN have no cause a soak injects: they are
#: defects.
CAUSES: dict[str, frozenset[str]] = {
    "ENCODER_STALE": _BUS | _NODES | {"encoder-dropout"},
    "DRIVE_LOST": _BUS | _NODES,
    "DRIVE_ERROR": _BUS | _NODES | _WHEEL | _ENCODERS,
    "ENCODER_STUCK": _ENCODERS | _NODES | _WHEEL | _BUS,
    "ENCODER_JUMP": _ENCODERS | _NODES | _WHEEL | _BUS,
    "DISOBEYED": _ENCODERS | _NODES | _WHEEL | _BUS | _ATTACKS,
    "OFF_PATH": _ENCODERS | _NODES | _WHEEL | _BUS | _LOCALIZER,
    # arming waits for both drives in closed loop, their heartbeats and a first fix
    "ARMING_TIMEOUT": _NODES | _BUS | _LOCALIZER,
    "CONTRACT_MISMATCH": frozenset({"bus-corrupt"}),
    "OPERATOR": frozenset({"control-term"}),
    "HOST_SILENT": frozenset({"control-term"}),
}
_ACTIVE = {HostState.ARMING.name, HostState.TRACKING.name}
_STOPPED = {HostState.SAFE_STOP.name, HostState.FAULT.name, HostState.DONE.name}


def is_moot(event: Mapping[str, Any]) -> bool:
    """A signal whose process had ended by itself just before (a stop, between legs): it
    could not be sent, which the run is not to blame for (counted apart, not as not done)."""
    detail = str(event.get("detail", ""))
    return event.get("action") == "signal" and (
        detail.endswith("had already ended") or detail.startswith("no ")
    )


@dataclass
class LogView:
    """What one recorder's log shows, in simulation time (ns)."""

    path: str
    steps_ns: list[int] = field(default_factory=list)
    #: every Host_Heartbeat: (t, state name, Stop_Reason name)
    heartbeats: list[tuple[int, str, str]] = field(default_factory=list)
    #: gaps in the feedback and the host's setpoints: (t at the gap's end, ms, what)
    gaps: list[tuple[int, float, str]] = field(default_factory=list)
    #: bench truth where a wheel's rim moved faster than STILL_MPS: (t, m/s)
    moving: list[tuple[int, float]] = field(default_factory=list)
    bench_end_ns: int | None = None
    damage: list[str] = field(default_factory=list)

    @property
    def first_ns(self) -> int | None:
        return self.steps_ns[0] if self.steps_ns else None

    @property
    def last_ns(self) -> int | None:
        return self.steps_ns[-1] if self.steps_ns else None


def read_log(path: Path, half_track_m: float | None = None) -> LogView:
    """:class:`LogView` of a recorder's MCAP (a truncated one too: what it holds)."""
    b = half_track_m if half_track_m is not None else default_config().chair.half_track_m
    view = LogView(str(path))
    last_rx: dict[str, int] = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TruncatedLogWarning)
        try:
            for lt, t, node, p in iter_decoded(path):
                kind = type(p)
                if kind is BenchStep:
                    view.steps_ns.append(t)
                    continue
                if not view.steps_ns:
                    continue  # a restarted recorder's frames before its first step: no time
                if kind is HostHeartbeat:
                    view.heartbeats.append((t, p.state.name, _reason(p.stop_reason)))
                elif kind is TruthTwist:
                    rim = abs(p.v_mps) + abs(p.omega_radps) * b
                    if rim >= STILL_MPS:
                        view.moving.append((t, rim))
                elif kind is BenchEnd:
                    view.bench_end_ns = t
                elif node is not None and node in DRIVES:
                    what = None
                    if kind is EncoderEstimates:
                        what, limit = f"encoder feedback of {node.name}", STALE_GAP_MS
                    elif kind is SetInputVel or kind is SetInputVelAuth:
                        what, limit = f"host setpoints to {node.name}", SETPOINT_GAP_MS
                    if what is not None:
                        prev = last_rx.get(what)
                        last_rx[what] = lt
                        if prev is not None and (lt - prev) / 1e6 > limit:
                            view.gaps.append((t, (lt - prev) / 1e6, what))
        except Exception as err:  # a damaged log: what was read stands, the damage is said
            view.damage.append(f"{type(err).__name__}: {err}")
    view.damage += sorted({str(w.message) for w in caught})
    return view


def _reason(code: int) -> str:
    try:
        return StopReason(code).name
    except ValueError:
        return f"UNKNOWN_{code}"


# ------------------------------------------------------------------ the stops


@dataclass
class Stop:
    """One stop of a controller."""

    leg: int
    at_s: float
    state: str
    reason: str
    source: str
    evidence: list[str] = field(default_factory=list)
    #: the leg's route, and whether its controller armed and tracked before the stop
    route: str = ""
    tracked: bool = False

    @property
    def explained(self) -> bool:
        return bool(self.evidence)

    def as_dict(self) -> dict[str, Any]:
        return {
            "leg": self.leg,
            "at_s": round(self.at_s, 3),
            "state": self.state,
            "reason": self.reason,
            "source": self.source,
            "route": self.route,
            "tracked": self.tracked,
            "explained": self.explained,
            "evidence": self.evidence,
        }


def stops_in(views: Sequence[LogView]) -> list[tuple[float, str, str]]:
    """Every stop the logs show: (simulation s, state, reason): a host leaving ARMING or
    TRACKING for SAFE_STOP, FAULT or DONE, or falling silent while in them
    (``HOST_SILENT``)."""
    out: list[tuple[float, str, str]] = []
    for v in views:
        prev: tuple[int, str, str] | None = None
        for hb in v.heartbeats:
            if prev is not None and prev[1] in _ACTIVE:
                if hb[1] in _STOPPED:
                    out.append((hb[0] / 1e9, hb[1], hb[2]))
                elif (hb[0] - prev[0]) / 1e9 > HOST_SILENT_S:
                    out.append((prev[0] / 1e9, "SILENT", "HOST_SILENT"))
            prev = hb
        last = v.last_ns
        silent = last is not None and prev is not None and (last - prev[0]) / 1e9 > HOST_SILENT_S
        if prev is not None and prev[1] in _ACTIVE and silent:
            out.append((prev[0] / 1e9, "SILENT", "HOST_SILENT"))
    return sorted(out)


def explain(
    at_s: float,
    reason: str,
    events: Iterable[dict[str, Any]],
    views: Sequence[LogView],
    *,
    auth: bool,
    bench_end_s: float | None,
    part: str | None = None,
) -> list[str]:
    """The evidence that explains a stop for ``reason`` at ``at_s`` (empty: unexplained).

    ``events``: the events carried out (``kind``, ``action``, ``done_sim_s`` or ``at_s``,
    ``duration_s``; a signal's ``target``).  ``part``: the stopped controller (``control-3``):
    a signal explains only the stop of the part it was sent to."""
    why: list[str] = []
    if reason == "ROUTE_DONE":
        return ["the route ended (DONE)"]
    if bench_end_s is not None and at_s >= bench_end_s - 1.0:
        return [f"the run ended at {bench_end_s:.1f} s (the bench's end, or the soak stopped)"]
    causes = CAUSES.get(reason, frozenset())
    for ev in events:
        if not ev.get("ok", True):
            continue
        kind = str(ev["kind"])
        start = ev.get("done_sim_s")
        start = float(ev["at_s"]) if start is None else float(start)
        end = start + float(ev.get("duration_s") or 0.0)
        if kind == "control-term":
            # a controller asked to stop ends whatever it was doing, in its next ticks
            if part is not None and ev.get("target") and ev["target"] != part:
                continue
            if start - 0.5 <= at_s <= start + GRACE_S:
                why.append(f"SIGTERM of the controller at {start:.1f} s")
            continue
        if kind in _ATTACKS and auth:
            continue  # with authentication an attack must change nothing
        if kind in causes and start <= at_s <= end + GRACE_S:
            span = f"{start:.1f}-{end:.1f} s" if end > start else f"at {start:.1f} s"
            params = " ".join(f"{k}={v}" for k, v in sorted(dict(ev.get("params", {})).items()))
            why.append(f"{ev['action']} {kind}{' ' + params if params else ''} {span}")
    if reason in _STALENESS:
        for v in views:
            for t, ms, what in v.gaps:
                if at_s - 1.0 <= t / 1e9 <= at_s + 0.1:
                    why.append(f"{what} paused {ms:.0f} ms at {t / 1e9:.2f} s (log {v.path})")
                    break
    return why


def leg_stops(
    legs: Sequence[dict[str, Any]],
    views: Sequence[LogView],
    events: Sequence[dict[str, Any]],
    *,
    auth: bool,
    stopped_s: float | None = None,
) -> list[Stop]:
    """One stop per controller leg: from the logs where a recorder saw it, else from the
    controller's statistics; each with its evidence.  ``stopped_s``: when a stop signal ended
    the soak early (it ends the controllers too)."""
    logged = stops_in(views)
    ends = [v.bench_end_ns / 1e9 for v in views if v.bench_end_ns is not None]
    if stopped_s is not None:
        ends.append(stopped_s)
    bench_end = min(ends, default=None)
    out: list[Stop] = []
    used: set[int] = set()
    for leg in legs:
        lo = float(leg.get("start_sim_s") or 0.0) - 0.5
        hi = leg.get("end_sim_s")
        hi = math.inf if hi is None else float(hi) + 1.0
        # each stop in the logs is one leg's: the first of this leg's span not yet taken
        mine = [k for k, s in enumerate(logged) if lo <= s[0] <= hi and k not in used]
        if mine:
            used.add(mine[0])
            at, state, reason = logged[mine[0]]
            source = "log"
        elif leg.get("stats") is not None:
            st = leg["stats"]
            at = float(leg.get("end_sim_s") or leg.get("start_sim_s") or 0.0)
            state = str(st.get("final_state") or "?")
            reason = str(st.get("stop_reason") or "UNKNOWN")
            source = "controller_stats.json (no recorder saw the stop)"
            if state in _ACTIVE:
                state, reason = "SILENT", "HOST_SILENT"
        else:  # it never ran its loop to the end: its exit and its own last words
            at = float(leg.get("end_sim_s") or leg.get("start_sim_s") or 0.0)
            state, reason = "EXITED", f"EXIT_{leg.get('exit_code')}"
            source = f"no statistics; its stderr ends: {leg.get('said') or '-'}"
        stop = Stop(int(leg["index"]), at, state, reason, source, route=str(leg.get("route", "")))
        stop.tracked = any(
            lo <= t / 1e9 <= at and st == HostState.TRACKING.name
            for v in views
            for t, st, _r in v.heartbeats
        )
        stop.evidence = explain(
            at,
            reason,
            events,
            views,
            auth=auth,
            bench_end_s=bench_end,
            part=f"control-{leg['index']}",
        )
        out.append(stop)
    return out


# ------------------------------------------------------------------- motion


def moving_after_stops(
    stops: Sequence[Stop], legs: Sequence[dict[str, Any]], views: Sequence[LogView]
) -> list[str]:
    """Where a wheel moved (bench truth) from SETTLE_S after a stop until the next controller
    started."""
    starts = {int(leg["index"]): float(leg.get("start_sim_s") or 0.0) for leg in legs}
    found: list[str] = []
    for stop in stops:
        lo = stop.at_s + SETTLE_S
        hi = starts.get(stop.leg + 1, math.inf)  # the next controller may move the chair
        for v in views:
            fast = [(t, m) for t, m in v.moving if lo <= t / 1e9 < hi]
            if fast:
                t, m = max(fast, key=lambda x: x[1])
                found.append(
                    f"after the stop of leg {stop.leg} at {stop.at_s:.1f} s a wheel moved at "
                    f"{m:.3f} m/s at {t / 1e9:.2f} s (bound {STILL_MPS:.3f} m/s)"
                )
                break
    return found


# ------------------------------------------------------------------- losses


def step_period_ns(views: Sequence[LogView]) -> int | None:
    diffs = [b - a for v in views for a, b in itertools.pairwise(v.steps_ns)]
    diffs = [d for d in diffs if d > 0]
    return int(statistics.median(diffs)) if diffs else None


def missing_steps(steps_ns: Sequence[int], period_ns: int) -> int:
    """Bench_Step periods missing between the first and the last step of a log."""
    return sum(max(0, round((b - a) / period_ns) - 1) for a, b in itertools.pairwise(steps_ns))


def losses(
    recorders: Sequence[dict[str, Any]],
    views: Sequence[LogView],
    bench: dict[str, Any] | None,
    controllers: Sequence[dict[str, Any]],
) -> tuple[dict[str, Any], list[str]]:
    """Frames lost per receiver, and the losses nobody counted.

    ``recorders`` and ``views`` pair up in order; each recorder's ``stats`` is its
    recorder_stats.json (None when it was killed); ``bench`` the bench's statistics;
    ``controllers`` each with ``name`` and ``stats``."""
    period = step_period_ns(views)
    per: dict[str, Any] = {}
    uncounted: list[str] = []
    if bench is None:
        uncounted.append("the bench wrote no statistics: its receive losses are not counted")
    else:
        per["sim"] = {"kernel_dropped": int(bench.get("rx_dropped") or 0)}
    for c in controllers:
        st = c.get("stats")
        if st is None:
            uncounted.append(f"{c['name']} wrote no statistics: its receive losses are not counted")
            continue
        per[c["name"]] = {"kernel_dropped": int(st.get("rx_dropped") or 0)}
    prev_last: int | None = None
    for rec, view in zip(recorders, views, strict=True):
        name = str(rec["name"])
        st = rec.get("stats")
        inside = missing_steps(view.steps_ns, period) if period else 0
        down = 0
        if prev_last is not None and view.first_ns is not None and period:
            down = max(0, round((view.first_ns - prev_last) / period) - 1)
        entry: dict[str, Any] = {
            "log": view.path,
            "steps": len(view.steps_ns),
            "missing_steps_in_log": inside,
            "steps_while_down_before": down,
        }
        if st is not None:
            entry["kernel_dropped"] = int(st.get("rx_dropped") or 0)
            entry["missed_steps_counted"] = int(st.get("missed_steps") or 0)
            entry["ended_by"] = st.get("ended_by", "")
            if inside > entry["missed_steps_counted"]:
                uncounted.append(
                    f"{name}: {inside} Bench_Step periods missing in {view.path}, its recorder "
                    f"counted {entry['missed_steps_counted']}"
                )
        else:
            entry["ended_by"] = f"{rec.get('signalled') or 'ended'} (no statistics)"
            if inside:
                uncounted.append(
                    f"{name}: {inside} Bench_Step periods missing in {view.path} and no "
                    "statistics of its recorder count them"
                )
        per[name] = entry
        if view.last_ns is not None:
            prev_last = view.last_ns
    return per, uncounted


# ------------------------------------------------------------------- memory


def slope_per_min(points: Sequence[tuple[float, float]]) -> float | None:
    """Least-squares slope of (s, value) points, per minute (None for fewer than 2)."""
    if len(points) < 2:
        return None
    xs = [p[0] for p in points]
    ys = [p[1] for p in points]
    mx, my = statistics.fmean(xs), statistics.fmean(ys)
    sxx = sum((x - mx) ** 2 for x in xs)
    if sxx == 0:
        return None
    return 60.0 * sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx


def growth_slope(processes: Sequence[Sequence[tuple[float, float]]]) -> float | None:
    """Memory growth with a process's age, pooled over processes (MiB/min): the
    least-squares slope of (s, MiB) with an intercept of each process's own (the
    within-process estimate), so that short-lived processes of a part, restarted again and
    again, add up their evidence.  None without two points in one process."""
    num = den = 0.0
    for pts in processes:
        if len(pts) < 2:
            continue
        mx = statistics.fmean(p[0] for p in pts)
        my = statistics.fmean(p[1] for p in pts)
        num += sum((x - mx) * (y - my) for x, y in pts)
        den += sum((x - mx) ** 2 for x, _ in pts)
    return 60.0 * num / den if den > 0 else None


def memory(rss: Sequence[Sequence[Any]]) -> tuple[dict[str, Any], list[str]]:
    """Per part (sim, record, control): RSS per minute (MiB, median of the samples), its
    slope over the run, and the growth with a process's age after its warm-up, pooled over
    the part's processes (:func:`growth_slope`); the parts whose memory grew too fast.

    ``rss``: (wall s, simulation s or None, instance name, KiB) samples."""
    by_proc: dict[str, list[tuple[float, float]]] = defaultdict(list)
    per_min: dict[str, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    for wall, sim, name, kib in rss:
        part = str(name).split("-")[0]
        if part == "attacker":
            continue
        by_proc[str(name)].append((float(wall), kib / 1024.0))
        minute = int((float(sim) if sim is not None else float(wall)) // 60)
        per_min[part][minute].append(kib / 1024.0)
    out: dict[str, Any] = {}
    failures: list[str] = []
    for part, minutes in sorted(per_min.items()):
        table = {m: round(statistics.median(v), 1) for m, v in sorted(minutes.items())}
        judged: dict[str, list[tuple[float, float]]] = {}
        for name, pts in by_proc.items():
            if name.split("-")[0] == part:
                t0 = pts[0][0]
                mine = [(t, v) for t, v in pts if t - t0 >= RSS_WARMUP_S]
                if len(mine) >= 2:
                    judged[name] = mine
        span = sum(p[-1][0] - p[0][0] for p in judged.values())
        slope = growth_slope(list(judged.values())) if span >= RSS_MIN_SPAN_S else None
        if (
            slope is not None
            and slope > RSS_SLOPE_MIB_PER_MIN
            and slope * span / 60.0 > RSS_MIN_GROWTH_MIB
        ):
            failures.append(
                f"{part}: memory grew {slope:.2f} MiB/min with the age of its processes over "
                f"{span:.0f} s of {len(judged)} process(es) (bound {RSS_SLOPE_MIB_PER_MIN} "
                f"MiB/min beyond {RSS_MIN_GROWTH_MIB} MiB)"
            )
        out[part] = {
            "rss_mib_per_minute": {str(m): v for m, v in table.items()},
            "slope_mib_per_min_over_run": _round(
                slope_per_min([(m * 60.0, v) for m, v in table.items()])
            ),
            "growth_mib_per_min": _round(slope),
            "judged_s": round(span, 1),
            "judged_processes": len(judged),
        }
    return out, failures


def _round(v: float | None, nd: int = 3) -> float | None:
    return None if v is None else round(v, nd)


# ---------------------------------------------------------------- lateness


def lateness(legs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The controllers' p99 tick lateness per minute of simulation time (ms), with its slope
    (/controller/loop of each leg's controller.mcap)."""
    per_min: dict[int, list[float]] = defaultdict(list)
    for leg in legs:
        path = Path(str(leg["dir"])) / "ctl" / "controller.mcap"
        if not path.exists():
            continue
        base = float(leg.get("start_sim_s") or 0.0)
        first: int | None = None
        try:
            for _ch, msg in iter_messages(path, topics={"/controller/loop"}):
                rec = json.loads(msg.data)
                late = rec.get("lateness_us")
                if late is None:
                    continue
                first = msg.log_time if first is None else first
                minute = int((base + (msg.log_time - first) / 1e9) // 60)
                per_min[minute].append(float(late) / 1000.0)
        except Exception:  # a controller stopped mid-write: what was read stands
            continue
    table = {m: round(_p99(v), 3) for m, v in sorted(per_min.items()) if v}
    return {
        "p99_ms_per_minute": {str(m): v for m, v in table.items()},
        "slope_ms_per_min": _round(slope_per_min([(m * 60.0, v) for m, v in table.items()])),
    }


def _p99(values: list[float]) -> float:
    values = sorted(values)
    return values[min(len(values) - 1, math.ceil(0.99 * len(values)) - 1)]


# --------------------------------------------------------------- completeness


def verify(log: Path) -> dict[str, Any]:
    """``wheelchair-hil replay LOG --verify``: its exit status and last line."""
    try:
        proc = subprocess.run(
            transport.python_argv("replay", str(log), "--verify"),
            capture_output=True,
            text=True,
            timeout=600,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired) as err:
        return {"exit": None, "said": f"{type(err).__name__}: {err}"}
    lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if ln.strip()]
    return {"exit": proc.returncode, "said": lines[-1] if lines else ""}


# ------------------------------------------------------------------- report


def _json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def judge(
    stops: Sequence[Stop],
    uncounted: Sequence[str],
    moved: Sequence[str],
    memory_failures: Sequence[str],
) -> list[str]:
    """The soak's failures (empty: it passed)."""
    f = [
        f"unexplained stop of leg {s.leg} at {s.at_s:.1f} s: {s.state} {s.reason} ({s.source})"
        for s in stops
        if not s.explained
    ]
    f += [f"uncounted loss: {u}" for u in uncounted]
    f += [f"wheel moving after a stop: {m}" for m in moved]
    f += [f"memory growth: {m}" for m in memory_failures]
    return f


def analyse(out: Path, *, run_verify: bool = True) -> dict[str, Any]:
    """The report of the soak in ``out`` (written to ``out/soak.json`` by the caller)."""
    orch = _json(out / "orchestration.json")
    if orch is None:
        raise FileNotFoundError(f"{out / 'orchestration.json'}: missing or unreadable")
    sched = _json(out / "schedule.json") or {}
    auth = bool(orch.get("auth", True))
    insts = list(orch.get("instances", []))
    events = list(orch.get("events", []))
    recs = [i for i in insts if i["part"] == "record"]
    legs = [i for i in insts if i["part"] == "control"]
    for leg in legs:
        leg["stats"] = _json(Path(leg["dir"]) / "ctl" / "controller_stats.json")
        if leg["stats"] is None:
            leg["said"] = _last_line(Path(leg["dir"]) / "control.err")
    for rec in recs:
        rec["stats"] = _json(Path(rec["dir"]) / "recorder_stats.json")
    views = [read_log(Path(r["dir"]) / "run.mcap") for r in recs]
    stopped = orch.get("stopped_sim_s")
    stops = leg_stops(
        legs, views, events, auth=auth, stopped_s=None if stopped is None else float(stopped)
    )
    moved = moving_after_stops(stops, legs, views)
    lost, uncounted = losses(
        recs,
        views,
        _json(out / "sim" / "bench_stats.json"),
        [{"name": f"control-{leg['index']}", "stats": leg["stats"]} for leg in legs],
    )
    mem, mem_fail = memory(orch.get("rss", []))
    logs = []
    for rec, view in zip(recs, views, strict=True):
        entry: dict[str, Any] = {
            "log": view.path,
            "recorder": rec["name"],
            "signalled": rec.get("signalled", ""),
            "first_s": _round((view.first_ns or 0) / 1e9),
            "last_s": _round((view.last_ns or 0) / 1e9),
            "damage": view.damage,
        }
        if run_verify:
            entry["verify"] = verify(Path(view.path))
        logs.append(entry)
    failures = judge(stops, uncounted, moved, mem_fail)
    moot = [e for e in events if not e.get("ok") and is_moot(e)]
    not_done = [e for e in events if not e.get("ok") and not is_moot(e)]
    kinds_done = sorted({str(e["kind"]) for e in events if e.get("ok")})
    summary = {
        "passed": not failures,
        "minutes": sched.get("minutes"),
        "seed": sched.get("seed"),
        "ended_by": orch.get("ended_by", ""),
        # the whole schedule carried out to the bench's end: a soak cut short is partial
        "complete": orch.get("ended_by") == "the bench ended" and not not_done,
        "controllers": len(legs),
        "controllers_that_tracked": sum(s.tracked for s in stops),
        "recorders": len(recs),
        "stops": len(stops),
        "stops_unexplained": sum(not s.explained for s in stops),
        "stop_reasons": dict(sorted(_count(s.reason for s in stops).items())),
        "events_done": len(events) - len(not_done) - len(moot),
        "events_moot": len(moot),
        "events_not_done": len(not_done),
        "fault_kinds_covered": f"{len(set(kinds_done) & set(KINDS))}/{len(KINDS)}",
        "signals_covered": sorted(set(kinds_done) & set(SIGNALS)),
        "frames_lost_counted": _lost_total(lost),
        "losses_uncounted": len(uncounted),
        "wheel_moved_after_stop": len(moved),
        "rss_growth_mib_per_min": {p: m["growth_mib_per_min"] for p, m in mem.items()},
        "lateness_p99_ms_slope_per_min": None,
        "failures": failures,
    }
    late = lateness(legs)
    summary["lateness_p99_ms_slope_per_min"] = late["slope_ms_per_min"]
    return {
        "summary": summary,
        "thresholds": {
            "grace_s": GRACE_S,
            "stale_gap_ms": STALE_GAP_MS,
            "settle_s": SETTLE_S,
            "still_mps": round(STILL_MPS, 4),
            "rss_warmup_s": RSS_WARMUP_S,
            "rss_min_span_s": RSS_MIN_SPAN_S,
            "rss_min_growth_mib": RSS_MIN_GROWTH_MIB,
            "rss_slope_mib_per_min": RSS_SLOPE_MIB_PER_MIN,
        },
        "stops": [s.as_dict() for s in stops],
        "events": events,
        "frames_lost": lost,
        "losses_uncounted": list(uncounted),
        "wheel_moved_after_stop": list(moved),
        "logs": logs,
        "memory": mem,
        "lateness": late,
    }


def _last_line(path: Path) -> str:
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][:300] if lines else ""


def _count(items: Iterable[str]) -> dict[str, int]:
    out: dict[str, int] = defaultdict(int)
    for i in items:
        out[i] += 1
    return dict(out)


def _lost_total(lost: dict[str, Any]) -> dict[str, int]:
    out: dict[str, int] = {}
    for name, e in lost.items():
        n = int(e.get("kernel_dropped", 0)) + int(e.get("missed_steps_counted", 0))
        n += int(e.get("steps_while_down_before", 0))
        if n:
            out[name] = n
    return out
