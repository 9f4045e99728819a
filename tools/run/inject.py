"""``wheelchair-hil inject``: inject or clear a fault in a running bench, through a bench frame.

Examples (on the bench's bus, e.g. inside ``wheelchair-hil sandbox``)::

    wheelchair-hil inject flat-tire --side left --to-radius 0.26 --time-constant 2
    wheelchair-hil inject shaft-bump --side right --amplitude 0.015
    wheelchair-hil inject flat-tire --side left --clear      # every left flat tire
    wheelchair-hil inject all --clear                        # every active fault
    wheelchair-hil inject --id 3 all --clear                 # fault 3 only

The command waits for the bench's clock (a ``Bench_Step``), sends one ``Bench_Fault_Command``
and waits for the bench's ``Bench_Fault_Event`` answer, which it prints with the simulation time
of the latest ``Bench_Step`` (``--wait``: wall seconds for each of the two waits).  Options carry the parameter's unit (see ``--help`` or docs/faults.md); only
the parameters a ``Bench_Fault_Command`` can carry are offered.  Exit status 0 when the bench
confirmed, 1 when it refused, 2 when no bench answered.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
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
from tools.bus.transport import open_bus
from tools.cli import from_args

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


def build_command(args: argparse.Namespace) -> Any:
    """The Bench_Fault_Command payload for the parsed arguments (ConfigError if invalid)."""

    sides = {None: FaultSide.NONE, "left": FaultSide.LEFT, "right": FaultSide.RIGHT}
    sides["both"] = FaultSide.BOTH
    given = {
        field: getattr(args, f"fault_{field}")
        for _opt, (field, _u) in wire_fields().items()
        if getattr(args, f"fault_{field}", None) is not None
    }
    if not 0 <= args.id <= 255:
        raise ConfigError(f"--id {args.id} is outside [0, 255]")
    if args.clear:
        if given:
            raise ConfigError("--clear takes no fault parameters")
        ftype = FaultType.NONE if args.kind == "all" else KINDS[args.kind].fault_type
        return FaultCommand(args.id, ftype, sides[args.side], FaultAction.CLEAR)
    if args.kind == "all":
        raise ConfigError("'all' can only be cleared (--clear)")
    info = KINDS[args.kind]
    names = {f.name for f in dataclasses.fields(info.params)}
    extra = sorted(set(given) - {info.amplitude, info.param})
    if extra:
        own = [_option(n) for n in (info.amplitude, info.param) if n]
        raise ConfigError(
            f"{_option(extra[0])} does not apply to {args.kind} "
            f"(its options: {', '.join(own) or 'none'})"
        )
    table: dict[str, Any] = {"type": args.kind, "duration_s": args.fault_duration, **given}
    if "side" in names:
        table["side"] = args.side
        if args.side is None:
            table.pop("side")
    if "node" in names and args.node is not None:
        table["node"] = args.node
    return fault_command(table, args.id, source="wheelchair-hil inject")


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


def run(args: argparse.Namespace, argv: list[str]) -> int:

    cmd = build_command(args)
    codec = from_args.codec_for(args)
    spec = from_args.bus_spec(args)
    msg = codec.encode(cmd)
    answers: list[FaultEvent] = []
    sim_ns: int | None = None
    dropped: dict[str, int] = {}  # what the bus carried that was no frame
    bus = open_bus(spec)
    try:
        deadline = time.monotonic() + args.wait
        sim_ns = _wait_for_bench(bus, codec, deadline)
        if sim_ns is None:
            raise BusError(
                f"no bench is running on {spec.describe()}: no Bench_Step within {args.wait:g} s"
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
                at = f" at t={sim_ns / 1e9:.3f} s" if sim_ns is not None else ""
                print(f"{describe_event(payload)}{at}")
                settle = time.monotonic() + 0.2  # clear-all: collect the siblings
    finally:
        bus.shutdown()
    if not answers:
        raise BusError(
            f"no bench answered within {args.wait:g} s on {spec.describe()} "
            "(is a bench running on this bus?)"
        )
    return 1 if all(a.state == FaultState.REJECTED for a in answers) else 0


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
