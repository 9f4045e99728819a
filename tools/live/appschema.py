"""Whether Foxglove (or Lichtblick) can read a channel: its rules for a channel's schema.

A Foxglove WebSocket client turns each advertised channel's schema into the app's
datatypes before any panel sees a message.  For JSON messages with a JSON schema the
app takes a property only with one ``type`` of ``boolean``, ``string``, ``number``,
``integer``, ``object`` or ``array`` (an array's ``items`` with one of those), a
``oneOf`` of numeric constants (an enum such as ``foxglove.Log``'s level), and
``contentEncoding`` ``base64`` on a string (shown as bytes).  Anything else (a list of
types such as ``["number", "null"]``, ``"null"``, a property without a type) makes it
refuse the whole channel: *Failed to parse channel schema*, and no panel shows the topic.

:func:`foxglove_refusal` states these rules (the app's parser is not a package Python
can use), so that the view warns about a channel nobody could watch and the tests can
hold every channel of the log to them.  ``tests/repro/foxglove_client`` checks the same
with the protocol's JavaScript client on a live run.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

_SCALARS = frozenset({"boolean", "string", "number", "integer"})
#: message encoding -> the schema encodings the app pairs it with (None: no schema)
_PAIRS: dict[str, frozenset[str | None]] = {
    "json": frozenset({None, "", "jsonschema"}),
    "protobuf": frozenset({None, "", "protobuf"}),
    "flatbuffer": frozenset({None, "", "flatbuffer"}),
    "ros1": frozenset({None, "", "ros1msg"}),
    "cdr": frozenset({None, "", "ros2msg", "ros2idl", "omgidl"}),
}


def foxglove_refusal(
    message_encoding: str, schema_encoding: str | None, schema_data: bytes | str
) -> str | None:
    """Why Foxglove would refuse a channel with this encoding and schema, or None if it
    takes it (JSON schemas are checked field by field; other encodings by pair only)."""
    allowed = _PAIRS.get(message_encoding)
    if allowed is None:
        return f"message encoding {message_encoding!r} is not one Foxglove reads"
    if schema_encoding not in allowed:
        return f"message encoding {message_encoding!r} with schema encoding {schema_encoding!r}"
    if message_encoding != "json" or not schema_data:
        return None
    try:
        schema = json.loads(schema_data)
    except ValueError as err:
        return f"the JSON schema is not JSON: {err}"
    if not isinstance(schema, Mapping):
        return "the JSON schema is not an object"
    return _object_refusal(schema, "")


def _object_refusal(schema: Mapping[str, Any], where: str) -> str | None:
    if schema.get("type") != "object":
        return f'{where or "<root>"}: type {json.dumps(schema.get("type"))}, expected "object"'
    props = schema.get("properties") or {}
    for name, field in props.items():
        path = f"{where}.{name}" if where else name
        why = _field_refusal(field if isinstance(field, Mapping) else {}, path)
        if why is not None:
            return why
    return None


def _field_refusal(field: Mapping[str, Any], path: str) -> str | None:
    one_of = field.get("oneOf")
    if isinstance(one_of, list):
        if all(isinstance(alt, Mapping) and _is_number(alt.get("const")) for alt in one_of):
            return None
        return f"{path}: oneOf alternatives that are not numeric constants"
    kind = field.get("type")
    kind = kind if isinstance(kind, str) else repr(kind)  # a list of types is refused too
    if kind == "object":
        return _object_refusal(field, path)
    if kind == "array":
        items = field.get("items")
        items = items if isinstance(items, Mapping) else {}
        if items.get("type") == "object":
            return _object_refusal(items, path)
        if not isinstance(items.get("type"), str) or items.get("type") not in _SCALARS:
            return f"{path}: array items of type {json.dumps(items.get('type'))}"
        if items.get("type") == "string" and "contentEncoding" in items:
            return f"{path}: contentEncoding on array items"
        return None
    if kind not in _SCALARS:
        return (
            f"{path}: type {json.dumps(field.get('type'))} (Foxglove takes exactly one of boolean, string, "
            "number, integer, object, array)"
        )
    if kind == "string" and field.get("contentEncoding") not in (None, "base64"):
        return f"{path}: contentEncoding {json.dumps(field.get('contentEncoding'))}"
    return None


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)
