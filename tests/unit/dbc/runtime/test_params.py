"""Typed parameters: arrays of tables ([[section.items]]) are validated like sections."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

import pytest

from dbc.runtime import params
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import param


@dataclass(frozen=True)
class Item:
    side: str = param("left", unit="", choices=("left", "right"), doc="which")
    size_m: float = param(1.0, unit="m", lo=0.0, hi=2.0, doc="how big")


@dataclass(frozen=True)
class Holder:
    items: tuple[Item, ...] = param((), unit="", doc="an array of tables")


def test_an_array_of_tables_loads_as_typed_items_and_round_trips() -> None:
    h = params.load(Holder, {"items": [{"side": "right"}, {"size_m": 1.5}]}, source="f.toml")
    assert h.items == (Item(side="right"), Item(size_m=1.5))
    again = params.load(Holder, json.loads(json.dumps(dataclasses.asdict(h))), source="log")
    assert again == h
    assert params.replace(h, {}, source="x") == h


def test_a_bad_item_is_an_error_naming_its_index_and_key() -> None:
    with pytest.raises(ConfigError, match=r"f.toml: items\[1\].size_m = 3.0 is above its maximum"):
        params.load(Holder, {"items": [{}, {"size_m": 3.0}]}, source="f.toml")
    with pytest.raises(ConfigError, match=r"unknown key 'items\[0\].colour'"):
        params.load(Holder, {"items": [{"colour": "red"}]}, source="f.toml")
    with pytest.raises(ConfigError, match=r"items\[0\] must be a table"):
        params.load(Holder, {"items": [3]}, source="f.toml")
