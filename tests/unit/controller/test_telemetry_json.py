"""The telemetry's tick plans write exactly what json_bytes would, message for message.

``McapTelemetry.log`` formats the node's tick record with templates made once per layout
(``controller/telemetry.py``, ``_Plan``); the reference here is the log's layout spelled
out independently (``docs/logs.md``) with :func:`dbc.logschema.json_bytes` for every payload.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import dbc.logschema as ls
from controller.telemetry import TICK_TOPIC, McapTelemetry
from tools.logs.mcap_io import iter_messages, read_contents

MS = 1_000_000
_POSED = {
    "ref": ("/controller/reference", ls.REFERENCE_FRAME),
    "est": ("/controller/estimate", ls.ESTIMATE_FRAME),
}
_NAMED = {"err": "/controller/errors"}

Msg = tuple[str, int, int, bytes]  # topic, log time, sequence, data


def _reference(records: Sequence[tuple[int, Mapping[str, Any]]], pose_every: int) -> list[Msg]:
    """The messages of the tick records as the log's layout defines them (json_bytes); a
    tick that raises ends the list with the messages written before and the exception."""
    out: list[tuple[str, int, bytes]] = []
    try:
        _split(records, pose_every, out)
    except Exception as e:
        return [*_numbered(out), _error(e)]
    return _numbered(out)


def _numbered(out: list[tuple[str, int, bytes]]) -> list[Msg]:
    return [(topic, t, i + 1, data) for i, (topic, t, data) in enumerate(out)]


def _error(e: Exception) -> Msg:
    return ("raised", 0, 0, repr(e).encode())


def _split(
    records: Sequence[tuple[int, Mapping[str, Any]]],
    pose_every: int,
    out: list[tuple[str, int, bytes]],
) -> None:
    """Appends the records' messages (topic, log time, data) to ``out`` as they are written."""

    def pose(base: str, frame: str, t: int, v: Mapping[str, Any]) -> None:
        try:
            x, y, h = float(v["x"]), float(v["y"]), float(v["heading"])
        except (KeyError, TypeError, ValueError):
            return
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(h)):
            return  # a pose that is not finite has no pose and transform messages
        out.append((base + "/pose", t, ls.pose_in_frame(t, ls.WORLD_FRAME, x, y, h)))
        out.append((base + "/tf", t, ls.frame_transform(t, ls.WORLD_FRAME, frame, x, y, h)))

    for k, (t, rec) in enumerate(records):
        scalars: dict[str, Any] = {}
        command: dict[str, Any] = {}
        for key, value in rec.items():
            if not isinstance(value, Mapping):
                scalars[key] = value
            elif key in _POSED:
                base, frame = _POSED[key]
                out.append((base, t, ls.json_bytes(value)))
                if k % pose_every == 0:
                    pose(base, frame, t, value)
            elif key == "internals":
                groups: dict[str, dict[str, Any]] = {}
                for name, x in value.items():
                    group, dot, field = name.partition(".")
                    topic = f"/controller/internals/{group}" if dot else "/controller/internals"
                    groups.setdefault(topic, {})[field if dot else name] = x
                out.extend((topic, t, ls.json_bytes(g)) for topic, g in groups.items())
            elif key in _NAMED:
                out.append((_NAMED[key], t, ls.json_bytes(value)))
            elif key == "cmd":
                command.update(value)
            elif key == "cmd_raw":
                command["raw"] = dict(value)
            else:
                out.append((f"/controller/{key}", t, ls.json_bytes(value)))
        if command:
            out.append(("/controller/command", t, ls.json_bytes(command)))
        if scalars:
            out.append((TICK_TOPIC, t, ls.json_bytes(scalars)))


def _written(records: Sequence[tuple[int, Mapping[str, Any]]], pose_every: int) -> list[Msg]:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "c.mcap"
        tel = McapTelemetry(path, pose_every=pose_every)
        error: list[Msg] = []
        try:
            for t, rec in records:
                tel.log(TICK_TOPIC, t, rec)
        except Exception as e:  # e.g. math.sin(inf) for a pose: the same as the reference
            error.append(_error(e))
        tel.close()
        msgs = [(ch.topic, m.log_time, m.sequence, m.data) for ch, m in iter_messages(path)]
        return msgs + error


def _node_record(k: int) -> dict[str, Any]:
    """controller/node.py's tick record (adaptive law's internals), finite floats."""
    f = [math.sin(0.37 * k + i) * 10.0 ** (i % 7 - 3) for i in range(60)]
    return {
        "route_time_s": 0.01 * k,
        "ref": dict(
            zip(("x", "y", "heading", "v", "omega", "a", "alpha", "curvature"), f[:8], strict=True)
        ),
        "est": dict(zip(("x", "y", "heading", "v", "omega"), f[8:13], strict=True)),
        "err": {"x_e": f[13], "y_e": f[14], "phi_e": f[15]},
        "cmd_raw": {"v": f[16], "omega": f[17]},
        "cmd": {"v": f[18], "omega": f[17], "wheel_left_radps": f[19], "wheel_right_radps": f[20]},
        "step_us": 12.5 + k,
        "internals": {
            "e_x_m": f[21],
            "e_y_m": f[22],
            "parked": 0.0,
            "qp.status": 1.0,
            "qp.iter": float(k % 5),
            "qp.solve_us": f[23],
            "weights.scale_y": f[24],
        },
        "diagnosis": {
            "hypothesis": "flat-left" if k >= 5 else "none",
            "probability": 0.9 if k < 5 else 0.6,
            "p": {"none": 0.9 if k < 5 else 0.3, "flat-left": 0.1 if k < 5 else 0.6},
            "radius_left": 0.3,
            "radius_right": 0.3,
        },
    }


@pytest.fixture
def json_calls(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts json_bytes calls (the general path's encoder)."""
    calls: list[int] = []
    real = ls.json_bytes

    def counting(record: Mapping[str, Any]) -> bytes:
        calls.append(1)
        return real(record)

    monkeypatch.setattr(ls, "json_bytes", counting)
    return calls


def _written_by_the_plan(
    records: Sequence[tuple[int, Mapping[str, Any]]], pose_every: int, json_calls: list[int]
) -> list[Msg]:
    """:func:`_written`, checking that only the first tick called json_bytes (its schemas and
    payloads): the plan compiled after it formatted all the others."""
    _written(records[:1], pose_every)
    n_first = len(json_calls)
    json_calls.clear()
    got = _written(records, pose_every)
    assert len(json_calls) == n_first
    return got


def test_node_records_use_the_compiled_plan_and_write_json_bytes_output(
    json_calls: list[int],
) -> None:
    records = [(k * 10 * MS, _node_record(k)) for k in range(30)]
    got = _written_by_the_plan(records, 3, json_calls)
    assert got == _reference(records, 3)
    assert {m[0] for m in got} >= {
        "/controller/internals/qp",
        "/controller/internals/weights",
        "/controller/diagnosis",
        "/controller/estimate/tf",
    }


def test_non_finite_zero_signs_and_unchanged_channels_keep_json_bytes_output(
    json_calls: list[int],
) -> None:
    """Values that a template or the reuse of the previous tick's bytes could get wrong."""
    base = _node_record(3)
    variants = []
    for err in (
        {"x_e": 0.0, "y_e": 1.5, "phi_e": math.nan},
        {"x_e": -0.0, "y_e": 1.5, "phi_e": math.nan},  # equal to the last, but not its bytes
        {"x_e": -0.0, "y_e": 1.5, "phi_e": math.inf},
        {"x_e": 0.0, "y_e": 1.5, "phi_e": -math.inf},
        {"x_e": 0.0, "y_e": 1.5, "phi_e": -math.inf},
        {"x_e": 1e308, "y_e": 1e308, "phi_e": 5e-324},  # the finiteness check overflows
        {"x_e": 1e308, "y_e": 1e308, "phi_e": 5e-324},
        {"x_e": 1e16, "y_e": 1e-7, "phi_e": 123456789.123},
    ):
        rec = dict(base)
        rec["err"] = err
        variants.append(rec)
    records = [(k * 10 * MS, r) for k, r in enumerate(variants)]
    assert _written_by_the_plan(records, 1, json_calls) == _reference(records, 1)


def test_records_that_do_not_fit_the_plan_fall_back_to_json_bytes() -> None:
    base = _node_record(1)
    changed: list[dict[str, Any]] = [dict(base) for _ in range(9)]
    changed[1]["step_us"] = True  # bool is not a float (nor an int)
    changed[2]["step_us"] = 7  # an int: its own plan
    changed[3]["est"] = {**base["est"], "v": np.float64(0.1) / 3}  # repr differs from json
    changed[4]["internals"] = {"qp.status": None, **base["internals"]}  # other keys
    changed[5]["diagnosis"] = {**base["diagnosis"], "p": {"none": 1.0}}  # nested keys
    changed[6]["cmd"] = {"raw": 1.0, **base["cmd"]}  # merged into the command
    changed[7]["err"] = {"y_e": 1.0, "x_e": 2.0, "phi_e": 3.0}  # key order
    records = [(k * 10 * MS, r) for k, r in enumerate(changed + changed)]
    assert _written(records, 2) == _reference(records, 2)


# ----------------------------------------------------------------------------- property

#: Values by kind; a record's slot keeps its kind (so that records fit their plan) but for
#: a new value of another kind now and then.  Numpy floats are float subclasses whose repr
#: is not json's: a plan never formats them.
_KINDS = {
    "float": st.one_of(
        st.sampled_from([0.0, -0.0, 1.0, 0.1, -2.5e-8, 1e16, 1e300, math.nan, math.inf, -math.inf]),
        st.floats(),
    ),
    "int": st.one_of(st.sampled_from([0, -3, 2**64]), st.integers(-(2**70), 2**70)),
    "bool": st.booleans(),
    "none": st.none(),
    "str": st.one_of(
        st.sampled_from(["", 'q"uo\\te', "ünïcödé \u2028 \x00 \U0001f600"]), st.text(max_size=4)
    ),
    "numpy": st.builds(np.float64, st.floats()),
}
_PLAIN = ["float"] * 6 + ["int", "bool", "none", "str"]
_names = st.sampled_from(
    ["x", "y", "heading", "v", "a", "raw", "%", "%%", "%r", "50%s", 'q"', "é\n", "p.q", ".z", "z."]
)
_internal_names = st.sampled_from(
    [
        "e_x_m",
        "parked",
        "qp.status",
        "qp.iter",
        "qp.%d",
        "qp.%%",
        "weights.w",
        "a.b.c",
        ".x",
        "y.",
        "é.ü",
    ]
)


@st.composite
def _layout(draw: st.DrawFn) -> dict[str, Any]:
    """A tick record's keys: the node's groups (some left out, some extra), leaves as 0."""

    def flat(names: st.SearchStrategy[str], max_size: int) -> dict[str, Any]:
        keys = draw(st.lists(names, max_size=max_size, unique=True))
        return dict.fromkeys(keys, 0)

    rec: dict[str, Any] = {}
    for key in draw(st.permutations(["route_time_s", "ref", "est", "err", "cmd_raw", "cmd"])):
        if draw(st.integers(0, 5)):
            rec[key] = 0 if key == "route_time_s" else flat(_names, 5)
    if draw(st.booleans()):
        rec["ref"] = {"x": 0, "y": 0, "heading": 0, **rec.get("ref", {})}
    rec["step_us"] = 0
    rec["internals"] = flat(_internal_names, 6)
    rec["diagnosis"] = {"hypothesis": 0, "p": flat(_names, 3), "probability": 0}
    if draw(st.booleans()):
        rec["extra"] = {"nested": flat(_names, 2), "k": 0}
    if draw(st.booleans()):
        rec["note"] = 0
    return rec


@st.composite
def _reordered(draw: st.DrawFn, layout: dict[str, Any]) -> dict[str, Any]:
    """``layout`` with the same top-level keys, a nested dict's keys reordered or renamed:
    only the nested keys tell the records apart."""
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in layout.items()}
    nested = [k for k, v in out.items() if isinstance(v, dict) and v]
    if nested:
        key = draw(st.sampled_from(nested))
        names = list(out[key])
        if len(names) > 1 and draw(st.booleans()):
            names = draw(st.permutations(names))
        else:
            names[-1] = names[-1] + "_"
        out[key] = {n: out[key].get(n, 0) for n in names}
    return out


def _fill(layout: dict[str, Any], leaves: list[Any]) -> dict[str, Any]:
    it = iter(leaves)

    def fill(d: dict[str, Any]) -> dict[str, Any]:
        return {k: fill(v) if isinstance(v, dict) else next(it) for k, v in d.items()}

    return fill(layout)


def _count(layout: dict[str, Any]) -> int:
    return sum(_count(v) if isinstance(v, dict) else 1 for v in layout.values())


@st.composite
def _ticks(draw: st.DrawFn) -> list[tuple[int, dict[str, Any]]]:
    """Ticks of one or two layouts; each value kept from the last tick of its layout, or new
    (mostly of the same kind)."""
    kinds = _PLAIN + draw(st.sampled_from([[], [], ["numpy"]]))
    first = draw(_layout())
    layouts = [first, draw(st.one_of(_layout(), _reordered(first)))]
    slots = [[draw(st.sampled_from(kinds)) for _ in range(_count(lay))] for lay in layouts]
    last: list[list[Any] | None] = [None, None]
    out = []
    for k in range(draw(st.integers(1, 12))):
        i = draw(st.sampled_from([0, 0, 0, 1]))
        prev = last[i]
        leaves = [
            prev[j] if prev is not None and draw(st.integers(0, 3)) else draw(_KINDS[kind])
            for j, kind in enumerate(slots[i])
        ]
        if leaves and not draw(st.integers(0, 7)):  # a value of another kind: not the plan's
            j = draw(st.integers(0, len(leaves) - 1))
            leaves[j] = draw(_KINDS[draw(st.sampled_from(kinds))])
        last[i] = leaves
        out.append((k * 10 * MS, _fill(layouts[i], leaves)))
    return out


# 100 examples (hypothesis's default): 300 took 40 s of a loaded CI run for this one check
@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(records=_ticks(), pose_every=st.integers(1, 3))
def test_any_tick_records_give_the_messages_json_bytes_gives(
    records: list[tuple[int, dict[str, Any]]], pose_every: int
) -> None:
    assert _written(records, pose_every) == _reference(records, pose_every)


def test_keys_with_percent_signs_quotes_and_unicode_are_escaped(json_calls: list[int]) -> None:
    keys = ["%", "%%", "%r", "50%s", "%(x)s", 'q"', "\\", "é\n\u2028"]
    records = [
        (
            k * 10 * MS,
            {
                "ref": {key: 0.5 * k + i for i, key in enumerate(keys)},
                "internals": {f"g.{key}": 1.0 / (k + 1) for key in keys},
                **{key: float(k) for key in keys},
            },
        )
        for k in range(4)
    ]
    assert _written_by_the_plan(records, 2, json_calls) == _reference(records, 2)


def test_channels_and_schemas_are_registered_as_before(tmp_path: Path) -> None:
    records = [(k * 10 * MS, _node_record(k)) for k in range(3)]
    path = tmp_path / "c.mcap"
    tel = McapTelemetry(path)
    for t, rec in records:
        tel.log(TICK_TOPIC, t, rec)
    tel.close()
    contents = read_contents(path)
    topics = [ch.topic for _id, ch in sorted(contents.channels.items())]
    assert topics == list(dict.fromkeys(m[0] for m in _reference(records[:1], 1)))
    first = _node_record(0)
    ch = next(c for c in contents.channels.values() if c.topic == "/controller/diagnosis")
    schema = contents.schemas[ch.schema_id]
    assert schema.data == ls.json_bytes(
        ls.record_schema("controller.diagnosis", first["diagnosis"])
    )


def test_a_non_finite_pose_is_logged_as_nulls_without_raising(tmp_path: Path) -> None:
    from controller.telemetry import TICK_TOPIC, McapTelemetry
    from tools.logs.mcap_io import iter_messages

    tel = McapTelemetry(tmp_path / "c.mcap", pose_every=1)
    bad = {"x": 1.0, "y": float("nan"), "heading": float("inf"), "v": 0.0, "omega": 0.0}
    tel.log(TICK_TOPIC, 0, {"route_time_s": 0.0, "est": bad})  # must not raise
    tel.log(TICK_TOPIC, 10_000_000, {"route_time_s": 0.01, "est": dict(bad, y=2.0, heading=0.5)})
    tel.close()
    got = [(c.topic, m.data) for c, m in iter_messages(tmp_path / "c.mcap")]
    est = [d for t, d in got if t == "/controller/estimate"]
    assert est[0] == b'{"x":1.0,"y":null,"heading":null,"v":0.0,"omega":0.0}'
    poses = [t for t, _ in got if t.endswith("/pose")]
    assert poses == ["/controller/estimate/pose"]  # only the finite one
