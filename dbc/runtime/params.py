"""Typed parameters: declared once with unit, default and bounds, loaded from TOML.

Every tunable of the bench and of the controller is a field of a frozen dataclass
declared with :func:`param`.  :func:`load` builds such a dataclass from a TOML
table and rejects unknown keys, wrong types and values outside the declared
bounds with a :class:`~dbc.errors.ConfigError` that names the file, the dotted
key and the bound, e.g.::

    scenarios/fast.toml: [plant] mass_kg = 900.0 is above its maximum 400.0 (kg)

Both ``controller`` and ``firmware_sim`` use this module; it lives next to the
wire contract because it is the only other thing the two sides share.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from dbc.runtime.errors import ConfigError

T = TypeVar("T")

_UNSET = object()


def param(
    default: Any,
    *,
    unit: str,
    doc: str,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    choices: tuple[Any, ...] | None = None,
) -> Any:
    """Declare a dataclass field with its unit, documentation and bounds.

    ``lo``/``hi`` are inclusive unless ``lo_open`` is set (then ``lo`` is
    exclusive, for quantities that must be strictly positive).  For sequences the
    bounds apply to every element.
    """
    meta = {"unit": unit, "doc": doc, "lo": lo, "hi": hi, "lo_open": lo_open, "choices": choices}
    if isinstance(default, list | dict):
        raise TypeError("use a tuple (immutable) default for sequence parameters")
    return dataclasses.field(default=default, metadata=meta)


def section(cls: type[T], doc: str = "") -> Any:
    """Declare a nested parameter table whose defaults come from ``cls``."""
    return dataclasses.field(
        default_factory=cls, metadata={"unit": "", "doc": doc, "section": True}
    )


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning syntax errors into a ConfigError naming the file."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError as err:
        raise ConfigError(f"{p}: file not found") from err
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{p}: invalid TOML: {err}") from err


def load(cls: type[T], table: Mapping[str, Any] | None, *, source: str, prefix: str = "") -> T:
    """Build the frozen dataclass ``cls`` from ``table``, validating every key.

    ``source`` names the file (or other origin) for error messages and ``prefix``
    the dotted path of the table inside it.
    """
    table = dict(table or {})
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(table) - set(fields))
    if unknown:
        where = f"[{prefix}]" if prefix else "top level"
        raise ConfigError(
            f"{source}: unknown key {_dotted(prefix, unknown[0])!r} in {where}; "
            f"known keys: {', '.join(sorted(fields))}"
        )
    kwargs: dict[str, Any] = {}
    for name, value in table.items():
        f = fields[name]
        key = _dotted(prefix, name)
        typ = hints[name]
        if f.metadata.get("section") or (isinstance(typ, type) and dataclasses.is_dataclass(typ)):
            if not isinstance(value, Mapping):
                raise ConfigError(f"{source}: {key} must be a table, got {type(value).__name__}")
            kwargs[name] = load(typ, value, source=source, prefix=key)
            continue
        kwargs[name] = _coerce(value, typ, f.metadata, source=source, key=key)
    return cls(**kwargs)


def replace(obj: T, changes: Mapping[str, Any], *, source: str, prefix: str = "") -> T:
    """Return a copy of ``obj`` with ``changes`` applied and validated like :func:`load`."""
    merged = _as_table(obj)
    _deep_update(merged, dict(changes))
    return load(type(obj), merged, source=source, prefix=prefix)


def describe(cls: type[Any], prefix: str = "") -> list[dict[str, Any]]:
    """Flatten a parameter class into rows (key, type, unit, default, bounds, doc) for docs."""
    rows: list[dict[str, Any]] = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        key = _dotted(prefix, f.name)
        typ = hints[f.name]
        if f.metadata.get("section"):
            rows.extend(describe(typ, key))
            continue
        default = f.default if f.default is not dataclasses.MISSING else None
        rows.append(
            {
                "key": key,
                "type": _type_name(typ),
                "unit": f.metadata.get("unit", ""),
                "default": default,
                "lo": f.metadata.get("lo"),
                "hi": f.metadata.get("hi"),
                "doc": f.metadata.get("doc", ""),
            }
        )
    return rows


def _dotted(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def _type_name(typ: Any) -> str:
    return getattr(typ, "__name__", str(typ).replace("typing.", ""))


def _as_table(obj: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        out[f.name] = _as_table(v) if dataclasses.is_dataclass(v) else v
    return out


def _deep_update(dst: dict[str, Any], src: dict[str, Any]) -> None:
    for k, v in src.items():
        if isinstance(v, Mapping) and isinstance(dst.get(k), dict):
            _deep_update(dst[k], dict(v))
        else:
            dst[k] = v


def _coerce(value: Any, typ: Any, meta: Mapping[str, Any], *, source: str, key: str) -> Any:
    unit = meta.get("unit", "")
    origin = typing.get_origin(typ)
    args = typing.get_args(typ)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _coerce(value, inner[0], meta, source=source, key=key)
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{source}: {key} must be an array, got {type(value).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(
                _coerce(v, args[0], meta, source=source, key=f"{key}[{i}]")
                for i, v in enumerate(value)
            )
        if len(args) != len(value):
            raise ConfigError(f"{source}: {key} must have {len(args)} elements, got {len(value)}")
        return tuple(
            _coerce(v, a, meta, source=source, key=f"{key}[{i}]")
            for i, (v, a) in enumerate(zip(value, args, strict=True))
        )
    if isinstance(typ, type) and dataclasses.is_dataclass(typ):
        # an element of an array of tables ([[section.items]]), validated like a section
        if isinstance(value, typ):
            value = _as_table(value)
        if not isinstance(value, Mapping):
            raise ConfigError(f"{source}: {key} must be a table, got {type(value).__name__}")
        return load(typ, value, source=source, prefix=key)
    if typ is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{source}: {key} must be true or false, got {value!r}")
        return value
    if typ is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{source}: {key} must be a number ({unit}), got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{source}: {key} = {value} is not finite")
    elif typ is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{source}: {key} must be an integer ({unit}), got {value!r}")
    elif typ is str and not isinstance(value, str):
        raise ConfigError(f"{source}: {key} must be a string, got {value!r}")
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(
            f"{source}: {key} = {value!r} is not one of {', '.join(map(repr, choices))}"
        )
    if isinstance(value, int | float) and not isinstance(value, bool):
        lo, hi = meta.get("lo"), meta.get("hi")
        u = f" ({unit})" if unit else ""
        if lo is not None and (value < lo or (meta.get("lo_open") and value <= lo)):
            word = "must be above" if meta.get("lo_open") else "is below its minimum"
            raise ConfigError(f"{source}: {key} = {value} {word} {lo}{u}")
        if hi is not None and value > hi:
            raise ConfigError(f"{source}: {key} = {value} is above its maximum {hi}{u}")
    return value
