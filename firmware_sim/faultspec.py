"""What a fault of the bench is: its kind, typed parameters, and how a scenario or a frame asks for it.

Every fault kind (:data:`KINDS`) has its parameters declared once with unit, default and
bounds, like every other parameter; :func:`parse_schedule` validates a scenario's ``[[faults]]``
schedule (errors name the file, the key and the bound), :func:`spec_from_command` a live
``Bench_Fault_Command``, and :meth:`FaultSpec.wire` gives a fault's ``Bench_Fault_Event``.
Every fault has ``onset_s`` (simulation time) and ``duration_s`` (0 = until cleared).  A bus
fault's parameters are those of the :mod:`firmware_sim.busfaults` rule it becomes
(:meth:`BusRuleParams.rule_for`), its times in ms where the rule's are in ns.  What each fault
does to the simulated chair is :mod:`firmware_sim.faults`'.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from dbc.codec import Codec, FaultCommand, FaultEvent, FaultSide, FaultState, FaultType
from dbc.errors import EncodeError
from dbc.runtime import params
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import param
from firmware_sim import busfaults as bf

_DEG = 180.0 / math.pi
_NS_PER_MS = 1_000_000
#: Wire limit of Bench_Fault_*.Duration (14 bits at 0.1 s).
MAX_DURATION_S = 1638.3
_WHEEL_SIDES = ("left", "right", "both")
_DIRECTIONS = ("send", "recv", "both")

# ------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class FaultTiming:
    """When a fault acts: from ``onset_s`` for ``duration_s`` (0 = until cleared)."""

    onset_s: float = param(
        0.0, unit="s", lo=0.0, hi=86400.0, doc="simulation time at which the fault begins"
    )
    duration_s: float = param(
        0.0,
        unit="s",
        lo=0.0,
        hi=MAX_DURATION_S,
        doc="how long the fault lasts; 0 = until cleared (permanent)",
    )


def _side(default: str = "left", choices: tuple[str, ...] = _WHEEL_SIDES) -> Any:
    return param(default, unit="", choices=choices, doc="which wheel: " + ", ".join(choices))


@dataclass(frozen=True)
class FlatTireParams(FaultTiming):
    """A flat tire: the wheel's rolling radius decays to ``to_radius_m``."""

    side: str = _side(choices=("left", "right"))
    to_radius_m: float = param(
        0.26, unit="m", lo=0.05, hi=0.6, doc="rolling radius the tire deflates to"
    )
    time_constant_s: float = param(
        2.0, unit="s", lo=0.0, hi=400.0, doc="time constant of the exponential decay; 0 = a step"
    )


@dataclass(frozen=True)
class ShaftBumpParams(FaultTiming):
    """An eccentric wheel: the rolling radius swings by ``amplitude_m`` once per revolution."""

    side: str = _side(choices=("left", "right"))
    amplitude_m: float = param(
        0.015, unit="m", lo=0.0, hi=0.1, doc="eccentricity a: rolling radius swings by +-a"
    )
    phase_rad: float = param(
        0.0, unit="rad", lo=0.0, hi=math.tau, doc="phase of the swing at the onset (0: starts at r)"
    )


@dataclass(frozen=True)
class SlipParams(FaultTiming):
    """Longitudinal slip of one or both wheels at slip ratio ``ratio``."""

    side: str = _side("both")
    ratio: float = param(
        0.1, unit="1", lo=0.0, hi=0.9, doc="longitudinal slip ratio s (ground = rho (1 - s))"
    )


@dataclass(frozen=True)
class EncoderNoiseParams(FaultTiming):
    """Gaussian noise of ``sigma_counts`` on each encoder count the drive samples."""

    side: str = _side()
    sigma_counts: float = param(
        5.0, unit="counts", lo=0.0, hi=50.0, doc="std of Gaussian noise on each count sample"
    )


@dataclass(frozen=True)
class EncoderStuckParams(FaultTiming):
    """A stuck encoder: the count the drive samples stays at its value at the onset."""

    side: str = _side()


@dataclass(frozen=True)
class EncoderScaleParams(FaultTiming):
    """A miscalibrated encoder: the counts since the onset multiplied by ``scale``."""

    side: str = _side()
    scale: float = param(
        1.05, unit="1", lo=0.1, hi=10.0, doc="counts since the onset are multiplied by this"
    )


@dataclass(frozen=True)
class EncoderDropoutParams(FaultTiming):
    """Get_Encoder_Estimates frames lost, each with ``probability``."""

    side: str = _side()
    probability: float = param(
        1.0, unit="1", lo=0.0, hi=1.0, doc="share of Get_Encoder_Estimates frames lost"
    )


@dataclass(frozen=True)
class LocalizerDropoutParams(FaultTiming):
    """Pose fixes lost, each with ``probability``."""

    probability: float = param(1.0, unit="1", lo=0.0, hi=1.0, doc="share of pose fixes lost")


@dataclass(frozen=True)
class LocalizerBiasParams(FaultTiming):
    """A constant world-frame offset of ``offset_m`` on every pose fix's position."""

    offset_m: float = param(
        0.2, unit="m", lo=0.0, hi=10.0, doc="length of the constant position bias"
    )
    direction_rad: float = param(
        0.0, unit="rad", lo=0.0, hi=math.tau, doc="world-frame direction of the bias (0 = +x)"
    )


@dataclass(frozen=True)
class LocalizerHeadingBiasParams(FaultTiming):
    """A constant ``bias_rad`` added to every pose fix's heading."""

    bias_rad: float = param(
        0.05, unit="rad", lo=-math.pi, hi=math.pi, doc="constant bias added to the fix heading"
    )


@dataclass(frozen=True)
class TorqueLossParams(FaultTiming):
    """The motor's torque multiplied by ``gain``."""

    side: str = _side()
    gain: float = param(0.5, unit="1", lo=0.0, hi=1.0, doc="share of the motor torque left")


@dataclass(frozen=True)
class DeadMotorParams(FaultTiming):
    """An open motor winding: no current and no torque, unnoticed by the drive."""

    side: str = _side()


@dataclass(frozen=True)
class BusRuleParams(FaultTiming):
    """A bus fault: a :mod:`firmware_sim.busfaults` rule (:attr:`rule`) on the bench's bus.

    Its own parameters are the rule's fields of the same names, a ``*_ms`` one the rule's
    ``*_ns`` (:meth:`rule_for`); ``frames`` and ``direction`` select the frames it acts on.
    """

    #: the rule this fault becomes
    rule: ClassVar[type[bf.Rule]] = bf.Rule

    frames: tuple[str, ...] = param(
        (), unit="", doc="DBC message names the rule applies to; empty = every 11-bit frame"
    )
    direction: str = param(
        "both",
        unit="",
        choices=_DIRECTIONS,
        doc="as seen by the bench: send = frames it sends, recv = frames it receives",
    )

    def rule_for(self, match: bf.FrameMatch, direction: bf.Direction) -> bf.Rule:
        """The rule of this fault on the frames ``match`` selects, seen in ``direction``."""
        common = {f.name for f in dataclasses.fields(BusRuleParams)}
        own: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            if f.name in common:
                continue
            value = getattr(self, f.name)
            if f.name.endswith("_ms"):
                own[f.name.removesuffix("_ms") + "_ns"] = round(value * _NS_PER_MS)
            else:
                own[f.name] = value
        return self.rule(match=match, direction=direction, **own)


@dataclass(frozen=True)
class BusDropParams(BusRuleParams):
    """Frames lost on the bench's bus, in bursts (:class:`~firmware_sim.busfaults.Drop`)."""

    rule = bf.Drop

    probability: float = param(0.1, unit="1", lo=0.0, hi=1.0, doc="long-run share of frames lost")
    burst_length: float = param(
        1.0, unit="frames", lo=1.0, hi=400.0, doc="mean length of a loss burst (1 = independent)"
    )


@dataclass(frozen=True)
class BusDelayParams(BusRuleParams):
    """Frames delayed by ``delay_ms`` plus jitter (:class:`~firmware_sim.busfaults.Delay`)."""

    rule = bf.Delay

    delay_ms: float = param(20.0, unit="ms", lo=0.0, hi=5000.0, doc="added latency")
    jitter_ms: float = param(
        0.0, unit="ms", lo=0.0, hi=400.0, doc="plus a uniform random latency in [0, jitter]"
    )


@dataclass(frozen=True)
class BusDuplicateParams(BusRuleParams):
    """Frames sent twice (:class:`~firmware_sim.busfaults.Duplicate`)."""

    rule = bf.Duplicate

    probability: float = param(0.1, unit="1", lo=0.0, hi=1.0, doc="share of frames sent twice")


@dataclass(frozen=True)
class BusReorderParams(BusRuleParams):
    """Frames delivered after the next one (:class:`~firmware_sim.busfaults.Reorder`)."""

    rule = bf.Reorder

    probability: float = param(
        0.1, unit="1", lo=0.0, hi=1.0, doc="share of frames delivered after the next one"
    )
    max_hold_ms: float = param(
        100.0,
        unit="ms",
        lo=0.0,
        hi=10000.0,
        doc="a held frame is released after this at the latest",
    )


@dataclass(frozen=True)
class BusCorruptParams(BusRuleParams):
    """Frames with ``bits`` data bits flipped (:class:`~firmware_sim.busfaults.Corrupt`)."""

    rule = bf.Corrupt

    probability: float = param(
        0.1, unit="1", lo=0.0, hi=1.0, doc="share of frames with flipped bits"
    )
    bits: int = param(1, unit="bits", lo=1, hi=64, doc="distinct data bits flipped per frame")


@dataclass(frozen=True)
class NodeSilentParams(FaultTiming):
    """A drive or the localizer falls silent: its frames are lost both ways."""

    node: str = param(
        "left", unit="", choices=("left", "right", "localizer"), doc="node that falls silent"
    )


@dataclass(frozen=True)
class NodeRebootParams(FaultTiming):
    """A drive reboots, silent for its boot time, as after a supply glitch."""

    node: str = param("left", unit="", choices=("left", "right"), doc="drive that reboots")


@dataclass(frozen=True)
class KindInfo:
    """One fault kind: its parameters and how they travel in Bench_Fault_* frames."""

    name: str
    params: type
    fault_type: FaultType
    amplitude: str | None = None  # parameter carried in Amplitude
    amplitude_scale: float = 1.0  # wire = value * scale
    param: str | None = None  # parameter carried in Param
    param_scale: float = 1.0
    diagnosable: str | None = None  # hypothesis name prefix of the filter bank, if any

    @property
    def sided(self) -> bool:
        """Whether the kind's parameters name a wheel (``side``)."""
        return "side" in {f.name for f in dataclasses.fields(self.params)}


KINDS: dict[str, KindInfo] = {
    k.name: k
    for k in (
        KindInfo(
            "flat-tire",
            FlatTireParams,
            FaultType.FLAT_TIRE,
            "to_radius_m",
            1.0,
            "time_constant_s",
            diagnosable="flat",
        ),
        KindInfo(
            "shaft-bump",
            ShaftBumpParams,
            FaultType.SHAFT_BUMP,
            "amplitude_m",
            1.0,
            "phase_rad",
            _DEG,
            diagnosable="bump",
        ),
        KindInfo("slip", SlipParams, FaultType.SLIP, "ratio", diagnosable="slip"),
        KindInfo("encoder-noise", EncoderNoiseParams, FaultType.ENCODER_NOISE, "sigma_counts"),
        KindInfo("encoder-stuck", EncoderStuckParams, FaultType.ENCODER_STUCK),
        KindInfo("encoder-scale", EncoderScaleParams, FaultType.ENCODER_SCALE, "scale"),
        KindInfo("encoder-dropout", EncoderDropoutParams, FaultType.ENCODER_DROPOUT, "probability"),
        KindInfo(
            "localizer-dropout", LocalizerDropoutParams, FaultType.LOCALIZER_DROPOUT, "probability"
        ),
        KindInfo(
            "localizer-bias",
            LocalizerBiasParams,
            FaultType.LOCALIZER_BIAS,
            "offset_m",
            1.0,
            "direction_rad",
            _DEG,
        ),
        KindInfo(
            "localizer-heading-bias",
            LocalizerHeadingBiasParams,
            FaultType.LOCALIZER_HEADING_BIAS,
            "bias_rad",
        ),
        KindInfo("torque-loss", TorqueLossParams, FaultType.TORQUE_LOSS, "gain"),
        KindInfo("dead-motor", DeadMotorParams, FaultType.DEAD_MOTOR),
        KindInfo("bus-drop", BusDropParams, FaultType.BUS_DROP, "probability", 1.0, "burst_length"),
        KindInfo("bus-delay", BusDelayParams, FaultType.BUS_DELAY, "delay_ms", 1e-3, "jitter_ms"),
        KindInfo("bus-duplicate", BusDuplicateParams, FaultType.BUS_DUPLICATE, "probability"),
        KindInfo("bus-reorder", BusReorderParams, FaultType.BUS_REORDER, "probability"),
        KindInfo(
            "bus-corrupt", BusCorruptParams, FaultType.BUS_CORRUPT, "probability", 1.0, "bits"
        ),
        KindInfo("node-silent", NodeSilentParams, FaultType.NODE_SILENT),
        KindInfo("node-reboot", NodeRebootParams, FaultType.NODE_REBOOT),
    )
}
_BY_TYPE = {k.fault_type: k for k in KINDS.values()}
NODE_IDS = {"left": 1, "right": 2, "localizer": 3}
_NODE_NAMES = {v: k for k, v in NODE_IDS.items()}
SIDES = {"left": FaultSide.LEFT, "right": FaultSide.RIGHT, "both": FaultSide.BOTH}
_SIDE_NAMES = {v: k for k, v in SIDES.items()}


@dataclass(frozen=True)
class FaultSpec:
    """One validated fault: its kind and typed parameters."""

    kind: str
    params: Any

    @property
    def info(self) -> KindInfo:
        """The kind's :class:`KindInfo`."""
        return KINDS[self.kind]

    @property
    def onset_ns(self) -> int:
        """Simulation time at which the fault begins, in ns."""
        return round(self.params.onset_s * 1e9)

    @property
    def end_ns(self) -> int | None:
        """Simulation time at which the fault ends, in ns; None: until cleared."""
        d = self.params.duration_s
        return None if d <= 0.0 else self.onset_ns + round(d * 1e9)

    @property
    def side(self) -> str | None:
        """The wheel the fault acts on (``left``, ``right``, ``both``); None for other kinds."""
        return getattr(self.params, "side", None)

    @property
    def label(self) -> str:
        """Scenario-style name: ``flat-left``, ``bump-right``, ``slip``, ``torque-loss-left``."""
        info = self.info
        side = self.side
        base = info.diagnosable or info.name
        if base == "slip" or side is None:
            return base
        return f"{base}-{side}"

    def wire(self, fault_id: int, state: FaultState) -> FaultEvent:
        """This fault as a Bench_Fault_Event (amplitude and param in their wire units)."""
        info, p = self.info, self.params
        amp = getattr(p, info.amplitude) * info.amplitude_scale if info.amplitude else 0.0
        par = getattr(p, info.param) * info.param_scale if info.param else 0.0
        side = SIDES.get(self.side or "", FaultSide.NONE)
        node = getattr(p, "node", None)
        if node is not None:
            amp = float(NODE_IDS[node])
            side = SIDES.get(node, FaultSide.NONE)
        return FaultEvent(
            fault_id, info.fault_type, side, state, float(p.duration_s), float(amp), float(par)
        )


# ---------------------------------------------------------------------------- parsing


def parse_fault(
    entry: Mapping[str, Any], *, source: str, key: str, codec: Codec | None = None
) -> FaultSpec:
    """Validate one ``[[faults]]`` table (``key`` names it in errors, e.g. ``faults[2]``)."""
    if not isinstance(entry, Mapping):
        raise ConfigError(f"{source}: {key} must be a table")
    table = dict(entry)
    kind = table.pop("type", None)
    if kind not in KINDS:
        raise ConfigError(
            f"{source}: {key}.type = {kind!r} is not a fault type; known: {', '.join(KINDS)}"
        )
    info = KINDS[kind]
    if info.sided and "side" not in table:
        choices = next(f for f in dataclasses.fields(info.params) if f.name == "side").metadata[
            "choices"
        ]
        raise ConfigError(
            f"{source}: {key}.side is required for {kind} (one of {', '.join(choices)})"
        )
    p: Any = params.load(info.params, table, source=source, prefix=key)
    if kind == "node-reboot" and p.duration_s != 0.0:
        raise ConfigError(f"{source}: {key}.duration_s must be 0 for node-reboot (instantaneous)")
    frames = getattr(p, "frames", ())
    if frames:
        c = codec or Codec.default()
        for i, name in enumerate(frames):
            try:
                c.frame_key(name)
            except EncodeError as err:
                raise ConfigError(f"{source}: {key}.frames[{i}] = {name!r}: {err}") from err
    return FaultSpec(kind, p)


def parse_schedule(
    entries: Iterable[Mapping[str, Any]], *, source: str, codec: Codec | None = None
) -> tuple[FaultSpec, ...]:
    """Validate a scenario's ``[[faults]]`` array; errors name the file, the key and the bound."""
    if isinstance(entries, Mapping | str | bytes):
        raise ConfigError(f"{source}: faults must be an array of tables ([[faults]])")
    return tuple(
        parse_fault(e, source=source, key=f"faults[{i}]", codec=codec)
        for i, e in enumerate(entries)
    )


def spec_from_command(cmd: FaultCommand, now_ns: int) -> FaultSpec:
    """The fault a Bench_Fault_Command asks for, starting at ``now_ns`` (ConfigError if invalid)."""
    info = _BY_TYPE.get(cmd.fault_type)
    if info is None:
        raise ConfigError(f"Bench_Fault_Command: fault type {cmd.fault_type!r} cannot be injected")
    table: dict[str, Any] = {"onset_s": now_ns / 1e9, "duration_s": cmd.duration_s}
    names = {f.name for f in dataclasses.fields(info.params)}
    if "side" in names:
        if cmd.side not in _SIDE_NAMES:
            raise ConfigError(f"Bench_Fault_Command: {info.name} needs a side (LEFT, RIGHT, BOTH)")
        table["side"] = _SIDE_NAMES[cmd.side]
    if "node" in names:
        node = _NODE_NAMES.get(round(cmd.amplitude))
        if node is None:
            raise ConfigError(
                f"Bench_Fault_Command: {info.name} Amplitude = {cmd.amplitude} is not a node ID"
            )
        table["node"] = node
    elif info.amplitude:
        table[info.amplitude] = cmd.amplitude / info.amplitude_scale
    if info.param:
        value = cmd.param / info.param_scale
        table[info.param] = round(value) if info.param == "bits" else value
    return parse_fault(table | {"type": info.name}, source="Bench_Fault_Command", key="fault")
