"""The soak's schedule: which event happens at which simulation time, drawn from the seed.

It owns the list of event kinds (every fault kind the bench knows, the rogue node's attacks,
the signals to recorder and controller) and how they are spread over the run: in rounds,
each of which has every kind once in a random order at random moments, each fault lasting a
random time, so that faults follow one another and overlap.  The same seed and length always
give the same schedule (:func:`build`); nothing here starts a process or reads a clock.
"""

from __future__ import annotations

import dataclasses
import random
from dataclasses import dataclass, field
from typing import Any

from firmware_sim.faultspec import KINDS

#: The rogue node's modes (tools.safety.attacks.attacker.run_attacker) the soak uses: forging
#: setpoints and replaying captured ones.
ATTACKS: tuple[str, ...] = ("forge-both", "forge-left", "replay")
#: How long one attack acts (s of simulation time; tools.safety.attacks.attacker.ATTACK_S).
ATTACK_S = 3.5
#: The signals to the parts: SIGTERM and SIGKILL of the recorder, SIGTERM of the controller.
SIGNALS: tuple[str, ...] = ("record-term", "record-kill", "control-term")
#: Simulation time before the first event: the first route's host arms and tracks, and a
#: replay attack has 7 s of the host's setpoints to replay.
WARMUP_S = 20.0
#: Simulation time after the last event's onset: its consequences are in the log.
COOLDOWN_S = 12.0
#: A round: every kind once (s).  A run shorter than one round packs one round into it.
ROUND_S = 150.0
#: Bounds of a fault's duration (s); node-reboot is instantaneous.
FAULT_MIN_S, FAULT_MAX_S = 3.0, 10.0
#: The parameters drawn for a fault (among the choices its kind declares); the others keep
#: the kind's defaults.
_DRAWN = ("side", "node")


@dataclass(frozen=True)
class Event:
    """One scheduled event.

    ``action``: ``fault`` (``kind`` a fault kind of firmware_sim.faultspec, injected through
    a Bench_Fault_Command), ``attack`` (``kind`` an attacker mode) or ``signal`` (``kind`` one
    of :data:`SIGNALS`).  ``at_s`` and ``duration_s`` are the bench's simulation time.
    """

    at_s: float
    action: str
    kind: str
    duration_s: float = 0.0
    #: a fault's parameters beyond type and duration (side, node): the kinds' defaults else
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def end_s(self) -> float:
        return self.at_s + self.duration_s

    def fault_table(self) -> dict[str, Any]:
        """A fault event as a scenario's ``[[faults]]`` entry without its onset."""
        return {"type": self.kind, "duration_s": self.duration_s, **self.params}

    def describe(self) -> str:
        extra = " ".join(f"{k}={v}" for k, v in sorted(self.params.items()))
        span = f" for {self.duration_s:.1f} s" if self.duration_s else ""
        return f"t={self.at_s:7.1f} s  {self.action:6s} {self.kind}{span}" + (
            f" ({extra})" if extra else ""
        )

    def as_dict(self) -> dict[str, Any]:
        return {
            "at_s": self.at_s,
            "action": self.action,
            "kind": self.kind,
            "duration_s": self.duration_s,
            "params": dict(self.params),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Event:
        return cls(
            float(d["at_s"]),
            str(d["action"]),
            str(d["kind"]),
            float(d.get("duration_s", 0.0)),
            dict(d.get("params", {})),
        )


@dataclass(frozen=True)
class Schedule:
    """Every event of a soak, in time order."""

    seed: int
    minutes: float
    events: tuple[Event, ...]

    @property
    def duration_s(self) -> float:
        return self.minutes * 60.0

    def as_dict(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "minutes": self.minutes,
            "events": [e.as_dict() for e in self.events],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Schedule:
        return cls(
            int(d["seed"]), float(d["minutes"]), tuple(Event.from_dict(e) for e in d["events"])
        )

    def describe(self) -> list[str]:
        return [e.describe() for e in self.events]


#: The shortest soak (min): one round of events between warm-up and cool-down.
MIN_MINUTES = 2.0


def kinds() -> list[tuple[str, str]]:
    """Every (action, kind) a round holds once."""
    return [
        *(("fault", k) for k in KINDS),
        *(("attack", a) for a in ATTACKS),
        *(("signal", s) for s in SIGNALS),
    ]


def build(seed: int, minutes: float) -> Schedule:
    """The schedule of a soak of ``minutes`` with ``seed`` (ValueError below
    :data:`MIN_MINUTES`)."""
    if minutes < MIN_MINUTES:
        raise ValueError(f"a soak lasts at least {MIN_MINUTES:g} minutes (got {minutes:g})")
    rng = random.Random(seed)
    start, end = WARMUP_S, minutes * 60.0 - COOLDOWN_S
    rounds = max(1, int((end - start) // ROUND_S))
    width = (end - start) / rounds
    events: list[Event] = []
    for r in range(rounds):
        lo = start + r * width
        todo = kinds()
        rng.shuffle(todo)
        # one moment per kind, spread over the round: sorted uniform draws
        moments = sorted(rng.uniform(lo, lo + width) for _ in todo)
        for (action, kind), at in zip(todo, moments, strict=True):
            events.append(_event(rng, action, kind, round(at, 2)))
        _force_overlap(rng, events, lo)
    events.sort(key=lambda e: (e.at_s, e.action, e.kind))
    return Schedule(seed, minutes, tuple(events))


def _event(rng: random.Random, action: str, kind: str, at: float) -> Event:
    if action == "attack":
        return Event(at, action, kind, ATTACK_S)
    if action == "signal":
        return Event(at, action, kind)
    params: dict[str, Any] = {}
    for f in dataclasses.fields(KINDS[kind].params):
        if f.name in _DRAWN:
            params[f.name] = rng.choice(f.metadata["choices"])
    duration = 0.0 if kind == "node-reboot" else round(rng.uniform(FAULT_MIN_S, FAULT_MAX_S), 2)
    return Event(at, action, kind, duration, params)


def overlapping(events: tuple[Event, ...] | list[Event]) -> list[tuple[Event, Event]]:
    """Pairs of faults active at the same time."""
    faults = sorted((e for e in events if e.action == "fault"), key=lambda e: e.at_s)
    return [
        (a, b)
        for i, a in enumerate(faults)
        for b in faults[i + 1 :]
        if b.at_s < a.end_s and a.duration_s > 0
    ]


def _force_overlap(rng: random.Random, events: list[Event], lo: float) -> None:
    """Make sure the round starting at ``lo`` has two faults at once: the last timed fault
    of the round is moved into the span of the one before it if none overlap."""
    mine = [e for e in events if e.at_s >= lo and e.action == "fault" and e.duration_s > 0]
    if len(mine) < 2 or overlapping(mine):
        return
    mine.sort(key=lambda e: e.at_s)
    first, moved = mine[-2], mine[-1]
    at = round(first.at_s + rng.uniform(0.2, 0.8) * first.duration_s, 2)
    events[events.index(moved)] = Event(
        at, moved.action, moved.kind, moved.duration_s, moved.params
    )
