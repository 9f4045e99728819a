"""Bench configuration: chair.toml and the dataclasses agree; overrides are validated."""

from __future__ import annotations

import dataclasses
import re

import pytest

from dbc.runtime.errors import ConfigError
from dbc.runtime.params import describe, load_toml
from firmware_sim.config import CHAIR_TOML, BenchConfig, default_config, load_bench_config


def test_chair_toml_holds_exactly_the_declared_defaults() -> None:
    assert default_config() == BenchConfig()
    table = load_toml(CHAIR_TOML)
    declared = {row["key"] for row in describe(BenchConfig)}
    in_toml = {f"{sec}.{k}" for sec, sub in table.items() for k in sub}
    assert in_toml == declared


def test_every_parameter_in_chair_toml_has_a_comment_with_its_unit_or_meaning() -> None:
    lines = CHAIR_TOML.read_text().splitlines()
    units = {row["key"].split(".")[1]: row["unit"] for row in describe(BenchConfig)}
    for i, line in enumerate(lines):
        m = re.match(r"^(\w+) = ", line)
        if not m:
            continue
        assert lines[i - 1].startswith("#"), f"{m.group(1)} has no comment"
        unit = units[m.group(1)]
        if unit:
            comment = " ".join(lines[j] for j in range(i - 3, i) if lines[j].startswith("#"))
            assert unit in comment, f"{m.group(1)}: comment does not give the unit {unit}"


def test_every_parameter_is_declared_with_unit_doc_and_bounds_or_choices() -> None:
    for row in describe(BenchConfig):
        assert row["doc"], row["key"]
        if row["type"] in ("float", "int"):
            meta = _field_meta(row["key"])
            assert row["lo"] is not None or meta.get("choices"), row["key"]


def _field_meta(key: str) -> dict[str, object]:
    sec, name = key.split(".")
    cls = type(getattr(BenchConfig(), sec))
    return dict(next(f for f in dataclasses.fields(cls) if f.name == name).metadata)


def test_overrides_accept_dotted_keys_and_nested_tables() -> None:
    cfg = load_bench_config(
        {"chair.mass_kg": 150, "drive": {"vel_gain": 50.0}, "localizer.enabled": False},
        source="scenarios/heavy.toml",
    )
    assert cfg.chair.mass_kg == 150.0
    assert cfg.drive.vel_gain == 50.0
    assert cfg.localizer.enabled is False
    assert cfg.chair.wheel_radius_m == 0.30  # untouched defaults stay


def test_an_out_of_bound_override_names_the_file_key_and_bound() -> None:
    with pytest.raises(ConfigError) as ei:
        load_bench_config({"chair.mass_kg": 900.0}, source="scenarios/x.toml", prefix="bench")
    assert str(ei.value) == (
        "scenarios/x.toml: bench.chair.mass_kg = 900.0 is above its maximum 400.0 (kg)"
    )


def test_an_unknown_override_key_is_rejected_with_the_known_keys() -> None:
    with pytest.raises(ConfigError, match=r"unknown key 'chair\.mas_kg' in \[chair\]"):
        load_bench_config({"chair.mas_kg": 100.0}, source="s.toml")


def test_a_wrong_type_is_rejected() -> None:
    with pytest.raises(ConfigError, match=r"chair\.mass_kg must be a number \(kg\)"):
        load_bench_config({"chair.mass_kg": "heavy"}, source="s.toml")


def test_a_localizer_period_that_is_not_a_multiple_of_the_step_is_rejected() -> None:
    with pytest.raises(ConfigError, match=r"localizer\.rate_hz = 30\.0 gives a period of 33\.3"):
        load_bench_config({"localizer.rate_hz": 30.0}, source="s.toml")
    cfg = load_bench_config({"localizer.rate_hz": 20.0}, source="s.toml")
    assert cfg.localizer_period_ns == 50_000_000


def test_a_drive_current_limit_above_the_hardware_limit_is_rejected() -> None:
    with pytest.raises(ConfigError, match=r"drive\.current_limit_a = 80\.0 is above motor\.max"):
        load_bench_config({"drive.current_limit_a": 80.0}, source="s.toml")


def test_a_value_given_as_both_a_table_and_a_value_is_rejected() -> None:
    with pytest.raises(ConfigError, match="both as a value and a table"):
        load_bench_config({"chair": 1.0, "chair.mass_kg": 100.0}, source="s.toml")


def test_docs_physics_lists_every_parameter() -> None:
    doc = (CHAIR_TOML.parents[1] / "docs" / "physics.md").read_text()
    missing = [row["key"] for row in describe(BenchConfig) if f"`{row['key']}`" not in doc]
    assert not missing, f"docs/physics.md does not list {missing}"
