"""Live fault injection: a ``Bench_Fault_Command`` to a running bench, and its answers.

:func:`build_command` makes the command from a fault kind and its wire-carried parameters
(:func:`wire_options`: the options ``wheelchair-hil inject`` offers, named after the
parameters with their unit), :func:`fault_command` from a scenario's ``[[faults]]`` entry (the
soak's faults); :func:`inject` waits for the bench's clock (a ``Bench_Step``), sends the
command and collects the bench's ``Bench_Fault_Event`` answers; :func:`describe_event` is one
answer as a line.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from typing import Any

from dbc.codec import (
    BenchStep,
    FaultAction,
    FaultCommand,
    FaultEvent,
    FaultSide,
    FaultState,
    FaultType,
)
from dbc.errors import DecodeError
from dbc.runtime.busio import recv_dropping
from dbc.runtime.errors import BusError, ConfigError
from firmware_sim.faultspec import KINDS, parse_fault
from tools.bus.transport import BusSpec, open_bus

#: Unit suffixes dropped from parameter names to form option names (to_radius_m -> --to-radius).
_SUFFIXES = ("_m", "_s", "_rad", "_ms")


def _option(field: str) -> str:
    for suffix in _SUFFIXES:
        if field.endswith(suffix):
            field = field[: -len(suffix)]
            break
    return "--" + field.replace("_", "-")


def wire_fields() -> dict[str, tuple[str, str]]:
    """Option -> (parameter field, unit) over every kind's wire-carried parameters."""

    out: dict[str, tuple[str, str]] = {}
    for info in KINDS.values():
        fields = {f.name: f for f in dataclasses.fields(info.params)}
        for name in (info.amplitude, info.param):
            if name is not None:
                out[_option(name)] = (name, str(fields[name].metadata.get("unit", "")))
    return out


@dataclasses.dataclass(frozen=True)
class WireOption:
    """One ``inject`` option: the parameter it sets, its unit, meaning and the kinds using it."""

    field: str
    unit: str
    doc: str
    kinds: tuple[str, ...]

    @property
    def metavar(self) -> str:
        """The unit (``M``, ``RAD``), or the parameter's name where it has none (``GAIN``)."""
        return self.unit.upper() if self.unit not in ("", "1") else self.field.upper()


def wire_options() -> dict[str, WireOption]:
    """Option -> :class:`WireOption` over every kind's wire-carried parameters."""
    out: dict[str, WireOption] = {}
    for kind, info in KINDS.items():
        fields = {f.name: f for f in dataclasses.fields(info.params)}
        for name in (info.amplitude, info.param):
            if name is None:
                continue
            opt = _option(name)
            meta = fields[name].metadata
            prev = out.get(opt)
            kinds = (*prev.kinds, kind) if prev else (kind,)
            doc = str(meta.get("doc", ""))
            if prev and prev.doc != doc:  # kinds describe it each their way: just its name
                doc = name.replace("_", " ")
            out[opt] = WireOption(name, str(meta.get("unit", "")), doc, kinds)
    return out


def build_command(
    kind: str,
    *,
    side: str | None = None,
    node: str | None = None,
    params: Mapping[str, float] | None = None,
    duration_s: float = 0.0,
    clear: bool = False,
    fault_id: int = 0,
) -> Any:
    """The Bench_Fault_Command payload that injects (or with ``clear`` clears) a fault of
    ``kind`` (``all``: every kind, clear only) with its wire-carried ``params`` (parameter
    field -> value, :func:`wire_fields`); ConfigError, naming the option, if invalid."""

    sides = {None: FaultSide.NONE, "left": FaultSide.LEFT, "right": FaultSide.RIGHT}
    sides["both"] = FaultSide.BOTH
    given = dict(params or {})
    if not 0 <= fault_id <= 255:
        raise ConfigError(f"--id {fault_id} is outside [0, 255]")
    if clear:
        if given:
            raise ConfigError("--clear takes no fault parameters")
        ftype = FaultType.NONE if kind == "all" else KINDS[kind].fault_type
        return FaultCommand(fault_id, ftype, sides[side], FaultAction.CLEAR)
    if kind == "all":
        raise ConfigError("'all' can only be cleared (--clear)")
    info = KINDS[kind]
    names = {f.name for f in dataclasses.fields(info.params)}
    extra = sorted(set(given) - {info.amplitude, info.param})
    if extra:
        own = [_option(n) for n in (info.amplitude, info.param) if n]
        raise ConfigError(
            f"{_option(extra[0])} does not apply to {kind} "
            f"(its options: {', '.join(own) or 'none'})"
        )
    table: dict[str, Any] = {"type": kind, "duration_s": duration_s, **given}
    if "side" in names:
        table["side"] = side
        if side is None:
            table.pop("side")
    if "node" in names and node is not None:
        table["node"] = node
    return fault_command(table, fault_id, source="wheelchair-hil inject")


def fault_command(table: dict[str, Any], fault_id: int = 0, *, source: str) -> Any:
    """The Bench_Fault_Command that injects the fault ``table`` describes (a scenario's
    ``[[faults]]`` entry without its onset: ``type``, ``duration_s`` and the kind's parameters;
    ConfigError naming ``source`` if invalid)."""
    spec = parse_fault(table, source=source, key="fault")
    ev = spec.wire(fault_id, FaultState.ACTIVE)  # the same wire units as the bench's events
    return FaultCommand(
        fault_id, ev.fault_type, ev.side, FaultAction.INJECT, ev.duration_s, ev.amplitude, ev.param
    )


def describe_event(ev: Any) -> str:
    """One line for a Bench_Fault_Event: state, ID, kind, side and parameters in their units."""

    info = next((k for k in KINDS.values() if k.fault_type == ev.fault_type), None)
    kind = info.name if info else ev.fault_type.name
    parts = [f"{ev.state.name} fault {ev.fault_id} {kind}"]
    if ev.side.name != "NONE":
        parts.append(f"side={ev.side.name.lower()}")
    if info is not None and not (ev.state.name == "REJECTED" and not ev.amplitude):
        if info.amplitude:
            parts.append(f"{info.amplitude}={ev.amplitude / info.amplitude_scale:g}")
        if info.param:
            parts.append(f"{info.param}={ev.param / info.param_scale:g}")
        if info.name.startswith("node-"):
            parts.append(f"node={int(ev.amplitude)}")
    if ev.duration_s:
        parts.append(f"duration_s={ev.duration_s:g}")
    elif ev.state.name == "ACTIVE":
        parts.append("until cleared")
    return " ".join(parts)


def inject(
    spec: BusSpec,
    codec: Any,
    cmd: Any,
    *,
    wait_s: float,
    on_answer: Callable[[FaultEvent, int | None], None] | None = None,
) -> list[FaultEvent]:
    """Send ``cmd`` to the bench on ``spec`` and return its answers (``Bench_Fault_Event`` of
    the command's kind and side; ``on_answer(event, sim_time_ns)`` as each comes, with the
    simulation time of the latest ``Bench_Step``).  ``wait_s``: wall seconds for each of the
    two waits, for the bench's clock before sending and for its answer after; BusError if no
    bench is running or none answered."""

    msg = codec.encode(cmd)
    answers: list[FaultEvent] = []
    sim_ns: int | None = None
    dropped: dict[str, int] = {}  # what the bus carried that was no frame
    bus = open_bus(spec)
    try:
        deadline = time.monotonic() + wait_s
        sim_ns = _wait_for_bench(bus, codec, deadline)
        if sim_ns is None:
            raise BusError(
                f"no bench is running on {spec.describe()}: no Bench_Step within {wait_s:g} s"
            )
        bus.send(msg)
        settle: float | None = None
        while True:
            now = time.monotonic()
            end = deadline if settle is None else min(deadline, settle)
            if now >= end:
                break
            frame = recv_dropping(bus, end - now, dropped)
            if frame is None or not frame.is_extended_id:
                continue
            try:
                payload = codec.decode(frame).payload
            except DecodeError:
                continue
            if type(payload) is BenchStep:
                sim_ns = payload.sim_time_ns
            elif type(payload) is FaultEvent and (
                cmd.fault_type in (FaultType.NONE, payload.fault_type)
                and cmd.side in (FaultSide.NONE, payload.side)
            ):
                answers.append(payload)
                if on_answer is not None:
                    on_answer(payload, sim_ns)
                settle = time.monotonic() + 0.2  # clear-all: collect the siblings
    finally:
        bus.shutdown()
    if not answers:
        raise BusError(
            f"no bench answered within {wait_s:g} s on {spec.describe()} "
            "(is a bench running on this bus?)"
        )
    return answers


def _wait_for_bench(bus: Any, codec: Any, deadline: float) -> int | None:
    """Simulation time of the first Bench_Step heard before ``deadline`` (None: no bench)."""

    while (left := deadline - time.monotonic()) > 0:
        frame = recv_dropping(bus, left, {})
        if frame is None or not frame.is_extended_id:
            continue
        try:
            payload = codec.decode(frame).payload
        except DecodeError:
            continue
        if type(payload) is BenchStep:
            return int(payload.sim_time_ns)
    return None
