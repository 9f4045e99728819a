"""The chair's dynamics as the controller believes them ([body]) match the bench's defaults."""

from __future__ import annotations

import pytest

from controller.config import BodyParams, load_config
from dbc.runtime.errors import ConfigError
from firmware_sim.config import load_bench_config


def test_the_believed_body_matches_the_bench_defaults() -> None:
    chair = load_bench_config(None, source="test").chair
    ours = load_config().body
    assert ours == BodyParams()  # controller.toml states the defaults
    assert ours.mass_kg == chair.mass_kg
    assert ours.yaw_inertia_kgm2 == chair.yaw_inertia_kgm2
    assert ours.wheel_inertia_kgm2 == chair.wheel_inertia_kgm2
    assert ours.com_offset_m == chair.com_offset_m


def test_an_out_of_range_mass_is_an_error_naming_the_key() -> None:
    with pytest.raises(ConfigError, match="mass_kg"):
        load_config(overrides={"body": {"mass_kg": 5.0}})
