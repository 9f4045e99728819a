"""The safety suite's criteria: one case run reduced to its figures and checked.

:func:`analyse` derives from a :class:`~tools.safety.runner.RunOutput` the detection time,
stop start, stop time, stop distance, ``|wL - wR|`` and the heading during the stop and the
no-resume check, and checks them against the criteria of docs/safety.md
(:class:`CaseResult.failures`); :func:`evaluate` runs a case and judges it, against the cached
fault-free run where the case compares with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dbc.codec import AxisError, HostState
from tools.safety.cases import NO_MOTION, PERIOD_S, RIDE, SAFE, SAME, STOP, SafetyCase
from tools.safety.runner import RunOutput, run_case
from tools.safety.verdict import Verdict

#: Rim deceleration of every coordinated stop (drive Stop_Decel and host safe stop), m/s^2.
A_STOP_MPS2 = 1.0
#: A wheel whose rim moves slower than this is at standstill (m/s).
STANDSTILL_MPS = 0.01


def standstill_limit_s(watchdog_s: float, v0_mps: float, stop_ref_mps: float) -> float:
    """How long after the last setpoint the wheels of drives left without setpoints may take
    to stand still: the drives' watchdog, then the coordinated stop at :data:`A_STOP_MPS2`
    from the larger of the measured rim speed ``v0_mps`` and the stop reference the host sent
    with its last setpoint (the drive ramps down from that, docs/safety.md), and five periods
    for the drive loop, the wheels' lag behind the ramp and the feedback's sampling."""
    return watchdog_s + max(v0_mps, stop_ref_mps) / A_STOP_MPS2 + 5 * PERIOD_S


#: "Without yaw" (docs/safety.md): during the stop |wL - wR| may exceed the curvature-keeping
#: profile (shrinking in proportion to the speed) by at most this (rad/s: 3 cm/s of rim speed),
YAW_TOL_RADPS = 0.1
#: and the heading may differ from that of the curvature-keeping stop by at most this (deg).
HEADING_TOL_DEG = 1.0
#: A ride-through case may leave the chair at most this far from the fault-free run (m).
RIDE_THROUGH_TOL_M = 0.05

#: The fault-free reference run every ride-through and unaffected case is compared with.
BASELINE = SafetyCase("fault-free", "no fault", RIDE, "-")

_BITS = {
    AxisError.WATCHDOG_TIMER_EXPIRED: "WATCHDOG_TIMER_EXPIRED",
    AxisError.MISSING_INPUT: "MISSING_INPUT",
    AxisError.ESTOP_REQUESTED: "ESTOP_REQUESTED",
}


def _bits(err: int) -> str:
    names = [n for b, n in _BITS.items() if err & b]
    return "+".join(names) if names else f"{err:#x}"


@dataclass
class CaseResult(Verdict):
    """The figures of one case against its criteria (JSON-friendly)."""

    name: str
    fault: str
    expect: str
    detector_expected: str
    detector: str = "-"
    detection_s: float | None = None
    detection_limit_s: float | None = None
    #: when the stop took effect at the wheels (a drive's ramp or brake, the host's ramp)
    stop_start_s: float | None = None
    stop_time_s: float | None = None
    v0_mps: float = 0.0
    stop_distance_m: float | None = None
    stop_distance_limit_m: float | None = None
    dw_at_detection_radps: float | None = None
    dw_max_radps: float | None = None
    #: largest excess of |wL - wR| over the curvature-keeping profile, and its limit
    dw_excess_radps: float | None = None
    dw_limit_radps: float | None = None
    #: heading change during the stop minus that of the curvature-keeping stop (degrees)
    heading_deviation_deg: float | None = None
    reported_in_heartbeat_s: float | None = None
    no_resume: bool | None = None
    max_speed_mps: float = 0.0
    deviation_m: float | None = None
    rejected: dict[str, int] = field(default_factory=dict)
    effects: dict[str, int] = field(default_factory=dict)
    exceptions: list[str] = field(default_factory=list)
    final_state: str = ""
    stop_reason: str = ""
    wall_s: float = 0.0
    failures: list[str] = field(default_factory=list)
    note: str = ""


def _rejections(out: RunOutput) -> dict[str, int]:
    rej: dict[str, int] = {}
    for where, table in (
        ("bench", out.bench_rejected),
        ("drives", out.drive_ignored),
        ("host", out.host_rejected),
    ):
        for reason, n in sorted(table.items()):
            if n and reason not in ("not_a_command",):
                rej[f"{where}:{reason}"] = int(n)
    return rej


def analyse(out: RunOutput, baseline: RunOutput | None = None) -> CaseResult:
    """Reduce one run to its figures and check them against the case's criteria."""
    case = out.case
    tr = out.trace
    res = CaseResult(
        case.name,
        case.fault,
        case.expect,
        case.detector,
        rejected=_rejections(out),
        effects={k: int(v) for k, v in sorted(out.bench_effects.items()) if v},
        final_state=out.final_state,
        stop_reason=out.stop_reason,
        wall_s=round(out.wall_s, 2),
        note=case.note,
    )
    fail = res.failures
    exc = list(out.thread_errors)
    if out.host_exceptions:
        exc.append(f"controller tick exceptions: {out.host_exceptions}")
    for where, table in (("bench", out.bench_rejected), ("host", out.host_rejected)):
        for reason in ("internal", "handler_error"):
            if table.get(reason):
                exc.append(f"{where} receive path failed {table[reason]} times ({reason})")
    res.exceptions = exc
    if exc:
        fail.append("exception out of a receive path or thread: " + "; ".join(exc))
    for key in case.must_reject:
        if not res.rejected.get(key):
            fail.append(f"expected rejections {key!r} did not occur")
    if not tr.t_ns:
        fail.append("no simulation samples")
        return res
    t = np.asarray(tr.t_ns, dtype=np.int64)
    w = np.asarray(tr.w, dtype=float)
    r = np.asarray(tr.r, dtype=float)
    rim = np.abs(w) * r
    vmax = rim.max(axis=1)
    stopping = np.asarray(tr.stopping, dtype=bool)
    armed = np.asarray(tr.armed, dtype=bool)
    errors = np.asarray(tr.errors, dtype=np.int64)
    feed = np.asarray(tr.feed_ns, dtype=np.int64)
    onset_ns = round(case.onset_s * 1e9)
    i0 = int(np.searchsorted(t, onset_ns))
    res.v0_mps = round(float(vmax[min(i0, len(t) - 1)]), 4)
    res.max_speed_mps = round(float(vmax[i0:].max()) if i0 < len(t) else 0.0, 4)
    dt_s = (t[1] - t[0]) * 1e-9 if len(t) > 1 else 1e-3
    ht = np.asarray(tr.host_t_ns, dtype=np.int64)
    hs = np.asarray(tr.host_state, dtype=int)
    # ---- reactions after the onset: who detected first, and when the stop took effect
    events: list[tuple[int, str]] = []  # detections
    starts: list[int] = []  # a stop in effect at the wheels
    after = np.flatnonzero(stopping[i0:].any(axis=1))
    if after.size:
        i = i0 + int(after[0])
        side = "drives" if stopping[i].all() else ("left" if stopping[i, 0] else "right")
        err = int(errors[i, 0] if stopping[i, 0] else errors[i, 1])
        label = f"drives: {_bits(err)}" if side == "drives" else f"drive {side}: {_bits(err)}"
        events.append((int(t[i]), label))
        starts.append(int(t[i]))
    stop_states = (int(HostState.SAFE_STOP), int(HostState.FAULT))
    hidx = np.flatnonzero((ht >= onset_ns) & np.isin(hs, stop_states))
    if hidx.size:
        t_host = int(ht[hidx[0]])
        events.append((t_host, f"host: {tr.host_reason[int(hidx[0])]}"))
        holding = np.asarray(tr.host_holding, dtype=bool)
        ramp = hidx[~holding[hidx]]  # ticks in SAFE_STOP/FAULT past any hold
        if ramp.size:
            t_ramp = int(ht[ramp[0]])
            j0 = int(np.searchsorted(t, t_ramp))
            was_armed = armed[min(i0, len(t) - 1)]
            took = (feed[j0:] >= t_ramp).any(axis=1) | (
                (~armed[j0:] & was_armed).any(axis=1) & ~stopping[j0:].any(axis=1)
            )
            k = np.flatnonzero(took)
            if k.size:
                starts.append(int(t[j0 + int(k[0])]))
    hb = [t_hb for t_hb, _n, err in out.drive_heartbeats if t_hb >= onset_ns and err]
    if hb:
        res.reported_in_heartbeat_s = round((min(hb) - onset_ns) * 1e-9, 3)
    t_eff = min(events)[0] if events else None
    t_start = min(starts) if starts else None
    if t_eff is not None:
        res.detector = min(events)[1]
        res.detection_s = round((t_eff - onset_ns) * 1e-9, 4)
    if t_start is not None:
        res.stop_start_s = round((t_start - onset_ns) * 1e-9, 4)
    # ---- standstill to the end
    moving = np.flatnonzero(vmax >= STANDSTILL_MPS)
    j_still = int(moving[-1]) + 1 if moving.size else 0
    still_to_end = j_still < len(t)
    observed_still_s = (t[-1] - t[j_still]) * 1e-9 if still_to_end else 0.0
    base_dev = None
    if baseline is not None and case.expect in (RIDE, SAME):
        bx, by = baseline.truth_xy
        base_dev = math.hypot(out.truth_xy[0] - bx, out.truth_xy[1] - by)
        res.deviation_m = round(base_dev, 4)

    if case.expect == STOP or (case.expect == SAFE and t_eff is not None):
        limit = case.budget_s + 2 * PERIOD_S + 1e-9
        if case.expect == STOP:
            res.detection_limit_s = round(limit, 3)
        if t_eff is None or t_start is None:
            fail.append("no stop happened" if t_eff is None else "the stop never took effect")
            return res
        if case.expect == STOP and res.detection_s is not None and res.detection_s > limit:
            fail.append(f"detection {res.detection_s:.3f} s > N*T + 2T = {limit:.3f} s")
        if not still_to_end or j_still < i0:
            fail.append("the wheels did not come to a standstill")
            return res
        res.stop_time_s = round((t[j_still] - onset_ns) * 1e-9, 3)
        dist = float((rim[i0:j_still].sum(axis=0) * dt_s).max()) if j_still > i0 else 0.0
        det = (t_start - onset_ns) * 1e-9
        # v0: the fastest rim speed from the onset until the stop takes effect (the formula
        # assumes the chair keeps its speed until then; in a curve the outer wheel may speed
        # up meanwhile); t_det: when the stop took effect at the wheels
        ie0 = int(np.searchsorted(t, t_start))
        v0 = float(vmax[i0 : ie0 + 1].max())
        res.v0_mps = round(v0, 4)
        bound = 1.05 * (v0 * det + v0 * v0 / (2.0 * A_STOP_MPS2))
        res.stop_distance_m = round(dist, 4)
        res.stop_distance_limit_m = round(bound, 4)
        if dist > bound + 1e-4:
            fail.append(f"stop distance {dist:.3f} m > {bound:.3f} m")
        ie = int(np.searchsorted(t, t_start))
        dw = np.abs(w[:, 0] - w[:, 1])
        seg = slice(ie, max(j_still, ie + 1))
        res.dw_at_detection_radps = round(float(dw[ie]), 3)
        res.dw_max_radps = round(float(dw[seg].max()), 3)
        res.dw_excess_radps = round(yaw_excess(dw[seg], vmax[seg]), 3)
        yaw_rate = (w[:, 1] * r[:, 1] - w[:, 0] * r[:, 0]) / (2.0 * out.half_track_m)
        res.heading_deviation_deg = round(
            math.degrees(heading_deviation(yaw_rate[seg], vmax[seg], dt_s)), 2
        )
        if case.yaw_free:
            res.dw_limit_radps = YAW_TOL_RADPS
            if res.dw_excess_radps > YAW_TOL_RADPS:
                fail.append(
                    f"|wL - wR| exceeded the curvature-keeping profile by "
                    f"{res.dw_excess_radps:.3f} rad/s during the stop (> {YAW_TOL_RADPS})"
                )
            if abs(res.heading_deviation_deg) > HEADING_TOL_DEG:
                fail.append(
                    f"the heading left the arc by {res.heading_deviation_deg:.2f} deg during "
                    f"the stop (> {HEADING_TOL_DEG})"
                )
        if (
            case.expect == STOP
            and res.detector.startswith("drive")
            and not case.bus_blocked
            and (
                res.reported_in_heartbeat_s is None
                or res.reported_in_heartbeat_s > det + 2 * PERIOD_S + 1e-9
            )
        ):
            fail.append(
                f"the drive's error reached the bus at +{res.reported_in_heartbeat_s} s, "
                f"more than 2T after the trip (+{res.detection_s} s)"
            )
        res.no_resume, why = _no_resume(out, t, armed, int(t_eff))
        if not res.no_resume:
            fail.append(f"resumed: {why}")
        if observed_still_s < 1.0:
            fail.append(f"standstill observed only {observed_still_s:.2f} s before the end")
    elif case.expect == NO_MOTION:
        if res.max_speed_mps >= STANDSTILL_MPS:
            fail.append(f"the chair moved: {res.max_speed_mps:.3f} m/s")
        res.no_resume, why = _no_resume(out, t, armed, onset_ns)
        if not res.no_resume:
            fail.append(f"resumed: {why}")
        if t_eff is not None:
            res.detector = min(events)[1]
    elif case.expect in (RIDE, SAME):
        if t_eff is not None:
            fail.append(f"unexpected stop: {res.detector} at +{res.detection_s} s")
        if out.final_state != "TRACKING":
            fail.append(f"host ended in {out.final_state} ({out.stop_reason})")
        if float(vmax[-1]) < 0.1:
            fail.append("the chair is not moving at the end of the run")
        if base_dev is not None:
            tol = 0.0 if case.expect == SAME else RIDE_THROUGH_TOL_M
            if base_dev > tol + 1e-12:
                fail.append(f"{base_dev:.4f} m from the fault-free run (> {tol} m)")
        if case.expect == SAME and baseline is not None and tr.host_cmd != baseline.trace.host_cmd:
            fail.append("the controller's commands differ from the fault-free run")
    elif case.expect == SAFE and t_eff is None and out.final_state != "TRACKING":
        fail.append(f"host ended in {out.final_state} without a stop at the wheels")
    return res


def yaw_excess(dw: np.ndarray, v: np.ndarray) -> float:
    """Largest excess of ``|wL - wR|`` over the curvature-keeping stop (rad/s).

    Keeping the curvature means both wheels shrink by the same factor, so the difference
    falls in proportion to the speed: ``dw(t) = dw(0) v(t) / v(0)``.  Equal decelerations
    keep ``dw`` constant instead while the chair slows: it turns onto a tighter arc.
    """
    if dw.size == 0 or v[0] <= 0.0:
        return 0.0
    return float(max(0.0, (dw - dw[0] * v / v[0]).max()))


def heading_deviation(yaw_rate: np.ndarray, v: np.ndarray, dt_s: float) -> float:
    """Heading change during the stop minus that of the curvature-keeping stop (rad)."""
    if yaw_rate.size == 0 or v[0] <= 0.0:
        return 0.0
    return float(((yaw_rate - yaw_rate[0] * v / v[0]) * dt_s).sum())


def _no_resume(out: RunOutput, t: np.ndarray, armed: np.ndarray, t0_ns: int) -> tuple[bool, str]:
    """Both drives disarmed after ``t0_ns`` and never armed again; a live host in FAULT."""
    i0 = int(np.searchsorted(t, t0_ns))
    both_off = np.flatnonzero(~armed[i0:].any(axis=1))
    if not both_off.size:
        return False, "the drives never both disarmed"
    k = i0 + int(both_off[0])
    if armed[k:].any():
        return (
            False,
            f"a drive re-armed at {t[k + int(np.flatnonzero(armed[k:].any(axis=1))[0])] * 1e-9:.3f} s",
        )
    dead = out.case.host_fault is not None and out.case.host_fault.kind in ("kill", "freeze-repeat")
    if not dead and out.final_state != "FAULT":
        return False, f"the host ended in {out.final_state}, not FAULT"
    return True, ""


_baseline_cache: dict[tuple[str, str, int], RunOutput] = {}


def baseline_run(scenario: str = "short", controller: str = "baseline", seed: int = 1) -> RunOutput:
    """The fault-free run (cached per process)."""
    key = (scenario, controller, seed)
    if key not in _baseline_cache:
        _baseline_cache[key] = run_case(
            BASELINE, scenario=scenario, controller=controller, seed=seed
        )
    return _baseline_cache[key]


def evaluate(case: SafetyCase, **kw: Any) -> CaseResult:
    """Run ``case`` (and the cached fault-free run when the case compares with it)."""
    base = baseline_run(**kw) if case.expect in (RIDE, SAME) else None
    return analyse(run_case(case, **kw), base)
