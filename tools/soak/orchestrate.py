"""The soak's processes and the schedule carried out on them, inside a private namespace.

It owns the run's layout and its moments: one bench (``sim``) for the whole soak; a recorder
(``record``), restarted with a new log whenever a scheduled signal (or anything else) ends it;
controllers (``control``) one after another, each on the next packaged route moved to start
where the chair stands (the bench's truth pose), so that the chair drives route after route;
one attacking node per scheduled attack (:func:`tools.safety.attacks.attacker.attacker_part`, from
12 s before its onset to 2 s after its attack), and the
faults sent as Bench_Fault_Commands (:func:`tools.run.inject.fault_command`) at their
simulation time.  The parts are the project's (:func:`tools.run.processes.realtime_parts`,
:class:`~tools.run.processes.Parts`); this module only decides when each starts, is
signalled or is replaced, samples every part's memory once a second, and writes what it did
to ``orchestration.json`` for :mod:`tools.soak.analyse`.

Directory layout (``out``)::

    schedule.json          the schedule, written before anything starts
    orchestration.json     what was done when (simulation and wall time), parts, memory samples
    sim/                   the bench's statistics
    rec-NN/run.mcap        the NN-th recorder's log (and recorder_stats.json when it ended cleanly)
    leg-NN/                the NN-th controller: route.toml, scenario, controller.toml, ctl/
    attack-NN/             the NN-th attacker's output

Over udp_multicast it must run in a private network namespace
(:func:`tools.bus.transport.in_private_namespace`): :func:`run` refuses otherwise; over
socketcan (the user-mode Linux guest's vcan0, a chair's bench bus) it runs where it is.
Nothing here prints.
"""

from __future__ import annotations

import dataclasses
import json
import math
import signal
import threading
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dbc.codec import BenchEnd, BenchStep, Codec, TruthPose, TruthTwist
from dbc.errors import DecodeError
from dbc.runtime import stopping
from dbc.runtime.errors import BusError
from tools.bus import transport
from tools.run import scenario as scenario_mod
from tools.run.inject import fault_command
from tools.run.processes import Part, PartFailedError, Parts, realtime_parts, signal_part
from tools.safety.attacks.attacker import attacker_part
from tools.safety.attacks.runs import write_configs
from tools.soak.schedule import Event, Schedule

#: The packaged routes driven in turn (scenarios/routes).
ROUTES: tuple[str, ...] = ("short", "paper", "short-pause")
#: A new controller is started only if this much simulation time is left (s): less cannot
#: arm and track.
MIN_LEG_S = 15.0
#: Wall seconds a signalled part may take to end before it is killed.
PART_END_S = 10.0
#: Wall seconds the parts may take to end after the bench has.
DRAIN_S = 60.0
#: The chair stands still below these (m/s, rad/s) ...
STILL_MPS, STILL_RADPS = 0.01, 0.02
#: ... and a new controller starts once it has stood still this long (s of simulation
#: time), or this long (wall s) after the last controller ended, whichever comes first.
SETTLED_S, SETTLE_WAIT_S = 0.5, 5.0
#: An attacker starts this long before its onset and is stopped this long after its
#: attack (s of simulation time).
ATTACKER_LEAD_S, ATTACKER_TAIL_S = 12.0, 2.0
#: What an attacker's command line holds (signal_part checks it: never a recycled PID).
_ATTACKER_WORDS = (b"tools.safety.attacks", b"attacker")
#: Wall seconds between two memory samples.
SAMPLE_S = 1.0

ORCHESTRATION = "orchestration.json"
SCHEDULE = "schedule.json"


@dataclass(frozen=True)
class SoakOptions:
    """What the user chose."""

    schedule: Schedule
    out: Path
    auth: bool = True
    controller: str = "antifragile"
    routes: tuple[str, ...] = ROUTES
    rt_priority: int = 0
    #: python-can interface and channel of every part: udp_multicast (inside a private
    #: namespace), or socketcan (e.g. vcan0 in the user-mode Linux guest)
    interface: str = "udp_multicast"
    channel: str | None = None

    @property
    def bus_options(self) -> tuple[str, ...]:
        """The parts' bus options on their command lines."""
        channel = ("--channel", self.channel) if self.channel else ()
        return ("--bus", self.interface, *channel)


@dataclass
class Instance:
    """One process the soak started: its part, directory, PID and how it ended."""

    part: str  # sim, record, control, attacker
    index: int
    dir: str
    pid: int | None = None
    start_sim_s: float | None = None
    start_wall_s: float = 0.0
    end_sim_s: float | None = None
    end_wall_s: float | None = None
    exit_code: int | None = None
    #: the signal the soak sent it (SIGTERM, SIGKILL) and at what simulation time
    signalled: str = ""
    signalled_sim_s: float | None = None
    route: str = ""

    @property
    def name(self) -> str:
        return self.part if self.part == "sim" else f"{self.part}-{self.index}"


@dataclass
class Done:
    """One scheduled event as carried out."""

    event: Event
    sim_s: float | None
    wall_s: float
    ok: bool
    detail: str = ""
    #: the instance a signal was sent to (``control-3``)
    target: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {
            **self.event.as_dict(),
            "done_sim_s": self.sim_s,
            "done_wall_s": self.wall_s,
            "ok": self.ok,
            "detail": self.detail,
            "target": self.target,
        }


@dataclass
class Orchestration:
    """What :func:`run` did: ``orchestration.json``."""

    auth: bool
    controller: str
    duration_s: float
    instances: list[Instance] = field(default_factory=list)
    done: list[Done] = field(default_factory=list)
    #: (wall s, simulation s or None, instance name, RSS KiB)
    rss: list[tuple[float, float | None, str, int]] = field(default_factory=list)
    ended_by: str = ""
    #: the simulation time at which a stop signal ended the soak early
    stopped_sim_s: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            "auth": self.auth,
            "controller": self.controller,
            "duration_s": self.duration_s,
            "ended_by": self.ended_by,
            "stopped_sim_s": self.stopped_sim_s,
            "instances": [dataclasses.asdict(i) | {"name": i.name} for i in self.instances],
            "events": [d.as_dict() for d in self.done],
            "rss": [list(r) for r in self.rss],
        }


class _Listener:
    """The bench's clock and the chair's true pose, heard on the bus by a thread."""

    def __init__(self, bus: Any, codec: Codec) -> None:
        self._bus = bus
        self._codec = codec
        self.sim_ns: int | None = None
        self.pose: tuple[float, float, float] | None = None
        #: the simulation time (ns) since which the chair has stood still (None: moving)
        self.still_since_ns: int | None = None
        self.ended = threading.Event()
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._pump, name="soak listener", daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        while not self._halt.is_set():
            try:
                msg = self._bus.recv(0.2)
            except Exception:  # a receive error must not end the soak: the parts count theirs
                continue
            if msg is None or not msg.is_extended_id:
                continue
            try:
                p = self._codec.decode(msg).payload
            except DecodeError:
                continue
            if type(p) is BenchStep:
                self.sim_ns = p.sim_time_ns
            elif type(p) is TruthPose:
                self.pose = (p.x_m, p.y_m, p.heading_rad)
            elif type(p) is TruthTwist:
                still = abs(p.v_mps) < STILL_MPS and abs(p.omega_radps) < STILL_RADPS
                if not still:
                    self.still_since_ns = None
                elif self.still_since_ns is None:
                    self.still_since_ns = self.sim_ns
            elif type(p) is BenchEnd:
                self.ended.set()

    @property
    def sim_s(self) -> float | None:
        return None if self.sim_ns is None else self.sim_ns / 1e9

    def close(self) -> None:
        self._halt.set()
        self._thread.join(2.0)


def moved_route(route_file: Path, pose: tuple[float, float, float] | None) -> str:
    """The route in ``route_file`` as TOML, turned and shifted so that it starts at ``pose``
    (x m, y m, heading rad) facing its start heading; unchanged for ``None``."""
    table = tomllib.loads(route_file.read_text())
    if pose is not None:
        pts = [tuple(map(float, w)) for w in table["waypoints_m"]]
        x0, y0 = pts[0]
        h0 = table.get("start_heading_rad")
        if h0 is None:
            h0 = math.atan2(pts[1][1] - y0, pts[1][0] - x0)
        rot = pose[2] - float(h0)
        c, s = math.cos(rot), math.sin(rot)
        table["waypoints_m"] = [
            [
                round(pose[0] + c * (x - x0) - s * (y - y0), 4),
                round(pose[1] + s * (x - x0) + c * (y - y0), 4),
            ]
            for x, y in pts
        ]
        table["start_heading_rad"] = round(math.atan2(math.sin(pose[2]), math.cos(pose[2])), 6)
    # every value of a route is a number or a list of numbers: JSON writes them as TOML does
    return "".join(f"{k} = {json.dumps(v)}\n" for k, v in table.items())


class _Soak:
    def __init__(self, opts: SoakOptions, parts: Parts, listener: _Listener, bus: Any) -> None:
        self.opts = opts
        self.out = opts.out
        self.parts = parts
        self.listener = listener
        self.bus = bus
        self.codec = Codec.default()
        self.t0 = time.monotonic()
        self.orch = Orchestration(opts.auth, opts.controller, opts.schedule.duration_s)
        self.recorder: Instance | None = None
        self.controller: Instance | None = None
        self.bench: Instance | None = None
        self.legs = 0

    # ------------------------------------------------------------- helpers

    def wall(self) -> float:
        return time.monotonic() - self.t0

    def _start(self, inst: Instance, part: Part) -> None:
        part = dataclasses.replace(part, name=inst.name)
        inst.start_wall_s = self.wall()
        inst.start_sim_s = self.listener.sim_s
        self.orch.instances.append(inst)
        proc = self.parts.start(part)
        inst.pid = proc.pid

    def _leg_parts(
        self, k: int, pose: tuple[float, float, float] | None
    ) -> tuple[Path, list[Part]]:
        """Recorder-less parts of controller leg ``k`` (its scenario, route and config
        written into ``leg-k``), starting the route at ``pose``."""
        d = self.out / f"leg-{k:02d}"
        d.mkdir(parents=True, exist_ok=True)
        name = self.opts.routes[(k - 1) % len(self.opts.routes)]
        route = d / "route.toml"
        route.write_text(moved_route(scenario_mod.route_file(name), pose))
        scen = d / "soak-leg.toml"
        scen.write_text(
            f'[scenario]\nname = "soak-leg-{k}"\nroute = "{route}"\n'
            f"seed = {self.opts.schedule.seed}\ntail_s = 2.0\n"
        )
        ctl_cfg, scen_auth = write_configs(d, self.opts.auth, str(scen))
        left = max(self.opts.schedule.duration_s - (self.listener.sim_s or 0.0), MIN_LEG_S)
        parts = realtime_parts(
            d,
            str(scen_auth),
            left,
            control=("--controller", self.opts.controller, "--config", str(ctl_cfg)),
            rt_priority=self.opts.rt_priority,
            bus=self.opts.bus_options,
        )
        return d, parts

    def _start_leg(self, pose: tuple[float, float, float] | None) -> list[Part]:
        """Start the next controller; all the parts of its leg (the first leg's bench
        is the soak's)."""
        self.legs += 1
        d, parts = self._leg_parts(self.legs, pose)
        ctl = next(p for p in parts if p.name == "control")
        inst = Instance("control", self.legs, str(d))
        inst.route = self.opts.routes[(self.legs - 1) % len(self.opts.routes)]
        # a replacement does not hold the soak up until it is READY: the schedule goes on
        self._start(inst, ctl if self.legs == 1 else dataclasses.replace(ctl, ready=False))
        self.controller = inst
        return parts

    def _start_recorder(self, first: bool) -> None:
        k = 1 + sum(1 for i in self.orch.instances if i.part == "record")
        d = self.out / f"rec-{k:02d}"
        d.mkdir(parents=True, exist_ok=True)
        rec = realtime_parts(
            d, "short", 0.0, rt_priority=self.opts.rt_priority, bus=self.opts.bus_options
        )[0]
        inst = Instance("record", k, str(d))
        self._start(inst, rec if first else dataclasses.replace(rec, ready=False))
        self.recorder = inst

    def _ended(self, inst: Instance | None) -> bool:
        if inst is None or inst.exit_code is not None:
            return inst is not None
        code = self.parts.procs[inst.name].poll()
        if code is None:
            return False
        inst.exit_code = code
        inst.end_wall_s = self.wall()
        inst.end_sim_s = self.listener.sim_s
        return True

    def _signal(self, inst: Instance | None, sig: signal.Signals, word: bytes) -> str:
        if inst is None or inst.pid is None or self._ended(inst):
            return f"no {word.decode()} running"
        if not signal_part(inst.pid, sig, b"tools.cli", word):
            return f"{inst.name} had already ended"
        inst.signalled = sig.name
        inst.signalled_sim_s = self.listener.sim_s
        proc = self.parts.procs[inst.name]
        try:
            proc.wait(PART_END_S)
        except Exception:
            proc.kill()
            proc.wait()
        self._ended(inst)
        return f"{sig.name} to {inst.name} (pid {inst.pid}), exit {inst.exit_code}"

    # ------------------------------------------------------------ the events

    def _do(self, ev: Event) -> Done:
        sim_s, wall = self.listener.sim_s, self.wall()
        try:
            if ev.action == "fault":
                cmd = fault_command(ev.fault_table(), source=f"soak event {ev.describe()}")
                self.bus.send(self.codec.encode(cmd))
                return Done(ev, sim_s, wall, True, "Bench_Fault_Command sent")
            if ev.action == "signal":
                if ev.kind == "control-term":
                    # the replacement starts in the main loop, from where the chair stands
                    target = self.controller
                    why = self._signal(target, signal.SIGTERM, b"control")
                else:
                    target = self.recorder
                    sig = signal.SIGKILL if ev.kind == "record-kill" else signal.SIGTERM
                    why = self._signal(target, sig, b"record")
                    self._start_recorder(first=False)
                    why += "; restarted"
                name = target.name if target is not None else ""
                return Done(ev, sim_s, wall, why.startswith("SIG"), why, name)
            # attack: its node was started with the bench and acts from its onset on
            return Done(ev, sim_s, wall, True, "attacker acting from its onset")
        except Exception as err:  # an event that failed is reported, never ends the soak
            return Done(ev, sim_s, wall, False, f"{type(err).__name__}: {err}")

    def _chair_settled(self) -> bool:
        """Whether the next controller may start: the chair has stood still for SETTLED_S
        (the last one's stop ramp is over and the drives have disarmed, so that the new
        host re-arms them from rest and its route starts where the chair stands), or
        SETTLE_WAIT_S have passed since the last controller ended (a chair that a fault
        keeps moving: the new host's arming is then judged as it is)."""
        ctl = self.controller
        if ctl is None or ctl.end_wall_s is None:
            return True
        since = self.listener.still_since_ns
        sim_ns = self.listener.sim_ns
        if since is not None and sim_ns is not None and sim_ns - since >= SETTLED_S * 1e9:
            return True
        return self.wall() - ctl.end_wall_s >= SETTLE_WAIT_S

    def _sample(self) -> None:
        sim_s, wall = self.listener.sim_s, self.wall()
        for inst in self.orch.instances:
            if inst.exit_code is not None or inst.pid is None:
                continue
            kib = rss_kib(inst.pid)
            if kib is not None:
                self.orch.rss.append((round(wall, 2), sim_s, inst.name, kib))

    def _start_attackers(
        self, to_start: list[Event], started: list[tuple[Instance, float]], sim_s: float
    ) -> None:
        """Start the attackers whose onset is less than ATTACKER_LEAD_S away (a replay needs
        the host's setpoints of the 7 s before it)."""
        while to_start and to_start[0].at_s - ATTACKER_LEAD_S <= sim_s:
            ev = to_start.pop(0)
            k = len(started) + 1
            d = self.out / f"attack-{k:02d}"
            d.mkdir(parents=True, exist_ok=True)
            part = attacker_part(
                d,
                ev.kind,
                ev.at_s,
                auth=self.opts.auth,
                rt_priority=self.opts.rt_priority,
                bus=self.opts.bus_options,
            )
            inst = Instance("attacker", k, str(d))
            self._start(inst, part)
            started.append((inst, ev.end_s + ATTACKER_TAIL_S))

    def _stop_attackers(self, started: list[tuple[Instance, float]], sim_s: float) -> None:
        """SIGINT to the attackers whose attack is over (each writes its figures and ends):
        an attacker listens to every frame, and a long soak would pile them up."""
        for inst, until in started:
            if self._ended(inst):  # notes its end
                continue
            due = sim_s >= until and not inst.signalled
            if due and inst.pid and signal_part(inst.pid, signal.SIGINT, *_ATTACKER_WORDS):
                inst.signalled = "SIGINT"
                inst.signalled_sim_s = sim_s

    # --------------------------------------------------------------- the run

    def run(self, stop: threading.Event) -> Orchestration:
        sched = self.opts.schedule
        (self.out / "sim").mkdir(parents=True, exist_ok=True)
        self._start_recorder(first=True)
        # each attacker from ATTACKER_LEAD_S before its onset to ATTACKER_TAIL_S after its end
        to_start = [e for e in sched.events if e.action == "attack"]
        attackers: list[tuple[Instance, float]] = []
        self._start_attackers(to_start, attackers, 0.0)
        sim_part = next(p for p in self._start_leg(None) if p.name == "sim")
        sim_part = dataclasses.replace(
            sim_part,
            argv=(
                *_with_option(sim_part.argv, "--out", str(self.out / "sim")),
                *("--seed", str(sched.seed)),
            ),
            log=str(self.out / "sim" / "sim.err"),
            out=str(self.out / "sim" / "sim.out"),
        )
        self.bench = Instance("sim", 0, str(self.out / "sim"))
        self._start(self.bench, sim_part)
        pending = list(sched.events)
        next_sample = 0.0
        while not self._ended(self.bench):
            if stop.is_set():
                self.orch.ended_by = "stopped by a signal"
                self.orch.stopped_sim_s = self.listener.sim_s
                break
            sim_s = self.listener.sim_s
            while pending and sim_s is not None and pending[0].at_s <= sim_s:
                self.orch.done.append(self._do(pending.pop(0)))
            if sim_s is not None:
                self._start_attackers(to_start, attackers, sim_s)
                self._stop_attackers(attackers, sim_s)
            time_left = sim_s is not None and sched.duration_s - sim_s >= MIN_LEG_S
            if (
                self._ended(self.controller)
                and not self.listener.ended.is_set()
                and time_left
                and self._chair_settled()
            ):
                self._start_leg(self.listener.pose)
            if self._ended(self.recorder) and not self.listener.ended.is_set():
                self._start_recorder(first=False)  # it ended by itself: a new log
            if self.wall() >= next_sample:
                next_sample = self.wall() + SAMPLE_S
                self._sample()
            time.sleep(0.02)
        self.orch.ended_by = self.orch.ended_by or "the bench ended"
        for ev in pending:
            self.orch.done.append(Done(ev, None, self.wall(), False, "not reached"))
        deadline = time.monotonic() + (0.0 if stop.is_set() else DRAIN_S)
        while time.monotonic() < deadline and not all(self._ended(i) for i in self.orch.instances):
            time.sleep(0.1)
        return self.orch


def _with_option(argv: tuple[str, ...], option: str, value: str) -> tuple[str, ...]:
    """``argv`` with ``option``'s value replaced by ``value``."""
    out = list(argv)
    out[out.index(option) + 1] = value
    return tuple(out)


def rss_kib(pid: int) -> int | None:
    """Resident memory of process ``pid`` (KiB; None once it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def run(opts: SoakOptions) -> Orchestration:
    """Carry out ``opts.schedule`` (already in ``out/schedule.json``); ``orchestration.json``
    is written however the run ends.  BusError for udp_multicast outside a private network
    namespace."""
    if opts.interface == "udp_multicast" and not transport.in_private_namespace():
        raise BusError("the soak opens udp_multicast only inside a private network namespace")
    spec = transport.resolve(opts.interface, opts.channel)
    codec = Codec.default()
    listen = transport.open_bus(spec)
    send = transport.open_bus(spec)
    listener = _Listener(listen, codec)
    soak: _Soak | None = None
    try:
        with Parts(pid_dir=None, ready_timeout_s=180.0) as parts:
            soak = _Soak(opts, parts, listener, send)
            try:
                soak.run(stopping.stop_event())
            except PartFailedError as err:  # a part that did not start: the report says so
                soak.orch.ended_by = f"a part failed: {err}"
        # leaving Parts stopped whatever still ran: every part's exit code is known now
        for inst in soak.orch.instances:
            if inst.exit_code is None:
                inst.exit_code = parts.procs[inst.name].poll()
                inst.end_wall_s = soak.wall()
            if inst.end_sim_s is None:
                inst.end_sim_s = listener.sim_s
        return soak.orch
    finally:
        listener.close()
        listen.shutdown()
        send.shutdown()
        if soak is not None:
            (opts.out / ORCHESTRATION).write_text(json.dumps(soak.orch.as_dict(), indent=1) + "\n")
