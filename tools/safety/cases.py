"""The safety fault-injection suite: every case as data, one in-process runner, the criteria.

``tests/safety/`` parametrizes over :data:`CASES` and ``wheelchair-hil safety-report`` prints the
same cases as a table (docs/safety.md).  Each :class:`SafetyCase` runs the bench and the
controller in lock-step on python-can's virtual bus inside this process (deterministic,
simulation time) on the short route with the baseline controller and the *safety profile*
(:data:`SAFETY_PROFILE`: authenticated setpoints, neutral start, host-heartbeat monitor), and injects
its fault at ``onset_s``:

* bench-side faults through the scenario fault schedule (``[[faults]]`` tables, the bench's own
  :class:`~firmware_sim.busfaults.FaultInjectingBus`) or raw rules on an outer wrapper of the
  bench's bus (babbling node, fuzz, wrong node, truncated frames);
* host-side bus faults on a wrapper of the controller's bus (bus-off, babble);
* controller process faults through a clock shim (:class:`_FaultClock`): killed, frozen with
  its last frame re-sent, stalled for N periods.  A killed or stalled controller runs no
  tick and sends nothing; the shim still acknowledges ``Bench_Step`` (the bench's clock
  protocol, not chair traffic) so that the run stays deterministic and fast.  The real
  process is killed in the multi-process real-time tests (:func:`realtime_signal_run`);
* a faulty tracking law (NaN, infinite, out-of-range commands) or a controller that starts
  with a non-neutral command.

Ground truth is sampled at the drives' 1 kHz tick (wheel speeds, contact radii, each drive's
stop, errors and last accepted setpoint), the host's state at every tick and the drives'
heartbeats on the bus; :func:`analyse` derives detection time, stop start, stop time, stop
distance, ``|wL - wR|`` and the heading during the stop and the no-resume check, and checks
them against the criteria of docs/safety.md (:class:`CaseResult.failures`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import json
import math
import signal as signal_mod
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar
from unittest import mock

import can
import numpy as np

from controller.clock import LockstepClock
from controller.config import ControllerConfig, load_config
from controller.limits import LimitedCommand
from controller.node import ControllerNode
from controller.types import TwistCommand
from dbc.codec import (
    AxisError,
    AxisState,
    BenchStep,
    ClearErrors,
    Codec,
    EncoderEstimates,
    Heartbeat,
    HostState,
    Node,
    SetAxisState,
    SetInputVel,
    SetInputVelAuth,
    SetLimits,
    SetWatchdog,
)
from dbc.errors import DecodeError
from dbc.runtime import params
from dbc.secoc import Authenticator, load_key
from firmware_sim import busfaults as bf
from firmware_sim.config import load_bench_config
from firmware_sim.faults import parse_schedule
from tools.bus.transport import open_bus, resolve
from tools.logs.mcap_io import iter_frames
from tools.logs.recorder import BusRecorder
from tools.run import build
from tools.run import scenario as scenario_mod
from tools.run.processes import PartFailedError, SandboxedParts, realtime_parts, signal_part
from tools.run.runner import make_plan
from tools.safety.verdict import Verdict

MS = 1_000_000
PERIOD_S = 0.01
#: Rim deceleration of every coordinated stop (drive Stop_Decel and host safe stop), m/s^2.
A_STOP_MPS2 = 1.0
#: A wheel whose rim moves slower than this is at standstill (m/s).
STANDSTILL_MPS = 0.01
#: Setpoint watchdog of the safety profile: N = 10 periods of T = 10 ms.
WATCHDOG_S = 0.1
#: Fault onset on the short route: the chair is in its first (left) turn at about 0.9 m/s.
ONSET_S = 6.0
#: Simulated run length of a case: onset, the stop (< 1.5 s) and > 1 s to check no resume.
RUN_S = 9.0
#: "Without yaw" (docs/safety.md): during the stop |wL - wR| may exceed the curvature-keeping
#: profile (shrinking in proportion to the speed) by at most this (rad/s: 3 cm/s of rim speed),
YAW_TOL_RADPS = 0.1
#: and the heading may differ from that of the curvature-keeping stop by at most this (deg).
HEADING_TOL_DEG = 1.0
#: A ride-through case may leave the chair at most this far from the fault-free run (m).
RIDE_THROUGH_TOL_M = 0.05

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
    """A node without the key (issue 16): setpoints of 0.907 rev/s (1.71 m/s) to both drives,
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
    """After the host is gone (issue 16): every 10 ms, to both drives, Clear_Errors, a
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


# ------------------------------------------------------------------- observation


@dataclass
class Trace:
    """Ground truth at the drives' 1 kHz tick and the host's view at every tick."""

    t_ns: list[int] = field(default_factory=list)
    w: list[tuple[float, float]] = field(default_factory=list)  # wheel rad/s L, R
    r: list[tuple[float, float]] = field(default_factory=list)  # contact radius m L, R
    stopping: list[tuple[bool, bool]] = field(default_factory=list)
    armed: list[tuple[bool, bool]] = field(default_factory=list)
    errors: list[tuple[int, int]] = field(default_factory=list)
    feed_ns: list[tuple[int, int]] = field(default_factory=list)
    host_t_ns: list[int] = field(default_factory=list)
    host_state: list[int] = field(default_factory=list)
    host_reason: list[str] = field(default_factory=list)
    host_cmd: list[tuple[float, float]] = field(default_factory=list)
    host_seen_error: list[tuple[int, int]] = field(default_factory=list)
    host_holding: list[bool] = field(default_factory=list)


class _FaultClock:
    """A lock-step clock shim that emulates a dead, frozen or stalled controller process."""

    lockstep = True

    def __init__(
        self, inner: LockstepClock, fault: HostFault | None, onset_ns: int, trace: Trace
    ) -> None:
        self.inner = inner
        self.period_ns = inner.period_ns
        self.stats = inner.stats
        self.fault = fault
        self.onset_ns = onset_ns
        self.trace = trace
        self.node: ControllerNode | None = None
        self.now_ns = 0
        self.suppressed = 0
        self.ended_by = ""
        self._last_setpoints: dict[Node, can.Message] = {}
        self._setpoint_ids: dict[int, Node] | None = None

    def start(self) -> None:
        self.inner.start()

    def _muted(self, t_ns: int) -> bool:
        f = self.fault
        if f is None or t_ns < self.onset_ns:
            return False
        if f.kind in ("kill", "freeze-repeat"):
            return True
        if f.kind == "stall":
            return t_ns < self.onset_ns + f.periods * self.period_ns
        return False

    def wait_tick(self, on_frame: Callable[[can.Message], None]) -> int | None:
        while True:
            dead = self.fault is not None and self.fault.kind in ("kill", "freeze-repeat")
            sink = (lambda _m: None) if dead and self.now_ns >= self.onset_ns else on_frame
            t = self.inner.wait_tick(sink)
            if t is None:
                self.ended_by = self.inner.ended_by
                return None
            self.now_ns = t
            if not self._muted(t):
                return t
            self.suppressed += 1
            node = self.node
            if self.fault is not None and self.fault.kind == "freeze-repeat" and node is not None:
                for msg in self._last_setpoints.values():
                    node.link.bus.send(msg)
            self.inner.tick_done(t)  # the bench's clock protocol only (module docstring)

    def tick_done(self, t_ns: int) -> None:
        node = self.node
        if node is not None:
            tr = self.trace
            tr.host_t_ns.append(t_ns)
            tr.host_state.append(int(node.state))
            tr.host_reason.append(node.stop_reason.name)
            c = node._wheel_cmd_radps
            tr.host_cmd.append((c[Node.LEFT], c[Node.RIGHT]))
            d = node.link.drives
            tr.host_seen_error.append((d[Node.LEFT].axis_error, d[Node.RIGHT].axis_error))
            tr.host_holding.append(node.hold is not None)
        self.inner.tick_done(t_ns)

    def capture(self, msg: can.Message) -> None:
        """Keep the last setpoint *frame* to each drive, as a stuck transmit mailbox re-sends
        it (the same bytes: with authentication, a replay)."""
        ids = self._setpoint_ids
        if ids is None:
            codec = Codec.default()
            ids = self._setpoint_ids = {
                codec.frame_id(cls, n): n
                for cls in (SetInputVelAuth, SetInputVel)
                for n in (Node.LEFT, Node.RIGHT)
            }
        n = ids.get(msg.arbitration_id)
        if n is not None and not msg.is_extended_id:
            self._last_setpoints[n] = msg


class _FaultyLaw:
    """Wraps a tracking law; returns a bad command for ``periods`` ticks from the onset."""

    name: ClassVar[str] = "faulty"

    def __init__(self, law: Any, fault: HostFault, onset_ns: int, clock: _FaultClock) -> None:
        self._law = law
        self._fault = fault
        self._onset_ns = onset_ns
        self._clock = clock

    def __getattr__(self, name: str) -> Any:
        return getattr(self._law, name)

    def reset(self, *a: Any, **kw: Any) -> None:
        self._law.reset(*a, **kw)

    def internals(self) -> Any:
        return self._law.internals()

    def step(self, *a: Any, **kw: Any) -> TwistCommand:
        cmd = self._law.step(*a, **kw)
        t = self._clock.now_ns
        end = self._onset_ns + self._fault.periods * self._clock.period_ns
        if not self._onset_ns <= t < end:
            return cmd
        bad = {"law-nan": math.nan, "law-inf": math.inf, "law-huge": 1e9}[self._fault.kind]
        return TwistCommand(bad, cmd.omega_radps if self._fault.kind != "law-nan" else bad)


class _NonNeutralStartNode(ControllerNode):
    """A controller that commands 0.3 m/s forward while it arms the drives and after (its
    command never passes through zero: once the host sends a neutral one the drives would
    rightly follow it)."""

    def _send_setpoints(self, cmd: LimitedCommand) -> tuple[float, float]:
        if self.state in (HostState.ARMING, HostState.TRACKING):
            g = self.cfg.geometry
            cmd = LimitedCommand.from_twist(0.3, 0.0, g.half_track_m, g.wheel_radius_m)
        return super()._send_setpoints(cmd)


# ----------------------------------------------------------------------- running


@dataclass
class RunOutput:
    """Everything one case run produced (raw; :func:`analyse` reduces it)."""

    case: SafetyCase
    trace: Trace
    bench_rejected: dict[str, int]
    bench_effects: dict[str, int]
    drive_ignored: dict[str, int]
    host_rejected: dict[str, int]
    host_send_failed: int
    host_exceptions: int
    thread_errors: list[str]
    final_state: str
    stop_reason: str
    missed_acks: int
    suppressed_ticks: int
    truth_xy: tuple[float, float]
    wall_s: float
    #: half the wheel separation of the simulated chair (m)
    half_track_m: float = 0.28
    #: drive heartbeats seen on the bus: (simulation ns, node, Axis_Error)
    drive_heartbeats: list[tuple[int, int, int]] = field(default_factory=list)


_channels = itertools.count()


def _controller_config(case: SafetyCase) -> ControllerConfig:
    cfg = params.replace(load_config(), SAFETY_PROFILE, source="safety profile")
    if case.controller:
        cfg = params.replace(cfg, dict(case.controller), source=f"safety case {case.name}")
    if not cfg.drives.require_auth:  # a stock ODrive has no contract-hash endpoint
        cfg = params.replace(cfg, {"auth": {"check_contract": False}}, source="stock ODrive")
    return cfg


@contextlib.contextmanager
def _wall_clock_jump(enabled: bool, flag: threading.Event) -> Iterator[None]:
    """Patch ``time.time``/``time_ns``: +1 h once ``flag`` is set, -1 h a second later."""
    if not enabled:
        yield
        return
    real_time, real_time_ns = time.time, time.time_ns
    since: list[float] = []

    def offset_s() -> float:
        if not flag.is_set():
            return 0.0
        if not since:
            since.append(time.monotonic())
        return 3600.0 if time.monotonic() - since[0] < 1.0 else -3600.0

    with (
        mock.patch("time.time", lambda: real_time() + offset_s()),
        mock.patch("time.time_ns", lambda: real_time_ns() + int(offset_s() * 1e9)),
    ):
        yield


def run_case(
    case: SafetyCase, *, scenario: str = "short", controller: str = "baseline", seed: int = 1
) -> RunOutput:
    """Run one case in this process (lock-step, virtual bus); returns the raw observations."""
    codec = Codec.default()
    scen = scenario_mod.load(scenario)
    onset_ns = round(case.onset_s * 1e9)
    end_ns = onset_ns + round(case.fault_s * 1e9)
    ctx = Ctx(codec, onset_ns, end_ns, seed)
    faults = list(scen.faults)
    if case.faults:
        faults += parse_schedule([dict(f) for f in case.faults], source=f"case {case.name}")
    scen = dataclasses.replace(scen, faults=tuple(faults))
    plan = make_plan(scen, controller, realtime=False, duration_s=case.run_s, seed=seed)
    overrides = dict(scen.bench)
    for sec, vals in case.bench.items():
        overrides.setdefault(sec, {}).update(vals)
    cfg = _controller_config(case)
    if not cfg.drives.require_auth:  # a stock ODrive: no MAC, no contract check
        overrides.setdefault("drive", {}).update(require_auth=False, check_contract=False)
    bcfg = load_bench_config(overrides, source=f"safety case {case.name}")
    spec = resolve("virtual", f"safety-{next(_channels)}-{case.name}")
    trace = Trace()
    errors: list[str] = []
    jump = threading.Event()

    bench_raw = open_bus(spec)
    ctl_raw = open_bus(spec)
    rec_bus = open_bus(spec) if case.recorder_crash else None
    monitor = open_bus(spec)  # the bus as a listener sees it (drive heartbeats)
    holder: dict[str, Any] = {}
    bench_bus: can.BusABC = bench_raw
    if case.bench_rules is not None:
        bench_bus = bf.FaultInjectingBus(
            bench_raw, now_ns=lambda: holder["bench"].sim.now_ns, seed=seed
        )
        for rule in case.bench_rules(ctx):
            bench_bus.add_rule(rule)
    clock_ref: dict[str, _FaultClock] = {}
    ctl_bus: can.BusABC = ctl_raw
    if case.host_rules is not None:
        ctl_bus = bf.FaultInjectingBus(ctl_raw, now_ns=lambda: clock_ref["c"].now_ns, seed=seed + 1)
        for rule in case.host_rules(ctx):
            ctl_bus.add_rule(rule)
    wall0 = time.monotonic()
    node: ControllerNode | None = None
    try:
        law: Any = build.law(plan.controller, cfg, plan.trajectory)
        clock = _FaultClock(
            build.lockstep_clock(ctl_bus, cfg, codec=codec),
            case.host_fault,
            onset_ns,
            trace,
        )
        clock_ref["c"] = clock
        hf = case.host_fault
        hooks = build.ControllerHooks(
            wrap_law=(
                (lambda inner: _FaultyLaw(inner, hf, onset_ns, clock))
                if hf is not None and hf.kind.startswith("law-")
                else None
            ),
            node_cls=(
                _NonNeutralStartNode
                if hf is not None and hf.kind == "non-neutral-start"
                else ControllerNode
            ),
        )
        node = build.node(
            ctl_bus,
            cfg,
            law,
            plan.trajectory,
            clock,
            codec=codec,
            start_pose=plan.start_pose,
            hooks=hooks,
        )
        clock.node = node
        bus_send = node.link.bus.send

        def send(msg: can.Message, timeout: float | None = None) -> None:
            clock.capture(msg)
            bus_send(msg, timeout)

        node.link.bus.send = send  # type: ignore[method-assign]

        bench = build.bench(bench_bus, bcfg, plan, codec=codec)
        holder["bench"] = bench
        sim = bench.sim
        left, right, plant = sim.left, sim.right, sim.plant
        rec_stop = threading.Event()

        def observe(t_ns: int, _plant: Any) -> None:
            trace.t_ns.append(t_ns)
            lw, rw = plant.left, plant.right
            trace.w.append((lw.omega_radps, rw.omega_radps))
            trace.r.append((lw.contact_radius_m, rw.contact_radius_m))
            trace.stopping.append(
                (left.stop_started_ns is not None, right.stop_started_ns is not None)
            )
            trace.armed.append((left.armed, right.armed))
            trace.errors.append((left.active_errors, right.active_errors))
            trace.feed_ns.append((left.watchdog.last_feed_ns, right.watchdog.last_feed_ns))
            if t_ns >= onset_ns and not jump.is_set():
                jump.set()
                rec_stop.set()

        sim.add_tick_hook(observe)

        def guarded(name: str, fn: Callable[[], Any]) -> Callable[[], None]:
            def run() -> None:
                try:
                    fn()
                except BaseException as err:  # reported as a failed criterion
                    errors.append(f"{name}: {type(err).__name__}: {err}")

            return run

        threads = [threading.Thread(target=guarded("controller", node.run), daemon=True)]
        rec_dir = None
        if rec_bus is not None:
            rec_dir = tempfile.TemporaryDirectory(prefix="safety-rec-")
            recorder = BusRecorder(
                rec_bus,
                Path(rec_dir.name) / "run.mcap",
                lockstep=True,
                codec=codec,
                stop_event=rec_stop,
            )
            threads.append(threading.Thread(target=guarded("recorder", recorder.run), daemon=True))
        with _wall_clock_jump(case.wall_clock_jump, jump):
            for th in threads:
                th.start()
            try:
                bench.run()
            except BaseException as err:
                errors.append(f"bench: {type(err).__name__}: {err}")
            for th in threads:
                th.join(30.0)
                if th.is_alive():
                    errors.append(f"{th.name} did not end")
                    node.stop_event.set()
                    rec_stop.set()
                    th.join(5.0)
        if rec_dir is not None:
            rec_dir.cleanup()
        heartbeats = _drive_heartbeats(monitor, codec)
    finally:
        for b in (bench_bus, ctl_bus, bench_raw, ctl_raw, rec_bus, monitor):
            if b is not None:
                b.shutdown()
    ignored: Counter[str] = Counter()
    for d in (sim.left, sim.right):
        ignored.update(d.ignored)
    stats = bench.stats
    return RunOutput(
        case=case,
        trace=trace,
        bench_rejected=dict(stats.frames_rejected_by_reason),
        bench_effects=dict(stats.bus_fault_effects)
        | (dict(bench_bus.counters.effects) if isinstance(bench_bus, bf.FaultInjectingBus) else {}),
        drive_ignored=dict(ignored),
        host_rejected=dict(node.link.counters.rejected),
        host_send_failed=node.link.counters.send_failed,
        host_exceptions=node.stats.exceptions,
        thread_errors=errors,
        final_state=node.state.name,
        stop_reason=node.stop_reason.name,
        missed_acks=stats.missed_acks,
        suppressed_ticks=clock.suppressed,
        truth_xy=(sim.plant.x_m, sim.plant.y_m),
        wall_s=time.monotonic() - wall0,
        drive_heartbeats=heartbeats,
        half_track_m=0.5 * bcfg.chair.wheel_separation_m,
    )


def _drive_heartbeats(monitor: can.BusABC, codec: Codec) -> list[tuple[int, int, int]]:
    """Drain a listener bus: every drive Heartbeat with the simulation time of its step.

    The bench sends a step's drive frames before that step's ``Bench_Step``.
    """
    ids = {codec.frame_id(Heartbeat, n): int(n) for n in (Node.LEFT, Node.RIGHT)}
    step_id = codec.frame_id(BenchStep)
    out: list[tuple[int, int, int]] = []
    pending: list[tuple[int, int]] = []
    while (m := monitor.recv(0.0)) is not None:
        if m.is_extended_id:
            if m.arbitration_id == step_id:
                with contextlib.suppress(DecodeError):
                    t = codec.decode(m).payload.sim_time_ns
                    out += [(t, n, e) for n, e in pending]
                    pending.clear()
        elif m.arbitration_id in ids and not m.is_remote_frame:
            with contextlib.suppress(DecodeError):
                pending.append((ids[m.arbitration_id], codec.decode(m).payload.axis_error))
    return out


# ---------------------------------------------------------------------- analysis

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
        res.dw_excess_radps = round(_yaw_excess(dw[seg], vmax[seg]), 3)
        yaw_rate = (w[:, 1] * r[:, 1] - w[:, 0] * r[:, 0]) / (2.0 * out.half_track_m)
        res.heading_deviation_deg = round(
            math.degrees(_heading_deviation(yaw_rate[seg], vmax[seg], dt_s)), 2
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


def _yaw_excess(dw: np.ndarray, v: np.ndarray) -> float:
    """Largest excess of ``|wL - wR|`` over the curvature-keeping stop (rad/s).

    Keeping the curvature means both wheels shrink by the same factor, so the difference
    falls in proportion to the speed: ``dw(t) = dw(0) v(t) / v(0)``.  Equal decelerations
    keep ``dw`` constant instead while the chair slows: it turns onto a tighter arc.
    """
    if dw.size == 0 or v[0] <= 0.0:
        return 0.0
    return float(max(0.0, (dw - dw[0] * v / v[0]).max()))


def _heading_deviation(yaw_rate: np.ndarray, v: np.ndarray, dt_s: float) -> float:
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


# --------------------------------------------------------- real time, 3 processes


@dataclass
class RealtimeResult(Verdict):
    """A real-time run whose controller process got a signal, analysed in simulation time.

    ``last_setpoint_s``: simulation time of the controller's last setpoint before the drives
    tripped; every figure below is relative to it.
    """

    signal: str
    scenario: str
    last_setpoint_s: float | None = None
    v0_mps: float | None = None
    stop_ref_mps: float | None = None
    watchdog_in_heartbeat_s: float | None = None
    detection_limit_s: float = WATCHDOG_S + 2 * PERIOD_S
    standstill_s: float | None = None
    standstill_limit_s: float | None = None
    stop_distance_m: float | None = None
    stop_distance_limit_m: float | None = None
    dw_at_trip_radps: float | None = None
    dw_max_radps: float | None = None
    dw_excess_radps: float | None = None
    heading_deviation_deg: float | None = None
    still_to_end_s: float | None = None
    drives_idle_with_error_at_end: bool = False
    controller_final_state: str = ""
    #: False if the controller had already stopped by itself (its own safety monitors, or
    #: starved of CPU long enough for the drives' watchdogs) before the signal
    signalled: bool = True
    failures: list[str] = field(default_factory=list)


def _safety_toml(path: Path) -> Path:
    lines = ["# The safety profile (docs/safety.md) on top of controller/controller.toml", ""]
    for section, values in SAFETY_PROFILE.items():
        lines.append(f"[{section}]")
        lines += [
            f"{k} = {str(v).lower() if isinstance(v, bool) else v}" for k, v in values.items()
        ]
    lines.append("watchdog_timeout_ms = 100")
    path.write_text("\n".join(lines) + "\n")
    return path


def realtime_signal_run(
    out: Path,
    *,
    sig: str = "SIGKILL",
    scenario: str = "short",
    at_s: float = 5.0,
    stop_s: float = 1.5,
    duration_s: float = 9.0,
    rt_priority: int = 0,
) -> RealtimeResult:
    """Bench, controller (safety profile) and recorder as processes over udp_multicast in a
    private namespace (:class:`~tools.run.processes.SandboxedParts`), in real time; ``at_s``
    wall seconds after all are up the controller gets ``sig`` (SIGKILL, or SIGSTOP and
    ``stop_s`` later SIGCONT).  ``rt_priority`` > 0: the parts on SCHED_FIFO, as
    :func:`~tools.run.processes.realtime_parts` gives it.  Raises :class:`RuntimeError` if
    the processes fail."""

    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    cfg = _safety_toml(out / "safety.toml")
    parts = realtime_parts(
        out, scenario, duration_s, control=("--config", str(cfg)), rt_priority=rt_priority
    )
    try:
        with SandboxedParts(parts, out, timeout_s=duration_s * 4 + 60) as run:
            run.wait_started()
            time.sleep(at_s)
            pid = run.pid("control")
            if pid is None:
                raise PartFailedError("the controller never started")
            signalled = signal_part(
                pid, signal_mod.SIGKILL if sig == "SIGKILL" else signal_mod.SIGSTOP, *_CONTROL
            )
            if signalled and sig != "SIGKILL":
                time.sleep(stop_s)
                signal_part(pid, signal_mod.SIGCONT, *_CONTROL)
            run.wait()
    except PartFailedError as err:
        raise RuntimeError(f"real-time run failed: {err}") from err
    res = analyse_realtime_log(out / "run.mcap", sig=sig, scenario=scenario)
    res.signalled = signalled
    stats = out / "ctl" / "controller_stats.json"
    if stats.exists():
        res.controller_final_state = json.loads(stats.read_text()).get("final_state", "")
    if sig != "SIGKILL" and res.controller_final_state not in ("FAULT", ""):
        res.failures.append(f"the controller resumed into {res.controller_final_state}")
    return res


#: What the command line of the real-time runs' controller holds (:func:`signal_part`).
_CONTROL = (b"tools.cli", b"control")


def analyse_realtime_log(
    path: Path, *, sig: str = "SIGKILL", scenario: str = "short"
) -> RealtimeResult:
    """The figures of a real-time signal run from its recorder log, in simulation time."""

    codec = Codec.default()
    bcfg = load_bench_config({}, source="defaults")
    r_m = bcfg.chair.wheel_radius_m
    res = RealtimeResult(sig, scenario)
    t_sim = 0
    enc: dict[int, list[tuple[int, float]]] = {1: [], 2: []}
    hbs: list[tuple[int, int, int, int]] = []  # t, node, error, state
    sps: list[tuple[int, float]] = []  # t, stop ref rev/s
    for _t, msg in iter_frames(path):
        try:
            node, p = codec.decode(msg)
        except DecodeError:
            continue
        kind = type(p)
        if kind is BenchStep:
            t_sim = p.sim_time_ns
        elif kind is EncoderEstimates and node is not None:
            enc[int(node)].append((t_sim, p.vel_revps))
        elif kind is Heartbeat and node is not None:
            hbs.append((t_sim, int(node), p.axis_error, int(p.axis_state)))
        elif kind is SetInputVelAuth:
            sps.append((t_sim, p.stop_ref_revps))
    fail = res.failures
    trips = [h for h in hbs if h[2] & AxisError.WATCHDOG_TIMER_EXPIRED]
    if not trips or not sps:
        fail.append("no watchdog error in any drive heartbeat" if not trips else "no setpoints")
        return res
    t_trip = trips[0][0]
    before = [s for s in sps if s[0] <= t_trip]
    if not before:
        fail.append("no setpoint before the trip")
        return res
    t_last, ref = before[-1]
    res.last_setpoint_s = round(t_last * 1e-9, 3)
    res.watchdog_in_heartbeat_s = round((t_trip - t_last) * 1e-9, 3)
    if res.watchdog_in_heartbeat_s > res.detection_limit_s + 1e-9:
        fail.append(f"watchdog reported {res.watchdog_in_heartbeat_s} s after the last setpoint")
    # wheel rim speeds on a common time base (every Encoder_Estimates step)
    tl = np.array([t for t, _ in enc[1]], dtype=np.int64)
    vl = np.abs([v for _, v in enc[1]]) * 2 * math.pi * r_m
    tr_ = np.array([t for t, _ in enc[2]], dtype=np.int64)
    vr = np.abs([v for _, v in enc[2]]) * 2 * math.pi * r_m
    grid = np.intersect1d(tl, tr_)
    wl = np.interp(grid, tl, vl)
    wr = np.interp(grid, tr_, vr)
    sl = np.interp(grid, tl, [v for _, v in enc[1]])
    sr = np.interp(grid, tr_, [v for _, v in enc[2]])
    vmax = np.maximum(wl, wr)
    i0 = int(np.searchsorted(grid, t_last))
    v0 = float(vmax[i0])
    res.v0_mps = round(v0, 4)
    res.stop_ref_mps = round(ref * 2 * math.pi * r_m, 4)
    moving = np.flatnonzero(vmax >= STANDSTILL_MPS)
    j = int(moving[-1]) + 1 if moving.size else 0
    if j >= len(grid) or j <= i0:
        fail.append("the wheels were not at standstill at the end of the run")
        return res
    ref_mps = max(v0, res.stop_ref_mps)
    res.standstill_s = round(float(grid[j] - t_last) * 1e-9, 3)
    res.standstill_limit_s = round(WATCHDOG_S + ref_mps / A_STOP_MPS2 + 5 * PERIOD_S, 3)
    if res.standstill_s > res.standstill_limit_s:
        fail.append(f"standstill after {res.standstill_s} s > {res.standstill_limit_s} s")
    dt = np.diff(grid[i0 : j + 1]) * 1e-9
    dist = float(max((wl[i0:j] * dt).sum(), (wr[i0:j] * dt).sum()))
    res.stop_distance_m = round(dist, 4)
    res.stop_distance_limit_m = round(
        1.05 * (v0 * (WATCHDOG_S + 2 * PERIOD_S) + v0 * v0 / (2 * A_STOP_MPS2)), 4
    )
    if dist > res.stop_distance_limit_m:
        fail.append(f"stop distance {dist:.3f} m > {res.stop_distance_limit_m} m")
    dw = np.abs(sl - sr) * 2 * math.pi  # wheel rad/s
    it = int(np.searchsorted(grid, t_trip))
    res.dw_at_trip_radps = round(float(dw[it]), 3)
    res.dw_max_radps = round(float(dw[it:j].max()) if j > it else float(dw[it]), 3)
    res.dw_excess_radps = round(_yaw_excess(dw[it:j], vmax[it:j]), 3)
    if res.dw_excess_radps > YAW_TOL_RADPS:
        fail.append(
            f"|wL - wR| exceeded the curvature-keeping profile by {res.dw_excess_radps} rad/s"
        )
    yaw_rate = (sr - sl) * 2 * math.pi * r_m / bcfg.chair.wheel_separation_m
    seg = slice(it, max(j, it + 1))
    dt_grid = float(np.median(np.diff(grid))) * 1e-9 if len(grid) > 1 else PERIOD_S
    res.heading_deviation_deg = round(
        math.degrees(_heading_deviation(yaw_rate[seg], vmax[seg], dt_grid)), 2
    )
    if abs(res.heading_deviation_deg) > HEADING_TOL_DEG:
        fail.append(f"the heading left the arc by {res.heading_deviation_deg} deg")
    res.still_to_end_s = round(float(grid[-1] - grid[j]) * 1e-9, 3)
    if res.still_to_end_s < 1.0:
        fail.append(f"standstill observed for only {res.still_to_end_s} s")
    last = {n: h for h in hbs for n in (h[1],)}
    res.drives_idle_with_error_at_end = all(
        n in last and last[n][3] == 1 and last[n][2] & AxisError.WATCHDOG_TIMER_EXPIRED
        for n in (1, 2)
    )
    if not res.drives_idle_with_error_at_end:
        fail.append("the drives are not idle with the watchdog error latched at the end")
    return res
