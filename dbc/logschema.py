"""The log contract: channel names, JSON schemas and message builders of the MCAP logs.

Both writers of the run's log use this module: the bus recorder (``tools/logs/recorder.py``)
and the controller's own log (``controller/telemetry.py``), which may not import
``tools/``.  Like the DBC for frames, it is the one place where the log's layout is
spelled out (``docs/logs.md`` lists every channel).

* :data:`RAW_SCHEMA` mirrors python-can's ``Message`` (payload base64);
* :func:`decoded_schema` describes ``/can/<DBC message>`` channels from the DBC
  (units and ranges in the descriptions, ``<signal>_label`` for choice signals, the set
  bits' names for bit fields, :func:`flags_label`);
* the ``foxglove.*`` schemas are package data (``dbc/schemas/``), written from
  Foxglove's published definitions, so that Foxglove shows poses, transforms,
  joint states and logs natively.  The builders below produce their JSON with
  ``%``-formatting (``json.dumps`` is several times slower on the recorder's hot path);
* :func:`json_bytes` encodes records whose values may be non-finite: JSON has no
  NaN, so they become ``null``.
"""

from __future__ import annotations

import enum
import json
import math
from collections.abc import Iterable, Mapping
from functools import cache
from importlib import resources
from typing import Any

#: Root frame of the 3D scene; poses and transforms are given in it.
WORLD_FRAME = "world"
TRUTH_FRAME = "chair_truth"
ESTIMATE_FRAME = "chair_estimate"
REFERENCE_FRAME = "chair_reference"
WHEEL_JOINTS = ("left_wheel", "right_wheel")

#: Foxglove schemas shipped in ``dbc/schemas/``.
FOXGLOVE_SCHEMAS = (
    "foxglove.PoseInFrame",
    "foxglove.FrameTransform",
    "foxglove.Log",
    "foxglove.JointStates",
)

#: Signals the recorder derives Foxglove channels from (the DBC's names; a unit test checks
#: them against the DBC).  Kept here, in ``dbc/``, so that signal names stay out of ``tools/``.
TRUTH_POSE_SIGNALS = ("X", "Y", "Heading")  # Bench_Truth_Pose: m, m, rad
ENCODER_SIGNALS = ("Pos_Estimate", "Vel_Estimate")  # <side>_Get_Encoder_Estimates: rev, rev/s
#: DBC message names starting with this are fault injection/events (logged as foxglove.Log).
FAULT_MESSAGE_PREFIX = "Bench_Fault"

RAW_TOPIC = "/can/raw"
DECODED_PREFIX = "/can/"

RAW_SCHEMA: dict[str, Any] = {
    "title": "can.Message",
    "description": "A CAN frame as python-can's Message; data is base64",
    "type": "object",
    "properties": {
        "timestamp": {"type": "number", "description": "receive time, s since the epoch"},
        "arbitration_id": {"type": "integer"},
        "is_extended_id": {"type": "boolean"},
        "is_remote_frame": {"type": "boolean"},
        "is_error_frame": {"type": "boolean"},
        "is_fd": {"type": "boolean"},
        "dlc": {"type": "integer"},
        "data": {"type": "string", "contentEncoding": "base64"},
        "channel": {"type": "string", "description": "bus channel; absent when it had none"},
    },
    "required": ["timestamp", "arbitration_id", "is_extended_id", "dlc", "data"],
}


class LogLevel(enum.IntEnum):
    """foxglove.LogLevel."""

    UNKNOWN = 0
    DEBUG = 1
    INFO = 2
    WARNING = 3
    ERROR = 4
    FATAL = 5


@cache
def foxglove_schema(name: str) -> bytes:
    """The JSON schema ``name`` (one of :data:`FOXGLOVE_SCHEMAS`) as bytes."""
    if name not in FOXGLOVE_SCHEMAS:
        raise KeyError(f"no Foxglove schema {name!r}; known: {', '.join(FOXGLOVE_SCHEMAS)}")
    return (resources.files("dbc") / "schemas" / f"{name}.json").read_bytes()


def decoded_schema(name: str, signals: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Schema of the decoded channel of DBC message ``name`` (``Codec.describe_signals`` rows)."""
    props: dict[str, Any] = {}
    for s in signals:
        unit = f" [{s['unit']}]" if s["unit"] else ""
        props[s["name"]] = {
            "type": "number",
            "description": f"{s['comment']}{unit} range {s['minimum']}..{s['maximum']}".strip(),
        }
        if s["choices"] and s.get("flags"):
            props[s["name"] + "_label"] = {
                "type": "string",
                "description": "the names of the set bits, joined by '|' (a bit without a "
                f"name in hex), {s['choices'].get(0, '0')!r} for none",
            }
        elif s["choices"]:
            props[s["name"] + "_label"] = {
                "type": "string",
                "enum": sorted(set(s["choices"].values())),
            }
    return {"title": name, "type": "object", "properties": props}


def flags_label(value: int, bits: Mapping[int, str]) -> str:
    """The ``<signal>_label`` of a bit-field signal (``Codec.describe_signals``'s ``flags``):
    the names in ``bits`` of the bits set in ``value``, lowest first, joined by ``|``; a set bit
    without a name is written in hex; ``bits[0]`` (or ``"0"``) when no bit is set."""
    value = int(value)
    if value == 0:
        return bits.get(0, "0")
    names = []
    bit = 1
    while bit <= value:
        if value & bit:
            names.append(bits.get(bit, f"0x{bit:X}"))
        bit <<= 1
    return "|".join(names)


def record_schema(title: str, record: Mapping[str, Any]) -> dict[str, Any]:
    """A JSON schema for ``record`` derived from its values (telemetry channels).

    Every property has one ``type``: Foxglove (and Lichtblick) turn a JSON schema into
    their datatypes and refuse the whole channel if a property has a list of types (such
    as number or null) or none.  A number that is not finite is still written as
    ``null`` (:func:`json_bytes`, the log's contract), which a strict validator of this
    schema refuses; Foxglove reads it, and its plots leave a gap there.  A value without
    a JSON type of its own (``None``, a list of lists) is left out of the schema."""
    out = _props(record)
    out["title"] = title
    return out


def _props(record: Mapping[str, Any]) -> dict[str, Any]:
    props: dict[str, Any] = {}
    for k, v in record.items():
        if isinstance(v, bool):
            props[k] = {"type": "boolean"}
        elif isinstance(v, int | float):
            props[k] = {"type": "number"}
        elif isinstance(v, str):
            props[k] = {"type": "string"}
        elif isinstance(v, Mapping):
            props[k] = _props(v)
        elif isinstance(v, list | tuple):
            first = next((x for x in v if x is not None), 0.0)
            item = _props({"_": first})["properties"].get("_")
            if item is not None and item.get("type") != "array":  # Foxglove: no nesting
                props[k] = {"type": "array", "items": item}
        # else (None, or a value JSON does not type): left out of the schema, which
        # admits any further property; a property without a type would make Foxglove
        # refuse the whole channel
    return {"type": "object", "properties": props}


# ------------------------------------------------------------------ JSON builders


_encode = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode


def json_bytes(record: Mapping[str, Any]) -> bytes:
    """Compact JSON; non-finite floats (which JSON cannot carry) become ``null``."""
    try:
        return _encode(record).encode()
    except ValueError:
        return _encode(_finite(record)).encode()


def _finite(v: Any) -> Any:
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, Mapping):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_finite(x) for x in v]
    return v


def _num(v: float) -> str:
    return repr(v) if math.isfinite(v) else "null"


_TIME = '{"sec":%d,"nsec":%d}'
_POSE = (
    '{"timestamp":%s,"frame_id":"%s","pose":{"position":{"x":%s,"y":%s,"z":0.0},'
    '"orientation":{"x":0.0,"y":0.0,"z":%s,"w":%s}}}'
)
_LOG = '{"timestamp":%s,"level":%d,"message":%s,"name":%s,"file":%s,"line":%d}'
_JOINT = '{"name":"%s","position":%s,"velocity":%s}'
_JOINTS = '{"timestamp":%s,"joints":[%s]}'
_TF = (
    '{"timestamp":%s,"parent_frame_id":"%s","child_frame_id":"%s",'
    '"translation":{"x":%s,"y":%s,"z":0.0},"rotation":{"x":0.0,"y":0.0,"z":%s,"w":%s}}'
)


def time_json(t_ns: int) -> str:
    """A foxglove time ``{"sec", "nsec"}`` (times before the epoch clamp to 0)."""
    t_ns = max(0, int(t_ns))
    return _TIME % divmod(t_ns, 1_000_000_000)


def pose_in_frame(t_ns: int, frame_id: str, x_m: float, y_m: float, heading_rad: float) -> bytes:
    """foxglove.PoseInFrame of a planar pose (heading about +z)."""
    h = 0.5 * heading_rad
    return (
        _POSE
        % (time_json(t_ns), frame_id, _num(x_m), _num(y_m), _num(math.sin(h)), _num(math.cos(h)))
    ).encode()


def frame_transform(
    t_ns: int, parent: str, child: str, x_m: float, y_m: float, heading_rad: float
) -> bytes:
    """foxglove.FrameTransform placing planar frame ``child`` in ``parent``."""
    h = 0.5 * heading_rad
    return (
        _TF
        % (
            time_json(t_ns),
            parent,
            child,
            _num(x_m),
            _num(y_m),
            _num(math.sin(h)),
            _num(math.cos(h)),
        )
    ).encode()


def log_message(
    t_ns: int, level: LogLevel, message: str, name: str, file: str = "", line: int = 0
) -> bytes:
    """foxglove.Log."""
    return (
        _LOG
        % (
            time_json(t_ns),
            int(level),
            json.dumps(message),
            json.dumps(name),
            json.dumps(file),
            max(0, int(line)),
        )
    ).encode()


def joint_states(t_ns: int, joints: Iterable[tuple[str, float, float]]) -> bytes:
    """foxglove.JointStates from ``(name, position_rad, velocity_radps)`` triples."""
    items = ",".join(_JOINT % (n, _num(p), _num(v)) for n, p, v in joints)
    return (_JOINTS % (time_json(t_ns), items)).encode()
