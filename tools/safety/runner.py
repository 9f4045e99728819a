"""The safety suite's in-process runner: one case, bench and controller in lock-step.

:func:`run_case` runs the bench and the controller in lock-step on python-can's virtual bus
inside this process (deterministic, simulation time) on the short route with the baseline
controller and the *safety profile* (:data:`~tools.safety.cases.SAFETY_PROFILE`:
authenticated setpoints, neutral start, host-heartbeat monitor), and injects the case's fault
at its onset.  Controller process faults go through a clock shim (:class:`_FaultClock`):
killed, frozen with its last frame re-sent, stalled for N periods.  A killed or stalled
controller runs no tick and sends nothing; the shim still acknowledges ``Bench_Step`` (the
bench's clock protocol, not chair traffic) so that the run stays deterministic and fast.  The
real process is killed in the multi-process real-time tests
(:func:`tools.safety.realtime.realtime_signal_run`).  A case may also jump the wall clock
(``time.time`` patched for the run, :func:`_wall_clock_jump`).

Ground truth is sampled at the drives' 1 kHz tick (wheel speeds, contact radii, each drive's
stop, errors and last accepted setpoint), the host's state at every tick and the drives'
heartbeats on the bus, into a :class:`RunOutput` that :func:`tools.safety.criteria.analyse`
reduces.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import math
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar
from unittest import mock

import can

from controller.clock import LockstepClock
from controller.config import ControllerConfig, load_config
from controller.limits import LimitedCommand
from controller.node import ControllerNode
from controller.types import TwistCommand
from dbc.codec import (
    BenchStep,
    Codec,
    Heartbeat,
    HostState,
    Node,
    SetInputVel,
    SetInputVelAuth,
)
from dbc.errors import DecodeError
from dbc.runtime import params
from firmware_sim import busfaults as bf
from firmware_sim.config import load_bench_config
from firmware_sim.faultspec import parse_schedule
from tools.bus.transport import open_bus, resolve
from tools.logs.recorder import BusRecorder
from tools.run import build
from tools.run import scenario as scenario_mod
from tools.run.plan import make_plan
from tools.safety.cases import SAFETY_PROFILE, Ctx, HostFault, SafetyCase

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
            tr.host_holding.append(node.safe_stop.hold is not None)
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
