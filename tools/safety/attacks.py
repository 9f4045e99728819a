"""The attacks of docs/safety.md § 5a on a real-time run across processes, and their measured outcomes.

A third process on the run's private udp_multicast namespace (:func:`attacker_main`, started
by :func:`run_attack` next to bench, controller and recorder) does what a node without the
key can do:

* ``forge-both`` / ``forge-left``: right after each of the host's setpoints to a drive, a
  setpoint of 0.907 rev/s (1.71 m/s) of its own, with the host's live freshness + 1 (with
  authentication: and a made-up MAC; without: a plain Set_Input_Vel);
* ``replay``: the host's own setpoint frames from 7 s earlier, replayed in order after each
  live frame, once unchanged and once with the freshness byte re-synced to the live value;
* ``sigkill-rearm``: the controller is killed; 1 s later, for 3 s, every re-arm sequence:
  Clear_Errors, Set_Watchdog with every protection off, Set_Limits, Set_Axis_State
  (CLOSED_LOOP), forged Host_Heartbeats, plain and forged-authenticated setpoints of 0.907
  rev/s; then an Estop;
* ``wrong-dbc``: no third process; the controller is given a DBC whose left Input_Vel has
  factor 2 (``--dbc``).

The figures come from the recorder's log, in simulation time: the chair's speed and yaw rate
(bench truth) from the onset on, the first host stop (Host_Heartbeat state and reason) or
drive trip after it, the wheels' speed after a latched stop; and the drives' refusal counters
from ``bench_stats.json``.  ``wheelchair-hil attack`` prints them.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import signal
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controller.clock import try_realtime
from dbc.codec import (
    DBC_PATH,
    DRIVES,
    AxisState,
    BenchEnd,
    BenchStep,
    ClearErrors,
    Codec,
    EncoderEstimates,
    Estop,
    Heartbeat,
    HostHeartbeat,
    HostState,
    Node,
    SetAxisState,
    SetInputVel,
    SetInputVelAuth,
    SetLimits,
    SetWatchdog,
    TruthTwist,
)
from dbc.errors import DecodeError
from dbc.secoc import MAC_BITS, SETPOINT_FV_BITS, Authenticator, Verifier, load_key
from firmware_sim.config import default_config
from tools.bus import transport
from tools.logs.mcap_io import iter_decoded, iter_frames
from tools.logs.runlog import lost_from_stats
from tools.run import scenario as scenario_mod
from tools.run.processes import (
    Part,
    PartFailedError,
    SandboxedParts,
    realtime_parts,
    rt_option,
    signal_part,
)
from tools.safety.verdict import Verdict

ATTACKS: tuple[str, ...] = ("forge-both", "forge-left", "replay", "sigkill-rearm", "wrong-dbc")
#: The forged wheel speed of the issue's attacks (rev/s; 1.71 m/s at the 0.30 m rim).
FORGED_REVPS = 0.907
#: Physical criteria with authentication on (docs/safety.md § 5a).
SPEED_LIMIT_MPS = 1.3
YAW_LIMIT_RADPS = 1.5
STILL_REVPS = 0.02
ATTACK_S = 3.5


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


# ----------------------------------------------------------------- the attacker


def attacker_main(argv: list[str]) -> int:
    """The third process: ``python -m tools.safety.attacks attacker --attack X ...``."""

    ap = argparse.ArgumentParser(prog="attacker")
    ap.add_argument("--attack", required=True, choices=ATTACKS)
    ap.add_argument("--at", type=float, required=True, help="onset, simulated s")
    ap.add_argument("--auth", choices=("on", "off"), required=True)
    ap.add_argument("--kill-pid-file", default=None)
    ap.add_argument("--out", required=True)
    ap.add_argument("--bus", default="udp_multicast", help="python-can interface of the run")
    ap.add_argument("--channel", default=None, help="its channel (default: the interface's)")
    ap.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority once started (0: none), as another node's own hardware has",
    )
    args = ap.parse_args(argv)
    codec = Codec.default()
    rng = random.Random(16)
    bus = transport.open_bus(transport.resolve(args.bus, args.channel))
    # A node on the bus reacts in its own hardware's time.  A forged setpoint moves a wheel
    # only if it reaches the drive between the host's setpoint and the drive's step, 1.5 ms
    # later; at normal priority on a loaded machine it came 1-5 ms late, and the unauthenticated
    # forge runs ended with no DISOBEYED.  (Its priority is below the controller's: level with
    # it or above it, two attack runs side by side starved a host at the onset.)
    rt_notes = try_realtime(args.rt_priority) if args.rt_priority > 0 else []
    onset_ns = round(args.at * 1e9)
    end_ns = onset_ns + round(ATTACK_S * 1e9)
    sp_ids = {codec.frame_id(SetInputVelAuth, n): n for n in DRIVES}
    sp_ids.update({codec.frame_id(SetInputVel, n): n for n in DRIVES})
    recorded: dict[Node, list[tuple[int, Any]]] = {n: [] for n in DRIVES}
    replay_pos = {n: 0 for n in DRIVES}
    sent = 0
    t_ns = 0
    killed = False
    stopped = False
    hb = 0
    info: dict[str, Any] = {"onset_ns": None, "realtime_notes": rt_notes}

    def send(payload: Any, node: Node | None) -> None:
        nonlocal sent
        try:
            bus.send(codec.encode(payload, node))
            sent += 1
        except Exception:  # the attacker's own trouble must not end the run
            pass

    def send_raw(msg: Any) -> None:
        nonlocal sent
        try:
            bus.send(msg)
            sent += 1
        except Exception:
            pass

    try:
        while True:
            msg = bus.recv(0.5)
            if msg is None:
                continue
            try:
                _node, p = codec.decode(msg)
            except DecodeError:
                continue
            kind = type(p)
            if kind is BenchEnd:
                break
            if kind is BenchStep:
                t_ns = p.sim_time_ns
                if t_ns >= onset_ns and info["onset_ns"] is None:
                    info["onset_ns"] = t_ns
                if args.attack == "sigkill-rearm" and t_ns >= onset_ns:
                    if not killed and args.kill_pid_file:
                        killed = True
                        info["killed"] = _kill_controller(Path(args.kill_pid_file))
                    if onset_ns + 1_000_000_000 <= t_ns < end_ns + 1_000_000_000:
                        hb = (hb + 1) & 0xFF
                        send(HostHeartbeat(HostState.TRACKING, hb), Node.HOST)
                        for n in DRIVES:
                            send(ClearErrors(), n)
                            send(SetWatchdog(0, 0.0, False, 0, False), n)
                            send(SetLimits(20.0, 60.0), n)
                            send(SetAxisState(AxisState.CLOSED_LOOP_CONTROL), n)
                            send(SetInputVel(FORGED_REVPS, 0.0), n)
                            fv = rng.randrange(256)
                            send(SetInputVelAuth(FORGED_REVPS, 0.91, fv, rng.getrandbits(32)), n)
                    elif t_ns >= end_ns + 1_000_000_000 and not stopped:
                        stopped = True
                        for n in DRIVES:
                            send(Estop(), n)
                continue
            target = sp_ids.get(msg.arbitration_id) if not msg.is_extended_id else None
            if target is None:
                continue
            n = target
            # one of the host's setpoints to drive n
            if args.attack == "replay" and onset_ns - 7e9 <= t_ns < onset_ns - 7e9 + ATTACK_S * 1e9:
                recorded[n].append((t_ns, msg))
            if not onset_ns <= t_ns < end_ns:
                continue
            if args.attack in ("forge-both", "forge-left"):
                if args.attack == "forge-left" and n != Node.LEFT:
                    continue
                if kind is SetInputVelAuth:
                    fv = (p.freshness + 1) & 0xFF
                    send(SetInputVelAuth(FORGED_REVPS, 0.91, fv, rng.getrandbits(32)), n)
                else:
                    send(SetInputVel(FORGED_REVPS, 0.0), n)
            elif args.attack == "replay":
                rec = recorded[n]
                k = replay_pos[n]
                if k < len(rec):
                    replay_pos[n] = k + 1
                    old = rec[k][1]
                    send_raw(old)
                    if kind is SetInputVelAuth:
                        data = bytearray(old.data)
                        data[3] = (p.freshness + 1) & 0xFF  # re-synced to the live value
                        send_raw(
                            type(old)(
                                arbitration_id=old.arbitration_id, data=data, is_extended_id=False
                            )
                        )
    finally:
        bus.shutdown()
        info["frames_sent"] = sent
        info["recorded"] = {n.name: len(v) for n, v in recorded.items()}
        Path(args.out).write_text(json.dumps(info))
    return 0


def attacker_part(
    out: Path,
    attack: str,
    at_s: float,
    *,
    auth: bool,
    rt_priority: int = 0,
    bus: Sequence[str] = (),
) -> Part:
    """The attacking node as part ``attacker`` of a run in ``out`` (its figures in
    ``out/attacker.json``; ``sigkill-rearm`` kills the part whose PID is in
    ``out/control.pid``); ``bus``: its ``--bus``/``--channel`` (default udp_multicast)."""
    argv = (
        *(sys.executable, "-m", "tools.safety.attacks", "attacker", "--attack", attack),
        *("--at", f"{at_s}", "--auth", "on" if auth else "off"),
        *("--kill-pid-file", f"{out}/control.pid", "--out", f"{out}/attacker.json"),
        *rt_option("attacker", rt_priority),
        *bus,
    )
    return Part("attacker", argv, f"{out}/attacker.err", ready=False, out=f"{out}/attacker.out")


def _kill_controller(pid_file: Path) -> bool:
    """SIGKILL our ``control`` part (its command line checked first: never a recycled PID)."""
    try:
        pid = int(pid_file.read_text())
    except (OSError, ValueError):
        return False
    return signal_part(pid, signal.SIGKILL, b"tools.cli", b"control")


# ------------------------------------------------------------------ one run


def write_configs(out: Path, auth: bool, scenario: str) -> tuple[Path, Path]:
    """The controller's TOML and a scenario with the drives' power-on authentication."""

    scen = scenario_mod.load(scenario)
    ctl = out / "controller.toml"
    ctl.write_text(
        "# attack run (docs/safety.md 5a)\n[drives]\n"
        f"require_auth = {'true' if auth else 'false'}\n"
        "[auth]\n"
        f"check_contract = {'true' if auth else 'false'}\n"
    )
    text = Path(scen.path).read_text()
    bench = (
        "\n[bench]\n"
        f'"drive.require_auth" = {"true" if auth else "false"}\n'
        f'"drive.check_contract" = {"true" if auth else "false"}\n'
    )
    if "[bench]" in text:
        raise ValueError(f"{scen.path}: attack runs add their own [bench] table")
    scen_path = out / f"{scen.path.stem}-attack.toml"
    route = f'route = "{(Path(scen.route_path)).resolve()}"'
    lines = [route if ln.strip().startswith("route") else ln for ln in text.splitlines()]
    scen_path.write_text("\n".join(lines) + bench)
    return ctl, scen_path


def _wrong_dbc(out: Path, auth: bool) -> Path:
    """The project's DBC with the left wheel's Input_Vel factor doubled."""

    text = DBC_PATH.read_text()
    if auth:
        old = ' SG_ Input_Vel : 0|16@1- (0.0001,0) [-3.2767|3.2767] "rev/s" Drive_Left'
        new = ' SG_ Input_Vel : 0|16@1- (0.0002,0) [-3.2767|3.2767] "rev/s" Drive_Left'
    else:
        old = ' SG_ Input_Vel : 0|32@1- (1,0) [-20|20] "rev/s" Drive_Left'
        new = ' SG_ Input_Vel : 0|32@1- (2,0) [-20|20] "rev/s" Drive_Left'
    if old not in text:
        raise ValueError(f"{DBC_PATH}: no {old.strip()!r} to edit")
    path = out / "wrong-factor.dbc"
    path.write_text(text.replace(old, new, 1))
    return path


def run_attack(
    out: Path,
    attack: str,
    *,
    auth: bool,
    scenario: str = "fault-free",
    controller: str = "antifragile",
    at_s: float = 8.0,
    duration_s: float = 16.0,
    attempts: int = 3,
    rt_priority: int = 0,
) -> AttackResult:
    """One real-time run over udp_multicast in a private namespace with ``attack``; repeated
    (up to ``attempts`` times) while the run is invalid: the host was not tracking at the
    onset, or stopped for its drives' late feedback before the attack could be judged.

    ``rt_priority`` > 0: the controller runs on SCHED_FIFO at that priority and the bench, which
    stands in for the drives' own hardware, one above it, as ``run --rt-priority`` does."""
    for k in range(attempts):
        res = _run_once(
            out / f"try{k}",
            attack,
            auth=auth,
            scenario=scenario,
            controller=controller,
            at_s=at_s,
            duration_s=duration_s,
            rt_priority=rt_priority,
        )
        res.attempts = k + 1
        if not res.failures or not res.failures[0].startswith("invalid run"):
            break
    return res


def _run_once(
    out: Path,
    attack: str,
    *,
    auth: bool,
    scenario: str,
    controller: str,
    at_s: float,
    duration_s: float,
    rt_priority: int = 0,
) -> AttackResult:

    if attack not in (*ATTACKS, "none"):
        raise ValueError(f"unknown attack {attack!r}: choose one of {', '.join(ATTACKS)}")
    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    ctl_cfg, scen = write_configs(out, auth, scenario)
    dbc = ("--dbc", str(_wrong_dbc(out, auth))) if attack == "wrong-dbc" else ()
    attacker: list[Part] = []
    if attack not in ("wrong-dbc", "none"):
        attacker.append(attacker_part(out, attack, at_s, auth=auth, rt_priority=rt_priority))
    parts = realtime_parts(
        out,
        str(scen),
        duration_s,
        control=("--controller", controller, "--config", str(ctl_cfg), *dbc),
        rt_priority=rt_priority,
        others=attacker,
    )
    timeout_s = duration_s * 4 + 90
    try:
        with SandboxedParts(parts, out, timeout_s=timeout_s) as run:
            run.wait()
    except subprocess.TimeoutExpired:
        # a starved machine: a part that never started (the run is invalid, not failed)
        res = AttackResult(attack, auth)
        res.failures.append(f"invalid run: the processes did not finish in {timeout_s:g} s")
        return res
    except PartFailedError as err:
        raise RuntimeError(f"attack run failed: {err}") from err
    return analyse(out, attack, auth=auth, at_s=at_s)


# ----------------------------------------------------------------- the figures


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
    lost = _log_incomplete(out)
    if lost:
        # the figures would be those of a remnant: the run is repeated, not judged
        res.failures.append(f"invalid run: the run's record is incomplete ({lost})")
        return res
    if all(v is not None for v in latched.values()):
        res.drives_latched = True
        since = max(v for v in latched.values() if v is not None) + 1_000_000_000
        after = [w for tt, w in wheel if tt >= since]
        res.wheel_after_stop_revps = max(after, default=0.0)
    _judge(res)
    return res


def _log_incomplete(out: Path) -> str:
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


def _judge(res: AttackResult) -> None:
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


# ------------------------------------------------------------- cost per tick


def auth_cost(n: int = 20000) -> dict[str, float]:
    """Median cost (us) of one tick's authentication: host side (two secured setpoints
    against two plain-encoded ones) and drive side (one setpoint's MAC check), measured on
    the codec and the SecOC code the stack runs."""

    codec = Codec.default()
    key = load_key(default_config().key_path)
    auth = Authenticator(key)
    ver = Verifier(key)
    sp = SetInputVelAuth(0.5, 0.6)
    plain: list[float] = []
    secured: list[float] = []
    verify: list[float] = []
    clock = time.perf_counter_ns
    for _ in range(n):
        t0 = clock()
        codec.encode(SetInputVelAuth(0.5, 0.6, 1, 0), Node.LEFT)
        codec.encode(SetInputVelAuth(0.5, 0.6, 1, 0), Node.RIGHT)
        t1 = clock()
        (m,) = codec.encode_secured(sp, Node.LEFT, auth)
        codec.encode_secured(sp, Node.RIGHT, auth)
        t2 = clock()
        p = codec.decode(m).payload
        t3 = clock()
        ok = ver.verify(m.arbitration_id, m.data[:4], p.freshness, SETPOINT_FV_BITS, p.mac)
        t4 = clock()
        if ok:
            raise RuntimeError(f"a genuine setpoint failed verification: {ok}")
        plain.append((t1 - t0) / 1e3)
        secured.append((t2 - t1) / 1e3)
        verify.append((t4 - t3) / 1e3)
    med = statistics.median
    return {
        "mac_bits": float(MAC_BITS),
        "host_encode_plain_us_per_tick": med(plain),
        "host_encode_secured_us_per_tick": med(secured),
        "host_auth_us_per_tick": med(secured) - med(plain),
        "drive_verify_us_per_frame": med(verify),
    }


# ------------------------------------------------------------------------ CLI


def _fmt(v: float | None, nd: int = 2) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def run(args: argparse.Namespace, argv: list[str]) -> int:
    cost = auth_cost()
    print(
        f"MAC {cost['mac_bits']:.0f} bits (HMAC-SHA256 truncated); per tick: host "
        f"{cost['host_auth_us_per_tick']:.1f} us more for its two setpoints "
        f"({cost['host_encode_secured_us_per_tick']:.1f} us secured against "
        f"{cost['host_encode_plain_us_per_tick']:.1f} us plain), drive "
        f"{cost['drive_verify_us_per_frame']:.1f} us to check its setpoint (medians)"
    )
    if args.cost:
        return 0
    out = Path(args.out)
    modes = {"on": [True], "off": [False], "both": [True, False]}[args.auth]
    if args.false_alarms:
        return _false_alarms(args, out, modes)
    results = []
    for attack in args.attack or ATTACKS:
        for auth in modes:
            d = out / f"{attack}-auth-{'on' if auth else 'off'}"
            res = run_attack(
                d,
                attack,
                auth=auth,
                scenario=args.scenario,
                controller=args.controller,
                at_s=args.at,
                duration_s=args.duration,
                rt_priority=args.rt_priority,
            )
            results.append(res)
            print(_line(res), flush=True)
    (out / "attacks.json").write_text(json.dumps([r.as_dict() for r in results], indent=2))
    if args.json:
        print(json.dumps([r.as_dict() for r in results], indent=2))
    return 0 if all(r.passed for r in results) else 1


def _line(r: AttackResult) -> str:
    refused = {
        k: v for d in r.refusals.values() for k, v in d.items() if not k.startswith("booting")
    }
    total: dict[str, int] = {}
    for d in r.refusals.values():
        for k, v in d.items():
            total[k] = total.get(k, 0) + v
    del refused
    top = ", ".join(f"{k} {v}" for k, v in sorted(total.items(), key=lambda kv: -kv[1])[:4])
    return (
        f"{r.attack:14s} auth {'on ' if r.auth else 'off'}  peak {r.peak_speed_mps:.2f} m/s "
        f"{r.peak_yaw_radps:.2f} rad/s (route before: {r.route_peak_speed_mps:.2f}, "
        f"{r.route_peak_yaw_radps:.2f})  detected {_fmt(r.detected_s)} s {r.detection or '-'}; "
        f"host {r.host_final_state} {r.stop_reason}; after stop "
        f"{_fmt(r.wheel_after_stop_revps, 3)} rev/s; refused: {top or '-'}  "
        f"{'PASS' if r.passed else 'FAIL: ' + '; '.join(r.failures)}"
    )


def _false_alarms(args: argparse.Namespace, out: Path, modes: list[bool]) -> int:
    trips = invalid = early = 0
    worst: list[float] = []
    for k in range(args.false_alarms):
        for auth in modes:
            d = out / f"clean-{k}-auth-{'on' if auth else 'off'}"
            res = run_attack(
                d,
                "none",
                auth=auth,
                scenario=args.scenario,
                controller=args.controller,
                at_s=args.at,
                duration_s=args.duration,
                rt_priority=args.rt_priority,
            )
            w = math.nan if res.obey_worst_revps is None else res.obey_worst_revps
            worst.append(w)
            tripped = res.stop_reason == "DISOBEYED"
            trips += tripped
            invalid += bool(res.failures and res.failures[0].startswith("invalid run"))
            early += res.detected_s is not None
            stopped = (
                f"stopped {res.detected_s:.2f} s after {args.at:g} s: {res.detection}"
                if res.detected_s is not None
                else "no stop before the bench ended"
            )
            print(
                f"run {k} auth {'on' if auth else 'off'}: {stopped}; host at the end "
                f"{res.host_final_state} {res.stop_reason}; closest to the plausibility bound "
                f"{w:.4f} rev/s ({res.run_dir})",
                flush=True,
            )
    print(
        f"plausibility stops in {len(worst)} fault-free real-time runs: {trips}; "
        f"runs that stopped for any reason before the bench ended: {early}"
        + (
            f" ({invalid} of them invalid: the host was not tracking at {args.at:g} s)"
            if invalid
            else ""
        )
    )
    return 0 if trips == 0 and invalid == 0 else 1


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "attacker":
        raise SystemExit(attacker_main(sys.argv[2:]))
    raise SystemExit("usage: python -m tools.safety.attacks attacker ...")
