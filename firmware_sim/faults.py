"""Fault models of the bench: the plant, sensors, actuators and the bus, on a schedule or live.

This module owns what a fault *does* on the bench: the physical model each fault applies to
the simulated chair, and :class:`FaultManager`, which activates and clears faults at simulation time (scheduled, or
commanded live by ``Bench_Fault_Command`` frames) and reports every change as a
``Bench_Fault_Event``.  docs/faults.md explains each model; one line each:

* ``flat-tire``: the wheel's rolling radius decays exponentially from nominal to
  ``to_radius_m`` with ``time_constant_s`` (0 = a step); cleared = re-inflated at once;
* ``shaft-bump``: an eccentric wheel: the rolling radius is ``r + a sin(theta - theta_on + phase)``
  with ``a`` = ``amplitude_m``, one period per wheel revolution, synchronous with the wheel angle;
* ``slip``: a longitudinal slip ratio ``s`` on one or both wheels: ground distance per wheel
  radian ``rho (1 - s)``;
* ``encoder-noise`` / ``encoder-stuck`` / ``encoder-scale``: act on the quadrature count the
  drive samples (so the drive's own velocity loop sees them too): Gaussian count noise,
  a frozen count, ``c0 + scale (c - c0)`` from the onset;
* ``encoder-dropout``: each cyclic ``Get_Encoder_Estimates`` frame is lost with ``probability``;
* ``localizer-dropout`` / ``localizer-bias`` / ``localizer-heading-bias``: pose fixes lost with
  ``probability``, or offset by a constant world-frame vector or heading;
* ``torque-loss``: the motor's torque is multiplied by ``gain``; ``dead-motor``: an open
  winding, no current and no torque (the drive does not notice);
* ``bus-drop`` / ``bus-delay`` / ``bus-duplicate`` / ``bus-reorder`` / ``bus-corrupt`` /
  ``node-silent``: rules of :mod:`firmware_sim.busfaults` on the bench's bus;
  ``node-reboot``: the drive reboots (silent for its boot time) as after a supply glitch.

What a fault is (its kind and typed parameters, the ``[[faults]]`` schedule, the frames that
carry it) is :mod:`firmware_sim.faultspec`'s.  Every fault has ``onset_s`` (simulation time)
and ``duration_s`` (0 = until cleared), and a
private ``random.Random`` seeded from the run seed and its fault ID, so a lock-step run with
the same seed is identical.  Fault hooks never raise into the bench loop beyond
:meth:`ChairSim.advance`, which the bench already turns into a clean abort.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from dbc.codec import Codec, FaultAction, FaultCommand, FaultEvent, FaultSide, FaultState, FaultType
from dbc.runtime.errors import ConfigError
from firmware_sim import busfaults as bf
from firmware_sim.faultspec import (
    KINDS,
    NODE_IDS,
    SIDES,
    DeadMotorParams,
    EncoderDropoutParams,
    FaultSpec,
    FlatTireParams,
    NodeRebootParams,
    ShaftBumpParams,
    SlipParams,
    TorqueLossParams,
    spec_from_command,
)
from firmware_sim.plant import Wheel
from firmware_sim.sim import ChairSim

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- models


class _Model:
    """A fault acting on the simulated chair between :meth:`start` and :meth:`stop`."""

    plant = False  # changes Wheel seams every tick (see FaultManager._apply_plant)
    instantaneous = False  # cleared as soon as it has acted (a reboot)

    def start(self, now_ns: int) -> None:
        pass

    def stop(self, now_ns: int) -> None:
        pass

    def apply(self, t_ns: int) -> None:
        pass


def _wheels(sim: ChairSim, side: str) -> list[Wheel]:
    p = sim.plant
    return {"left": [p.left], "right": [p.right], "both": [p.left, p.right]}[side]


class _FlatTire(_Model):
    plant = True

    def __init__(self, sim: ChairSim, p: FlatTireParams) -> None:
        self.wheels = _wheels(sim, p.side)
        self.r0 = sim.config.chair.wheel_radius_m
        self.r1 = p.to_radius_m
        self.inv_tau_ns = 1e-9 / p.time_constant_s if p.time_constant_s > 0 else math.inf
        self.on_ns = 0

    def start(self, now_ns: int) -> None:
        self.on_ns = now_ns

    def apply(self, t_ns: int) -> None:
        k = (t_ns - self.on_ns) * self.inv_tau_ns
        r = self.r1 + (self.r0 - self.r1) * (math.exp(-k) if k < 700.0 else 0.0)
        for w in self.wheels:
            w.radius_m = r


class _ShaftBump(_Model):
    plant = True

    def __init__(self, sim: ChairSim, p: ShaftBumpParams) -> None:
        self.wheels = _wheels(sim, p.side)
        self.a = p.amplitude_m
        self.phase = p.phase_rad
        self.theta_on: list[float] = []

    def start(self, now_ns: int) -> None:
        self.theta_on = [w.angle_rad for w in self.wheels]

    def apply(self, t_ns: int) -> None:
        for w, th0 in zip(self.wheels, self.theta_on, strict=True):
            w.radius_offset_m += self.a * math.sin(w.angle_rad - th0 + self.phase)


class _Slip(_Model):
    plant = True

    def __init__(self, sim: ChairSim, p: SlipParams) -> None:
        self.wheels = _wheels(sim, p.side)
        self.keep = 1.0 - p.ratio

    def apply(self, t_ns: int) -> None:
        for w in self.wheels:
            w.slip_ratio = 1.0 - (1.0 - w.slip_ratio) * self.keep


class _TorqueLoss(_Model):
    plant = True

    def __init__(self, sim: ChairSim, p: TorqueLossParams | DeadMotorParams) -> None:
        self.wheels = _wheels(sim, p.side)
        self.gain = p.gain if isinstance(p, TorqueLossParams) else 0.0
        self.open = isinstance(p, DeadMotorParams)

    def apply(self, t_ns: int) -> None:
        for w in self.wheels:
            w.torque_gain *= self.gain
            if self.open:
                w.motor_open = True


class _EncoderFault(_Model):
    """Count filters; the manager composes the active ones per encoder."""

    def __init__(self, sim: ChairSim, spec: FaultSpec, rng: random.Random) -> None:
        side = spec.side or "left"
        self.encoders = [
            d.encoder for s, d in (("left", sim.left), ("right", sim.right)) if side in (s, "both")
        ]
        p = spec.params
        self.kind = spec.kind
        self.sigma = getattr(p, "sigma_counts", 0.0)
        self.scale = getattr(p, "scale", 1.0)
        self.rng = rng
        self.c0: dict[int, int] = {}

    def filter(self, key: int, count: int) -> int:
        if self.kind == "encoder-noise":
            return count + round(self.rng.gauss(0.0, self.sigma))
        c0 = self.c0.setdefault(key, count)
        if self.kind == "encoder-stuck":
            return c0
        return c0 + round(self.scale * (count - c0))


class _EncoderDropout(_Model):
    def __init__(self, sim: ChairSim, p: EncoderDropoutParams, rng: random.Random) -> None:
        self.drives = [
            d for s, d in (("left", sim.left), ("right", sim.right)) if p.side in (s, "both")
        ]
        self.p = p.probability
        self.rng = rng

    def drop(self) -> bool:
        return self.rng.random() < self.p

    def start(self, now_ns: int) -> None:
        for d in self.drives:
            d.drop_estimates = self.drop

    def stop(self, now_ns: int) -> None:
        for d in self.drives:
            if d.drop_estimates == self.drop:
                d.drop_estimates = None


class _LocalizerFault(_Model):
    def __init__(self, sim: ChairSim, spec: FaultSpec, rng: random.Random) -> None:
        self.loc = sim.localizer
        p = spec.params
        self.kind = spec.kind
        self.p = getattr(p, "probability", 0.0)
        self.rng = rng
        if spec.kind == "localizer-bias":
            self.bias = (
                p.offset_m * math.cos(p.direction_rad),
                p.offset_m * math.sin(p.direction_rad),
                0.0,
            )
        elif spec.kind == "localizer-heading-bias":
            self.bias = (0.0, 0.0, p.bias_rad)
        else:
            self.bias = (0.0, 0.0, 0.0)

    def drop(self) -> bool:
        return self.rng.random() < self.p

    def start(self, now_ns: int) -> None:
        loc = self.loc
        if loc is None:
            return
        if self.kind == "localizer-dropout":
            loc.drop = self.drop
        else:
            bx, by, bh = loc.bias
            loc.bias = (bx + self.bias[0], by + self.bias[1], bh + self.bias[2])

    def stop(self, now_ns: int) -> None:
        loc = self.loc
        if loc is None:
            return
        if self.kind == "localizer-dropout":
            if loc.drop == self.drop:
                loc.drop = None
        else:
            bx, by, bh = loc.bias
            loc.bias = (bx - self.bias[0], by - self.bias[1], bh - self.bias[2])


class _BusFault(_Model):
    def __init__(self, spec: FaultSpec, bus: bf.FaultInjectingBus | None, codec: Codec) -> None:
        self.bus = bus
        self.handle: int | None = None
        p = spec.params
        if spec.kind == "node-silent":
            match = bf.FrameMatch(nodes=frozenset({NODE_IDS[p.node]}))
            direction = bf.Direction.BOTH
        else:
            ids = frozenset(codec.frame_key(n) for n in p.frames)
            match = bf.FrameMatch(ids=ids)
            direction = {
                "send": bf.Direction.SEND,
                "recv": bf.Direction.RECV,
                "both": bf.Direction.BOTH,
            }[p.direction]
        self.rule: bf.Rule = (
            bf.Silence(match=match, direction=direction)
            if spec.kind == "node-silent"
            else p.rule_for(match, direction)
        )

    def start(self, now_ns: int) -> None:
        if self.bus is not None:
            self.handle = self.bus.add_rule(dataclasses.replace(self.rule, start_ns=now_ns))

    def stop(self, now_ns: int) -> None:
        if self.bus is not None and self.handle is not None:
            self.counters = self.bus.remove_rule(self.handle)
            self.handle = None


class _NodeReboot(_Model):
    instantaneous = True

    def __init__(self, sim: ChairSim, p: NodeRebootParams) -> None:
        self.drive = sim.left if p.node == "left" else sim.right

    def start(self, now_ns: int) -> None:
        self.drive.reboot(now_ns)


# ---------------------------------------------------------------------------- manager


@dataclass(frozen=True)
class _Context:
    """What a fault's model is built from."""

    sim: ChairSim
    spec: FaultSpec
    rng: random.Random
    bus: bf.FaultInjectingBus | None
    codec: Codec


#: Each fault kind's model, one entry per kind of :data:`firmware_sim.faultspec.KINDS` (what
#: a fault is, its parameters and frames): a kind is added there and here, and this module
#: refuses to load while the two tables differ.
MODELS: dict[str, Callable[[_Context], _Model]] = {
    "flat-tire": lambda c: _FlatTire(c.sim, c.spec.params),
    "shaft-bump": lambda c: _ShaftBump(c.sim, c.spec.params),
    "slip": lambda c: _Slip(c.sim, c.spec.params),
    "encoder-noise": lambda c: _EncoderFault(c.sim, c.spec, c.rng),
    "encoder-stuck": lambda c: _EncoderFault(c.sim, c.spec, c.rng),
    "encoder-scale": lambda c: _EncoderFault(c.sim, c.spec, c.rng),
    "encoder-dropout": lambda c: _EncoderDropout(c.sim, c.spec.params, c.rng),
    "localizer-dropout": lambda c: _LocalizerFault(c.sim, c.spec, c.rng),
    "localizer-bias": lambda c: _LocalizerFault(c.sim, c.spec, c.rng),
    "localizer-heading-bias": lambda c: _LocalizerFault(c.sim, c.spec, c.rng),
    "torque-loss": lambda c: _TorqueLoss(c.sim, c.spec.params),
    "dead-motor": lambda c: _TorqueLoss(c.sim, c.spec.params),
    "bus-drop": lambda c: _BusFault(c.spec, c.bus, c.codec),
    "bus-delay": lambda c: _BusFault(c.spec, c.bus, c.codec),
    "bus-duplicate": lambda c: _BusFault(c.spec, c.bus, c.codec),
    "bus-reorder": lambda c: _BusFault(c.spec, c.bus, c.codec),
    "bus-corrupt": lambda c: _BusFault(c.spec, c.bus, c.codec),
    "node-silent": lambda c: _BusFault(c.spec, c.bus, c.codec),
    "node-reboot": lambda c: _NodeReboot(c.sim, c.spec.params),
}
if set(MODELS) != set(KINDS):
    raise ImportError(
        f"firmware_sim.faults.MODELS and faultspec.KINDS differ: {sorted(set(MODELS) ^ set(KINDS))}"
    )


@dataclass
class ActiveFault:
    """A fault in force: its ID, spec, onset and end (ns; None: until cleared), its model."""

    fault_id: int
    spec: FaultSpec
    on_ns: int
    end_ns: int | None
    model: _Model


class FaultManager:
    """Activates, applies and clears faults on a :class:`ChairSim`, and reports them.

    ``schedule`` faults get IDs 1..n in order; live ones the next free ID.  The manager hooks
    into the simulation's 1 kHz tick (onsets and ends are tick-exact) and the bench calls
    :meth:`on_step` at every step boundary before it publishes, and :meth:`take_events` to
    send the Bench_Fault_Event frames.  ``bus`` (the bench's fault-injecting bus wrapper) is
    needed only for bus faults; without it they are reported but have no effect.
    """

    def __init__(
        self,
        sim: ChairSim,
        schedule: Sequence[FaultSpec] = (),
        *,
        seed: int = 0,
        bus: bf.FaultInjectingBus | None = None,
        codec: Codec | None = None,
    ) -> None:
        self.sim = sim
        self.seed = seed
        self.bus = bus
        self.codec = codec or Codec.default()
        if len(schedule) > 255:
            raise ConfigError(f"at most 255 scheduled faults, got {len(schedule)}")
        self.pending: list[tuple[int, FaultSpec]] = sorted(
            ((i + 1, s) for i, s in enumerate(schedule)), key=lambda e: e[1].onset_ns
        )
        self.active: dict[int, ActiveFault] = {}
        self.history: list[tuple[int, FaultEvent]] = []  # (sim ns, event)
        self._events: list[FaultEvent] = []
        self._used_ids = {fid for fid, _ in self.pending}
        self._touched: set[int] = set()  # id() of wheels a plant fault has changed
        self._reset: list[Wheel] = []  # those wheels, in the plant's order (left, right)
        self._plant_models: list[_Model] = []
        self._next_change_ns = self._compute_next_change()
        sim.add_tick_hook(self._on_tick)

    def reschedule(self, schedule: Sequence[FaultSpec]) -> None:
        """Replace the schedule of a manager none of whose faults has started yet, as if it
        had been built with ``schedule`` (IDs 1..n again): a lock-step run forked before its
        first fault goes on as another scenario that is the same up to there
        (``tools.run.branches``).  ``RuntimeError`` once a fault was activated or refused."""
        if self.active or self.history or self._events:
            raise RuntimeError("a fault schedule can be replaced only before any fault happened")
        if len(schedule) > 255:
            raise ConfigError(f"at most 255 scheduled faults, got {len(schedule)}")
        self.pending = sorted(
            ((i + 1, s) for i, s in enumerate(schedule)), key=lambda e: e[1].onset_ns
        )
        self._used_ids = {fid for fid, _ in self.pending}
        self._next_change_ns = self._compute_next_change()

    # -------------------------------------------------------------------- time

    def _compute_next_change(self) -> int | float:
        times: list[int | float] = [self.pending[0][1].onset_ns] if self.pending else []
        times += [a.end_ns for a in self.active.values() if a.end_ns is not None]
        return min(times, default=math.inf)

    def on_step(self, now_ns: int) -> None:
        """Activate and clear what is due at the step boundary ``now_ns``."""
        if now_ns >= self._next_change_ns:
            self._update(now_ns)

    def _on_tick(self, t_ns: int, _plant: Any) -> None:
        if t_ns >= self._next_change_ns:
            self._update(t_ns)
        if self._plant_models:
            self._apply_plant(t_ns)

    def _update(self, now_ns: int) -> None:
        for fid, a in list(self.active.items()):
            if a.end_ns is not None and now_ns >= a.end_ns:
                self._clear(fid, now_ns)
        while self.pending and self.pending[0][1].onset_ns <= now_ns:
            fid, spec = self.pending.pop(0)
            self._activate(fid, spec, now_ns)
        self._next_change_ns = self._compute_next_change()

    # --------------------------------------------------------------- activate

    def _model(self, fid: int, spec: FaultSpec) -> _Model:
        rng = random.Random(f"fault:{self.seed}:{fid}:{spec.kind}")
        return MODELS[spec.kind](_Context(self.sim, spec, rng, self.bus, self.codec))

    def _activate(self, fid: int, spec: FaultSpec, now_ns: int) -> None:
        model = self._model(fid, spec)
        end = spec.end_ns
        if end is not None:
            end = now_ns + (end - spec.onset_ns)
        a = ActiveFault(fid, spec, now_ns, end, model)
        self.active[fid] = a
        model.start(now_ns)
        if model.plant:
            self._plant_models.append(model)
            for w in getattr(model, "wheels", ()):
                self._touched.add(id(w))
            plant = self.sim.plant
            self._reset = [w for w in (plant.left, plant.right) if id(w) in self._touched]
            self._apply_plant(now_ns)
        if isinstance(model, _EncoderFault):
            self._compose_encoders()
        self._emit(now_ns, spec.wire(fid, FaultState.ACTIVE))
        if model.instantaneous:
            self._clear(fid, now_ns)
        log.info("fault %d %s active at t=%.3f s", fid, spec.label, now_ns / 1e9)

    def _clear(self, fid: int, now_ns: int) -> None:
        a = self.active.pop(fid)
        a.model.stop(now_ns)
        if a.model.plant:
            self._plant_models.remove(a.model)
            self._apply_plant(now_ns)
        if isinstance(a.model, _EncoderFault):
            self._compose_encoders()
        self._emit(now_ns, a.spec.wire(fid, FaultState.CLEARED))
        self._next_change_ns = self._compute_next_change()
        log.info("fault %d %s cleared at t=%.3f s", fid, a.spec.label, now_ns / 1e9)

    def _emit(self, now_ns: int, ev: FaultEvent) -> None:
        self._events.append(ev)
        self.history.append((now_ns, ev))

    def take_events(self) -> list[FaultEvent]:
        """Bench_Fault_Event payloads produced since the last call, in order."""
        ev, self._events = self._events, []
        return ev

    # ------------------------------------------------------------------ seams

    def _apply_plant(self, t_ns: int) -> None:
        """Recompute the touched wheels' seams from nominal plus every active plant fault."""
        if self._reset:
            r0 = self.sim.config.chair.wheel_radius_m
            for w in self._reset:
                w.radius_m = r0
                w.radius_offset_m = 0.0
                w.slip_ratio = 0.0
                w.torque_gain = 1.0
                w.motor_open = False
        for m in self._plant_models:
            m.apply(t_ns)

    def _compose_encoders(self) -> None:
        for key, drive in ((0, self.sim.left), (1, self.sim.right)):
            enc = drive.encoder
            models = [
                a.model
                for a in self.active.values()
                if isinstance(a.model, _EncoderFault) and enc in a.model.encoders
            ]
            enc.count_filter = _chain(models, key) if models else None

    # ------------------------------------------------------------------ live

    def command(self, cmd: FaultCommand, now_ns: int) -> None:
        """Act on a Bench_Fault_Command at ``now_ns``; the outcome is in :meth:`take_events`."""
        if cmd.action == FaultAction.INJECT:
            try:
                spec = spec_from_command(cmd, now_ns)
            except ConfigError as err:
                log.warning("fault command refused: %s", err)
                self._reject(cmd, now_ns)
                return
            fid = cmd.fault_id
            if fid == 0:
                fid = next((i for i in range(1, 256) if i not in self._used_ids), 0)
            if fid == 0 or fid in self.active:
                log.warning("fault command refused: fault ID %d unavailable", cmd.fault_id)
                self._reject(cmd, now_ns)
                return
            self._used_ids.add(fid)
            self.pending = [(i, s) for i, s in self.pending if i != fid]
            self._activate(fid, spec, now_ns)
        else:
            cancelled = False
            if cmd.fault_id:
                targets = [cmd.fault_id] if cmd.fault_id in self.active else []
                # a scheduled fault not yet active is cancelled (it never reports)
                before = len(self.pending)
                self.pending = [(i, s) for i, s in self.pending if i != cmd.fault_id]
                cancelled = len(self.pending) != before
            else:
                targets = [
                    fid
                    for fid, a in self.active.items()
                    if cmd.fault_type in (FaultType.NONE, a.spec.info.fault_type)
                    and cmd.side in (FaultSide.NONE, SIDES.get(a.spec.side or "", FaultSide.NONE))
                ]
            if not targets and not cancelled:
                self._reject(cmd, now_ns)
                return
            for fid in targets:
                self._clear(fid, now_ns)
        self._next_change_ns = self._compute_next_change()

    def _reject(self, cmd: FaultCommand, now_ns: int) -> None:
        self._emit(
            now_ns,
            FaultEvent(
                cmd.fault_id,
                cmd.fault_type,
                cmd.side,
                FaultState.REJECTED,
                cmd.duration_s,
                cmd.amplitude,
                cmd.param,
            ),
        )


def _chain(models: Sequence[_Model], key: int) -> Callable[[int], int]:
    filters = [m.filter for m in models if isinstance(m, _EncoderFault)]
    if len(filters) == 1:
        f0 = filters[0]
        return lambda c: f0(key, c)

    def chained(c: int) -> int:
        for f in filters:
            c = f(key, c)
        return c

    return chained
