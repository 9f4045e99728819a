"""The safety fault-injection suite's cases, as data: what each injects, when, and what it expects.

``tests/safety/`` parametrizes over :data:`CASES` and ``wheelchair-hil safety-report`` prints the
same cases as a table (docs/safety.md).  Each :class:`SafetyCase` names its fault, the outcome it
expects (:data:`STOP`, :data:`RIDE`, :data:`NO_MOTION`, :data:`SAME`, :data:`SAFE`), the detector
expected to act first and that detector's budget.  The faults are injected at ``onset_s``:

* bench-side faults through the scenario fault schedule (``[[faults]]`` tables, the bench's own
  :class:`~firmware_sim.busfaults.FaultInjectingBus`) or raw rules on an outer wrapper of the
  bench's bus (babbling node, fuzz, wrong node, truncated frames): :data:`RuleFactory`;
* host-side bus faults on a wrapper of the controller's bus (bus-off, babble);
* controller process faults (:class:`HostFault`): killed, frozen with its last frame re-sent,
  stalled for N periods;
* a faulty tracking law (NaN, infinite, out-of-range commands) or a controller that starts
  with a non-neutral command.

:mod:`tools.safety.runner` runs a case in this process, :mod:`tools.safety.criteria` judges
the run, :mod:`tools.safety.realtime` runs the controller as a real process and signals it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import can

from dbc.codec import (
    AxisState,
    ClearErrors,
    Codec,
    EncoderEstimates,
    Node,
    SetAxisState,
    SetInputVel,
    SetInputVelAuth,
    SetLimits,
    SetWatchdog,
)
from dbc.secoc import Authenticator, load_key
from firmware_sim import busfaults as bf
from firmware_sim.config import load_bench_config

MS = 1_000_000
PERIOD_S = 0.01
#: Setpoint watchdog of the safety profile: N = 10 periods of T = 10 ms.
WATCHDOG_S = 0.1
#: Fault onset on the short route: the chair is in its first (left) turn at about 0.9 m/s.
ONSET_S = 6.0
#: Simulated run length of a case: onset, the stop (< 1.5 s) and > 1 s to check no resume.
RUN_S = 9.0

#: Controller configuration of the suite: the safety profile (docs/safety.md).
SAFETY_PROFILE: dict[str, Any] = {
    "drives": {"require_auth": True, "require_neutral_start": True, "host_timeout_ms": 300}
}

STOP = "stop"
RIDE = "ride-through"
NO_MOTION = "no motion"
SAME = "unaffected"
#: Either rides through or stops within the stop criteria (fuzz: random frames on command
#: IDs are valid commands, e.g. Estop or IDLE).
SAFE = "safe"


# ------------------------------------------------------------------------- cases


@dataclass(frozen=True)
class Ctx:
    """What a rule factory needs: the codec, the onset and end of the fault in sim ns."""

    codec: Codec
    onset_ns: int
    end_ns: int
    seed: int


RuleFactory = Callable[[Ctx], Sequence[bf.Rule]]


@dataclass(frozen=True)
class HostFault:
    """How the controller process misbehaves from the onset.

    ``kind``: ``kill`` (no tick, nothing sent, to the end), ``freeze-repeat`` (no tick; the
    last setpoint frames are re-sent every period, as by a stuck transmit mailbox), ``stall``
    (no tick for ``periods`` periods, then it carries on: an overrun; SIGSTOP + SIGCONT),
    ``non-neutral-start`` (sends a forward command while arming), ``law-nan`` /
    ``law-inf`` / ``law-huge`` (the tracking law returns NaN / inf / 1e9 for ``periods``).
    """

    kind: str
    periods: int = 0


@dataclass(frozen=True)
class SafetyCase:
    """One fault case with its expected outcome and the criteria it is judged by."""

    name: str
    fault: str
    expect: str  # STOP, RIDE, NO_MOTION or SAME
    detector: str  # what is expected to act first
    budget_s: float = 0.0  # N*T of that detector; detection criterion: budget + 2T
    onset_s: float = ONSET_S
    fault_s: float = 2.0  # how long a timed fault lasts
    run_s: float = RUN_S
    faults: tuple[Mapping[str, Any], ...] = ()
    bench_rules: RuleFactory | None = None
    host_rules: RuleFactory | None = None
    host_fault: HostFault | None = None
    controller: Mapping[str, Any] = field(default_factory=dict)
    bench: Mapping[str, Any] = field(default_factory=dict)
    recorder_crash: bool = False
    wall_clock_jump: bool = False
    #: frames that must have been rejected, by "<where>:<reason>" (at least one each)
    must_reject: tuple[str, ...] = ()
    #: the wheels stop without yaw (both ramp together); False where a wheel is braked
    #: or blind, so only the distance and no-resume criteria apply
    yaw_free: bool = True
    #: the drives' heartbeats cannot reach the bus (a babbler holds it)
    bus_blocked: bool = False
    note: str = ""


def _bus_fault(kind: str, onset_s: float, duration_s: float, **kw: Any) -> dict[str, Any]:
    return {"type": kind, "onset_s": onset_s, "duration_s": duration_s, **kw}


_SETPOINTS = ("Left_Set_Input_Vel_Auth", "Right_Set_Input_Vel_Auth")


def _on_bus(
    name: str,
    fault: str,
    expect: str,
    detector: str = "-",
    budget_s: float = 0.0,
    *,
    kind: str,
    fault_s: float,
    frames: Sequence[str] | None = _SETPOINTS,
    case: Mapping[str, Any] | None = None,
    **params: Any,
) -> SafetyCase:
    """A case whose fault is one bus fault of the bench's schedule (``kind`` with ``params``)
    on ``frames`` (None: every 11-bit frame), from the onset for ``fault_s``; ``case``: the
    case's other fields."""
    on = {"frames": list(frames)} if frames is not None else {}
    schedule = _bus_fault(kind, ONSET_S, fault_s, **on, **params)
    return SafetyCase(
        name, fault, expect, detector, budget_s, fault_s=fault_s, faults=(schedule,), **(case or {})
    )


def _inject(c: Ctx, message: can.Message, period_ns: int, after_ns: int = 0) -> bf.Rule:
    """``message`` arrives every ``period_ns``, from ``after_ns`` past the onset to the end of
    the fault (a foreign node on the bus)."""
    return bf.Inject(
        direction=bf.Direction.RECV,
        start_ns=c.onset_ns + after_ns,
        end_ns=c.end_ns,
        message=message,
        period_ns=period_ns,
    )


def _frame(arbitration_id: int, data: bytes | bytearray, **kw: Any) -> can.Message:
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False, **kw)


def _babble(flood_period_ns: int, saturate: bool) -> RuleFactory:
    """A node sending ID 0x001 (highest priority of any frame here) back to back."""

    def rules(c: Ctx) -> list[bf.Rule]:
        out = [_inject(c, _frame(0x001, bytes(8)), flood_period_ns)]
        if saturate:  # the babbler wins every arbitration: nobody else gets a frame through
            out.append(bf.Drop(start_ns=c.onset_ns, end_ns=c.end_ns, probability=1.0))
        return out

    return rules


def _fuzz(c: Ctx) -> list[bf.Rule]:
    """Random frames on any 11-bit ID, and as many on the IDs the DBC defines."""
    defined = tuple(
        sorted({c.codec.frame_id(cls, n) for cls, n, _ in c.codec.all_messages() if n is not None})
    )
    common: dict[str, Any] = {
        "direction": bf.Direction.RECV,
        "start_ns": c.onset_ns,
        "end_ns": c.end_ns,
        "period_ns": 500_000,
        "max_length": 12,
        "remote_probability": 0.05,
    }
    return [bf.Fuzz(**common), bf.Fuzz(**common, ids=defined)]


def _wrong_node(c: Ctx) -> list[bf.Rule]:
    """The left drive's setpoints (authenticated for node 1 with the drives' key) and a plain
    one, sent to node 2: the MAC covers the frame ID, so node 2 refuses them."""

    codec = c.codec
    auth = Authenticator(load_key(load_bench_config({}, source="defaults").key_path))
    right_auth = codec.frame_id(SetInputVelAuth, Node.RIGHT)
    out: list[bf.Rule] = []
    for k in range(16):
        (left,) = codec.encode_secured(SetInputVelAuth(0.8, 0.8), Node.LEFT, auth)
        out.append(_inject(c, _frame(right_auth, left.data), 16 * MS, after_ns=k * MS))
    plain = codec.encode(SetInputVel(0.8), Node.LEFT)
    right_plain = codec.frame_id(SetInputVel, Node.RIGHT)
    out.append(_inject(c, _frame(right_plain, plain.data), 10 * MS))
    return out


def _bad_length(c: Ctx) -> list[bf.Rule]:
    """Truncated and oversized setpoints (to the drives) and encoder estimates (to the host)."""
    codec = c.codec
    out: list[bf.Rule] = []
    for cls, node, payload in (
        (SetInputVelAuth, Node.LEFT, SetInputVelAuth(0.8, 0.8, 3, 0)),
        (EncoderEstimates, Node.LEFT, EncoderEstimates(0.0, 0.5)),
    ):
        good = codec.encode(payload, node)
        for data in (bytes(good.data[:4]), bytes(good.data) + bytes(4)):
            m = _frame(codec.frame_id(cls, node), data, dlc=min(len(data), 8), check=False)
            out.append(_inject(c, m, 5 * MS))
    return out


def _non_finite_wire(c: Ctx) -> list[bf.Rule]:
    """Setpoints a foreign node can put on the wire: Input_Vel's raw -32768 (outside its
    +-3.2767 rev/s range) and +-3.2767 rev/s (beyond the drives' 1 rev/s limit), with a MAC it
    cannot compute.  The int16 of the authenticated frame cannot carry NaN or inf at all."""
    out: list[bf.Rule] = []
    for i, raw in enumerate((-32768, 32767, -32767, -32768)):
        good = c.codec.encode(SetInputVelAuth(0.0, 0.0, 5 + i, 0x5EC0C0DE), Node.RIGHT)
        data = bytearray(good.data)
        data[0:2] = raw.to_bytes(2, "little", signed=True)
        out.append(_inject(c, _frame(good.arbitration_id, data), 10 * MS, after_ns=i * MS))
    return out


def _forged_setpoints(c: Ctx) -> list[bf.Rule]:
    """A node without the key (docs/safety.md § 5a): setpoints of 0.907 rev/s (1.71 m/s) to both drives,
    each freshness value in turn, with made-up MACs, 1.6 frames per drive and period."""
    return [
        _inject(
            c,
            c.codec.encode(SetInputVelAuth(0.907, 0.91, k * 16, 0x0BADF00D + k), n),
            10 * MS,
            after_ns=k * MS // 2,
        )
        for n in (Node.LEFT, Node.RIGHT)
        for k in range(16)
    ]


def _rearm_plain(c: Ctx) -> list[bf.Rule]:
    """After the host is gone (docs/safety.md § 5a): every 10 ms, to both drives, Clear_Errors, a
    Set_Watchdog with every protection off, Set_Limits, Set_Axis_State(CLOSED_LOOP) and a plain
    setpoint of 0.907 rev/s, from 0.5 s after the onset, without the key."""

    frames = (
        ClearErrors(),
        SetWatchdog(0, 0.0, False, 0, False),
        SetLimits(20.0, 60.0),
        SetAxisState(AxisState.CLOSED_LOOP_CONTROL),
        SetInputVel(0.907),
    )
    return [
        _inject(c, c.codec.encode(payload, n), 10 * MS, after_ns=500 * MS + k * MS)
        for n in (Node.LEFT, Node.RIGHT)
        for k, payload in enumerate(frames)
    ]


def _bus_off(c: Ctx) -> list[bf.Rule]:
    return [bf.BusOff(start_ns=c.onset_ns, end_ns=c.end_ns)]


CASES: tuple[SafetyCase, ...] = (
    SafetyCase(
        "controller-sigkill",
        "controller killed (SIGKILL)",
        STOP,
        "drive watchdog",
        WATCHDOG_S,
        host_fault=HostFault("kill"),
    ),
    SafetyCase(
        "controller-sigstop",
        "controller stopped (SIGSTOP) for 1 s, then continued (SIGCONT)",
        STOP,
        "drive watchdog",
        WATCHDOG_S,
        host_fault=HostFault("stall", 100),
    ),
    SafetyCase(
        "frozen-last-frame-repeated",
        "frozen controller, its last setpoint frames re-sent every period",
        STOP,
        "drive watchdog (re-sent frames are replays)",
        WATCHDOG_S,
        host_fault=HostFault("freeze-repeat"),
        must_reject=("drives:auth_replayed",),
    ),
    SafetyCase(
        "frozen-plain-setpoints",
        "frozen controller re-sending plain Set_Input_Vel (Require_Auth off)",
        STOP,
        "drive host-heartbeat monitor",
        0.3,
        host_fault=HostFault("freeze-repeat"),
        controller={"drives": {"require_auth": False}},
        yaw_free=False,
        note="without authentication the repeated frame feeds the watchdog; the host heartbeat catches "
        "it; plain frames carry no stop reference, so the wheels stop at equal deceleration",
    ),
    *(
        _on_bus(
            f"loss-random-{pct}pct",
            f"random loss of {pct} % of the setpoints",
            RIDE,
            kind="bus-drop",
            fault_s=2.5,
            probability=p,
        )
        for pct, p in ((1, 0.01), (10, 0.1), (30, 0.3))
    ),
    _on_bus(
        "loss-random-30pct-all-frames",
        "random loss of 30 % of every 11-bit frame, both ways (feedback too)",
        SAFE,
        "host: ENCODER_STALE",
        kind="bus-drop",
        fault_s=2.5,
        frames=None,
        probability=0.3,
        case={
            "yaw_free": False,
            "note": "lost heartbeats or 4 encoder frames in a row lost end in a safe stop; "
            "the stop's own setpoints are lost too, so its curvature is reported, not judged",
        },
    ),
    *(
        _on_bus(
            f"loss-burst-{n}-periods",
            f"burst loss of {n_is} setpoint periods ({n}0 ms)",
            expect,
            detector,
            budget_s,
            kind="bus-drop",
            fault_s=n * PERIOD_S,
            probability=1.0,
        )
        for n, n_is, expect, detector, budget_s in (
            (9, "N-1 = 9", RIDE, "-", 0.0),
            (10, "N = 10", STOP, "drive watchdog", WATCHDOG_S),
        )
    ),
    *(
        _on_bus(
            f"loss-encoder-burst-{n}",
            f"burst loss of {n} encoder periods: {what}",
            expect,
            detector,
            budget_s,
            kind="bus-drop",
            fault_s=n * PERIOD_S,
            frames=("Left_Get_Encoder_Estimates",),
            probability=1.0,
        )
        for n, what, expect, detector, budget_s in (
            (3, "estimate 3 periods old (host limit: older than 3)", RIDE, "-", 0.0),
            (4, "estimate 4 periods old", STOP, "host: ENCODER_STALE", 0.03),
        )
    ),
    _on_bus(
        "delay-9-periods",
        "setpoints delayed by N-1 = 9 periods (90 ms) from the onset",
        RIDE,
        kind="bus-delay",
        fault_s=2.0,
        delay_ms=90.0,
        case={"note": "a constant 90 ms lag: the drives follow the delayed stream"},
    ),
    _on_bus(
        "delay-15-periods",
        "setpoints delayed by 15 periods (150 ms), beyond N",
        STOP,
        "drive watchdog",
        WATCHDOG_S,
        kind="bus-delay",
        fault_s=2.0,
        delay_ms=150.0,
    ),
    _on_bus(
        "duplication",
        "every setpoint duplicated with p = 0.5",
        RIDE,
        kind="bus-duplicate",
        fault_s=2.5,
        probability=0.5,
        case={"must_reject": ("drives:auth_replayed",)},
    ),
    _on_bus(
        "reordering",
        "setpoints reordered with p = 0.3 (including across the counter wrap 15 -> 0)",
        RIDE,
        kind="bus-reorder",
        fault_s=2.5,
        frames=("Left_Set_Input_Vel_Auth",),
        probability=0.3,
        max_hold_ms=30.0,
        case={"must_reject": ("drives:auth_replayed",)},
    ),
    *(
        _on_bus(
            f"corrupt-{b}-bit{'s' if b > 1 else ''}",
            f"{b} flipped bit{'s' if b > 1 else ''} in 20 % of the setpoints",
            RIDE,
            kind="bus-corrupt",
            fault_s=2.5,
            probability=0.2,
            bits=b,
            case={"must_reject": ("drives:auth_mac_mismatch",)},
        )
        for b in (1, 2, 3)
    ),
    SafetyCase(
        "wrong-node",
        "the left drive's setpoints (authenticated for node 1, and plain) sent to node 2",
        RIDE,
        "-",
        bench_rules=_wrong_node,
        must_reject=("drives:auth_mac_mismatch", "drives:plain_setpoint_auth_required"),
    ),
    SafetyCase(
        "babbling-node",
        "a node flooding ID 0x001 at 50 % bus load",
        RIDE,
        "-",
        bench_rules=_babble(500_000, saturate=False),
        host_rules=_babble(500_000, saturate=False),
        must_reject=("bench:unknown_id", "host:unknown_id"),
    ),
    SafetyCase(
        "babbling-node-saturating",
        "a node flooding ID 0x001 back to back: no other frame wins arbitration",
        STOP,
        "drive watchdog",
        WATCHDOG_S,
        bench_rules=_babble(250_000, saturate=True),
        host_rules=_babble(250_000, saturate=True),
        must_reject=("bench:unknown_id", "host:unknown_id"),
        bus_blocked=True,
        note="the host sees its encoders go stale first, but nothing it sends gets through",
    ),
    SafetyCase(
        "bus-off-host",
        "the controller's CAN controller goes bus-off",
        STOP,
        "drive watchdog",
        WATCHDOG_S,
        host_rules=_bus_off,
    ),
    SafetyCase(
        "drive-drops-out",
        "the left drive falls silent (both ways)",
        STOP,
        "host: ENCODER_STALE",
        0.03,
        faults=(_bus_fault("node-silent", ONSET_S, 0.0, node="left"),),
        note="the silent drive's own watchdog ramps it with the same stop reference",
    ),
    SafetyCase(
        "drive-reboots",
        "the left drive reboots mid-route (50 ms boot, comes back idle, brake on)",
        STOP,
        "host: ENCODER_STALE",
        0.03,
        faults=({"type": "node-reboot", "onset_s": ONSET_S, "node": "left"},),
        yaw_free=False,
        note="the rebooted wheel brakes at once; the host brakes the other on seeing it idle",
    ),
    SafetyCase(
        "stuck-encoder",
        "the left encoder count freezes",
        STOP,
        "host: ENCODER_JUMP/STUCK (brake)",
        0.5,
        faults=(_bus_fault("encoder-stuck", ONSET_S, 0.0, side="left"),),
        yaw_free=False,
        note="the drive's own speed loop is blind and pushes; the host brakes both wheels",
    ),
    SafetyCase(
        "law-nan",
        "the tracking law returns NaN",
        STOP,
        "host: NON_FINITE",
        0.0,
        host_fault=HostFault("law-nan", 1000),
    ),
    SafetyCase(
        "law-inf",
        "the tracking law returns infinity",
        STOP,
        "host: NON_FINITE",
        0.0,
        host_fault=HostFault("law-inf", 1000),
    ),
    SafetyCase(
        "law-out-of-range",
        "the tracking law returns v = 1e9 m/s for 0.3 s",
        RIDE,
        "-",
        host_fault=HostFault("law-huge", 30),
        note="saturated by the limiter (speed, acceleration, jerk, wheel limit)",
    ),
    SafetyCase(
        "wire-non-finite-setpoints",
        "unauthenticated setpoints out of range and at +-3.28 rev/s on the bus",
        RIDE,
        "-",
        bench_rules=_non_finite_wire,
        must_reject=("bench:range", "drives:auth_mac_mismatch"),
    ),
    SafetyCase(
        "bad-length-frames",
        "truncated (4 bytes) and oversized (12 bytes) setpoints and encoder frames",
        RIDE,
        "-",
        bench_rules=_bad_length,
        host_rules=_bad_length,
        must_reject=("bench:length", "host:length"),
    ),
    SafetyCase(
        "non-neutral-start",
        "the controller starts with a non-zero command while arming",
        NO_MOTION,
        "drive: neutral start + watchdog",
        WATCHDOG_S,
        onset_s=0.01,  # the host arms 10 ms in, after the drives confirmed the wire contract
        run_s=4.0,
        host_fault=HostFault("non-neutral-start"),
        must_reject=("drives:not_neutral_after_arm",),
    ),
    *(
        SafetyCase(
            f"overrun-{n}-periods",
            f"a controller tick overruns by {n} periods",
            RIDE if n * PERIOD_S < WATCHDOG_S else STOP,
            "-" if n * PERIOD_S < WATCHDOG_S else "drive watchdog",
            WATCHDOG_S if n * PERIOD_S >= WATCHDOG_S else 0.0,
            host_fault=HostFault("stall", n),
        )
        for n in (2, 5, 50)
    ),
    SafetyCase(
        "recorder-crash",
        "the log recorder dies mid-run",
        SAME,
        "-",
        recorder_crash=True,
        bench={"bench": {"recorder_window_steps": 100, "recorder_timeout_s": 0.5}},
    ),
    SafetyCase(
        "fuzz-all-ids",
        "seeded random frames for 1 s, 2 per ms: any 11-bit ID, and the DBC's IDs "
        "(length 0-12, 5 % RTR)",
        SAFE,
        "any",
        fault_s=1.0,
        bench_rules=_fuzz,
        host_rules=_fuzz,
        yaw_free=False,
        note="random frames on command IDs are valid commands (Estop, IDLE, Reboot ...): "
        "the criterion is no exception and a safe end, not ride-through",
    ),
    SafetyCase(
        "forged-setpoints",
        "a node without the key sends 0.907 rev/s setpoints with made-up MACs to both drives",
        RIDE,
        "-",
        fault_s=2.5,
        bench_rules=_forged_setpoints,
        must_reject=("drives:auth_mac_mismatch",),
    ),
    SafetyCase(
        "rearm-after-kill",
        "controller killed; a node without the key sends every re-arm sequence for 2.5 s",
        STOP,
        "drive watchdog",
        WATCHDOG_S,
        fault_s=3.0,
        host_fault=HostFault("kill"),
        bench_rules=_rearm_plain,
        must_reject=("drives:auth_missing", "drives:plain_setpoint_auth_required"),
    ),
    SafetyCase(
        "wall-clock-jump",
        "the wall clock jumps +1 h, then -2 h",
        SAME,
        "-",
        wall_clock_jump=True,
    ),
)

CASES_BY_NAME = {c.name: c for c in CASES}
