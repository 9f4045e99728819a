"""Foxglove's rules for a channel's schema, and every schema the log has against them."""

from __future__ import annotations

import json
from typing import Any

import pytest

from dbc import logschema as ls
from dbc.codec import Codec
from tools.live.appschema import foxglove_refusal


def _obj(**props: Any) -> bytes:
    return json.dumps({"type": "object", "properties": props}).encode()


@pytest.mark.parametrize(
    ("field", "why"),
    [
        ({"type": ["number", "null"]}, 'type ["number", "null"]'),
        ({"type": "null"}, 'type "null"'),
        ({}, "type null"),
        ({"oneOf": [{"const": "a"}, {"const": "b"}]}, "oneOf"),
        ({"type": "array", "items": {"type": "array", "items": {"type": "number"}}}, "items"),
        ({"type": "string", "contentEncoding": "base32"}, "contentEncoding"),
    ],
)
def test_a_field_foxglove_cannot_type_refuses_the_whole_channel(
    field: dict[str, Any], why: str
) -> None:
    refusal = foxglove_refusal("json", "jsonschema", _obj(ok={"type": "number"}, bad=field))
    assert refusal is not None and refusal.startswith("bad:") and why in refusal


def test_nested_fields_are_named_by_their_path() -> None:
    schema = _obj(raw={"type": "object", "properties": {"v": {"type": ["number", "null"]}}})
    assert (foxglove_refusal("json", "jsonschema", schema) or "").startswith("raw.v:")


def test_the_shapes_foxglove_reads_are_taken() -> None:
    schema = _obj(
        n={"type": "number"},
        i={"type": "integer", "minimum": 0},
        s={"type": "string", "enum": ["A", "B"]},
        b={"type": "boolean"},
        data={"type": "string", "contentEncoding": "base64"},
        level={"oneOf": [{"title": "INFO", "const": 2}, {"title": "WARN", "const": 3}]},
        joints={"type": "array", "items": {"type": "object", "properties": {}}},
        xs={"type": "array", "items": {"type": "number"}},
    )
    assert foxglove_refusal("json", "jsonschema", schema) is None
    assert foxglove_refusal("json", "jsonschema", b"") is None  # schemaless JSON
    assert foxglove_refusal("protobuf", "protobuf", b"\x00") is None  # not looked into
    assert "schema encoding" in (foxglove_refusal("json", "protobuf", b"{}") or "")
    assert "not one Foxglove reads" in (foxglove_refusal("msgpack", "", b"") or "")


def test_every_schema_the_log_can_carry_is_one_foxglove_takes() -> None:
    schemas = {name: ls.foxglove_schema(name) for name in ls.FOXGLOVE_SCHEMAS}
    schemas["can.Message"] = json.dumps(ls.RAW_SCHEMA).encode()
    codec = Codec()
    for m in codec.db.messages:
        schemas[m.name] = json.dumps(ls.decoded_schema(m.name, codec.describe_signals(m.name)))
    record = {
        "x": 1.0,
        "n": 3,
        "ok": True,
        "mode": "TRACK",
        "raw": {"v": float("nan"), "omega": 0.0},
        "missing": None,
        "xs": [1.0, 2.0],
        "rows": [[1.0], [2.0]],
    }
    schemas["controller.record"] = json.dumps(ls.record_schema("controller.record", record))
    refused = {n: w for n, s in schemas.items() if (w := foxglove_refusal("json", "jsonschema", s))}
    assert not refused
    assert len(schemas) > 50


def test_telemetry_numbers_have_one_type_and_untyped_values_are_left_out() -> None:
    schema = ls.record_schema("t", {"x": 1.0, "none": None, "rows": [[1.0]], "xs": [2]})
    assert schema["properties"] == {
        "x": {"type": "number"},
        "xs": {"type": "array", "items": {"type": "number"}},
    }
