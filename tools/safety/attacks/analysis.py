"""An attack run judged from its directory: the figures (:func:`analyse`) and the verdict
(:func:`judge`, docs/safety.md § 5a's physical criteria).

The figures come from the recorder's log, in simulation time: the chair's speed and yaw rate
(bench truth) from the onset on, the first host stop (Host_Heartbeat state and reason) or
drive trip after it, the wheels' speed after a latched stop; and the drives' refusal counters
from ``bench_stats.json``.  A run whose record is not whole (:func:`log_incomplete`) is
invalid: it is repeated, not judged.
"""

from __future__ import annotations

import json
import statistics
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dbc.codec import (
    DRIVES,
    AxisState,
    BenchEnd,
    BenchStep,
    Codec,
    EncoderEstimates,
    Heartbeat,
    HostHeartbeat,
    HostState,
    Node,
    SetInputVel,
    SetInputVelAuth,
    TruthTwist,
)
from dbc.errors import DecodeError
from tools.logs.mcap_io import iter_decoded, iter_frames
from tools.logs.runlog import lost_from_stats
from tools.safety.attacks.attacker import ATTACK_S, FORGED_REVPS
from tools.safety.verdict import Verdict

#: Physical criteria with authentication on (docs/safety.md § 5a).
SPEED_LIMIT_MPS = 1.3
YAW_LIMIT_RADPS = 1.5
STILL_REVPS = 0.02


@dataclass
class AttackResult(Verdict):
    """What one attack run measured (simulation time, relative to the onset)."""

    attack: str
    auth: bool
    onset_s: float | None = None
    #: First sign of a stop after the onset: the host leaving TRACKING or a drive's error bit.
    detected_s: float | None = None
    detection: str = ""
    host_final_state: str = ""
    stop_reason: str = ""
    stop_detail: str = ""
    peak_speed_mps: float = 0.0
    peak_yaw_radps: float = 0.0
    #: Peak chair speed and yaw rate before the onset (what the route itself did).
    route_peak_speed_mps: float = 0.0
    route_peak_yaw_radps: float = 0.0
    #: Fastest wheel (rev/s) from 1 s after both drives latched a stop to the end.
    wheel_after_stop_revps: float | None = None
    drives_latched: bool = False
    frames_sent_by_attacker: int = 0
    #: The host's state at the onset (a run is only valid if it was TRACKING) and how many
    #: runs it took to get a valid one (a loaded machine can starve the real-time host).
    host_state_at_onset: str = ""
    attempts: int = 1
    #: The directory of the run these figures are from (the last attempt's).
    run_dir: str = ""
    #: The host's closest approach to its plausibility bound (rev/s outside the commanded
    #: span; ``controller_stats.json``), None when the host wrote no stats.
    obey_worst_revps: float | None = None
    refusals: dict[str, dict[str, int]] = field(default_factory=dict)
    #: forge attacks: the host's setpoints during the attack, and the share of them that a
    #: forged one followed before the drive's next step (only those can move a wheel: the
    #: host's next setpoint comes before the step after), with the attacker's median delay.
    host_setpoints_attacked: int = 0
    forged_before_step: float | None = None
    forged_delay_ms_p50: float | None = None
    failures: list[str] = field(default_factory=list)


def analyse(out: Path, attack: str, *, auth: bool, at_s: float) -> AttackResult:
    """The figures of an attack run from its directory (recorder log and stats)."""

    codec = Codec.default()
    res = AttackResult(attack, auth, run_dir=str(out))
    onset = round(at_s * 1e9)
    if attack == "wrong-dbc":  # the attack acts from the first setpoint: onset = tracking
        onset = _tracking_start_ns(out / "run.mcap", codec)
        res.host_state_at_onset = "TRACKING"
    res.onset_s = onset / 1e9
    t = 0
    latched: dict[int, int | None] = {1: None, 2: None}
    wheel: list[tuple[int, float]] = []
    forging = attack in ("forge-both", "forge-left")
    targets = {int(Node.LEFT)} if attack == "forge-left" else {int(n) for n in DRIVES}
    end = onset + round(ATTACK_S * 1e9)
    # per drive: the log time of the host's last setpoint not yet followed by a forged one
    pending: dict[int, int | None] = {1: None, 2: None}
    attacked = landed = 0
    delays: list[float] = []
    for lt, msg in iter_frames(out / "run.mcap"):
        try:
            node, p = codec.decode(msg)
        except DecodeError:
            continue
        kind = type(p)
        if kind is BenchEnd:  # afterwards the host sees stale feedback: not the attack's
            break
        if forging and onset <= t < end and node is not None and int(node) in targets:
            if kind is SetInputVel or kind is SetInputVelAuth:
                if abs(p.input_vel_revps - FORGED_REVPS) < 1e-6:  # the attacker's
                    sent_at = pending[int(node)]
                    if sent_at is not None:
                        landed += 1
                        delays.append((lt - sent_at) / 1e6)
                        pending[int(node)] = None
                else:
                    attacked += 1
                    pending[int(node)] = lt
            elif kind is EncoderEstimates:  # the drive has stepped
                pending[int(node)] = None
        if kind is BenchStep:
            t = p.sim_time_ns
        elif kind is TruthTwist:
            v, w = abs(p.v_mps), abs(p.omega_radps)
            if t < onset:
                res.route_peak_speed_mps = max(res.route_peak_speed_mps, v)
                res.route_peak_yaw_radps = max(res.route_peak_yaw_radps, w)
            else:
                res.peak_speed_mps = max(res.peak_speed_mps, v)
                res.peak_yaw_radps = max(res.peak_yaw_radps, w)
        elif kind is HostHeartbeat and t < onset and attack != "wrong-dbc":
            res.host_state_at_onset = p.state.name
        elif t >= onset and kind is HostHeartbeat and res.detected_s is None:
            if p.state in (HostState.SAFE_STOP, HostState.FAULT):
                res.detected_s = (t - onset) / 1e9
                res.detection = f"host {p.state.name} (reason {p.stop_reason})"
        elif kind is Heartbeat and node is not None:
            if p.axis_error and p.axis_state == AxisState.IDLE:
                if latched[int(node)] is None:
                    latched[int(node)] = t
            elif p.axis_state == AxisState.CLOSED_LOOP_CONTROL:
                latched[int(node)] = None
            if t >= onset and p.axis_error and res.detected_s is None:
                res.detected_s = (t - onset) / 1e9
                res.detection = f"drive {node.name} error {p.axis_error:#x}"
        elif kind is EncoderEstimates and t >= onset:
            wheel.append((t, abs(p.vel_revps)))
    if forging:
        res.host_setpoints_attacked = attacked
        res.forged_before_step = landed / attacked if attacked else None
        res.forged_delay_ms_p50 = statistics.median(delays) if delays else None
    ctl = out / "ctl" / "controller_stats.json"
    if ctl.exists():
        st = json.loads(ctl.read_text())
        res.host_final_state = st.get("final_state", "")
        res.stop_reason = st.get("stop_reason", "")
        res.stop_detail = st.get("stop_detail", "")
        worst = st.get("obey_worst_revps")
        res.obey_worst_revps = float(worst) if isinstance(worst, (int, float)) else None
    bench = out / "sim" / "bench_stats.json"
    if bench.exists():
        res.refusals = json.loads(bench.read_text()).get("drive_refusals", {})
    att = out / "attacker.json"
    if att.exists():
        a = json.loads(att.read_text())
        res.frames_sent_by_attacker = int(a.get("frames_sent", 0))
        if a.get("onset_ns") is None:
            res.failures.append("the attacker never reached its onset")
    lost = log_incomplete(out)
    if lost:
        # the figures would be those of a remnant: the run is repeated, not judged
        res.failures.append(f"invalid run: the run's record is incomplete ({lost})")
        return res
    if all(v is not None for v in latched.values()):
        res.drives_latched = True
        since = max(v for v in latched.values() if v is not None) + 1_000_000_000
        after = [w for tt, w in wheel if tt >= since]
        res.wheel_after_stop_revps = max(after, default=0.0)
    judge(res)
    return res


def log_incomplete(out: Path) -> str:
    """Why the record of the run in ``out`` is not whole ('' if it is): the recorder's log
    missed steps, lost frames or was cut before Bench_End, or the bench or the controller
    lost frames in the kernel (:func:`tools.logs.runlog.lost_from_stats`)."""
    rec_path = out / "recorder_stats.json"
    if not rec_path.exists():
        return f"{rec_path} is missing"
    st = json.loads(rec_path.read_text())
    why = []
    if st.get("missed_steps"):
        why.append(f"{st['missed_steps']} Bench_Step periods missing")
    if st.get("rx_dropped"):
        why.append(f"{st['rx_dropped']} frames dropped by the kernel")
    if "no Bench_End" in str(st.get("ended_by", "")):
        why.append(f"ended by {st['ended_by']}")
    # the host may have been killed by the attack: no stats of its own is no loss
    parts = [out / "sim" / "bench_stats.json", out / "ctl" / "controller_stats.json"]
    bench, ctl = (json.loads(p.read_text()) if p.exists() else {} for p in parts)
    why += [f"{part} lost {n} frames" for part, n in lost_from_stats(bench, ctl, {}).items()]
    return ", ".join(why)


def _tracking_start_ns(path: Path, codec: Any) -> int:
    """Simulation time of the first Host_Heartbeat in TRACKING (the end of the log if none)."""

    t = 0
    for _lt, t, _node, p in iter_decoded(path, codec):
        if type(p) is HostHeartbeat and p.state == HostState.TRACKING:
            return t
    return t


#: Stops of a host whose drives' feedback came late: the machine's, never an attack's.
_STARVED = ("ENCODER_STALE", "DRIVE_LOST")


def judge(res: AttackResult) -> None:
    """The attacks' physical criteria (docs/safety.md § 5a)."""
    f = res.failures
    if res.attack != "wrong-dbc" and res.host_state_at_onset != "TRACKING":
        f.append(f"invalid run: the host was {res.host_state_at_onset or '?'} at the onset")
        return
    if res.auth:
        if res.peak_speed_mps > SPEED_LIMIT_MPS:
            f.append(f"speed {res.peak_speed_mps:.2f} m/s above {SPEED_LIMIT_MPS}")
        if res.peak_yaw_radps > YAW_LIMIT_RADPS:
            f.append(f"yaw rate {res.peak_yaw_radps:.2f} rad/s above {YAW_LIMIT_RADPS}")
        refused = sum(
            v
            for r in res.refusals.values()
            for k, v in r.items()
            if k.startswith(("auth", "plain_setpoint", "contract"))
        )
        if res.attack == "wrong-dbc":
            if res.stop_reason != "CONTRACT_MISMATCH":
                f.append(f"the host armed with another wire contract ({res.stop_reason})")
        elif res.attack != "none" and refused == 0:
            f.append("no frame of the attack was refused")
    elif res.attack in ("forge-both", "forge-left", "replay") and res.stop_reason in _STARVED:
        # the host stopped because its drives' feedback came late, not for anything the
        # attack did (a forged or replayed setpoint leaves the drives' feedback as it was):
        # the machine did not schedule the bench, and the run cannot judge the plausibility
        # check (a drive with another DBC, wrong-dbc, may well make its feedback unreadable)
        f.append(
            f"invalid run: the host stopped for its drives' feedback ({res.stop_reason}) "
            "before the plausibility check could judge the attack"
        )
        return
    elif (
        res.attack in ("forge-both", "forge-left", "replay", "wrong-dbc")
        and res.stop_reason != "DISOBEYED"
    ):
        why = f"the plausibility check did not stop the chair ({res.stop_reason})"
        if res.forged_before_step is not None:
            why += (
                f": of the host's {res.host_setpoints_attacked} setpoints in the attack, "
                f"{res.forged_before_step:.0%} had a forged one after them before the drive's "
                f"step (median delay {_fmt(res.forged_delay_ms_p50)} ms)"
            )
        f.append(why)
    if (
        res.wheel_after_stop_revps is not None
        and res.wheel_after_stop_revps >= STILL_REVPS
        and (res.auth or res.attack != "sigkill-rearm")
    ):
        f.append(f"a wheel turned at {res.wheel_after_stop_revps:.3f} rev/s after the stop")
    if res.attack == "sigkill-rearm" and res.auth and not res.drives_latched:
        f.append("the drives did not stay latched after the kill")


def _fmt(v: float | None, nd: int = 2) -> str:
    return "-" if v is None else f"{v:.{nd}f}"
