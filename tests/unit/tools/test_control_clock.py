"""`control`'s clock: the command line's --realtime/--lockstep, else the configuration's
[loop] clock, so that a chair's file runs on the wall clock without waiting for a bench."""

from __future__ import annotations

from pathlib import Path

import pytest

from controller.config import load_config
from dbc.runtime.errors import ConfigError
from tools.cli.control import realtime_clock
from tools.deploy.service import CHAIR_TEMPLATE


def test_the_packaged_configuration_is_lockstep_for_the_bench() -> None:
    cfg = load_config(None)
    assert cfg.loop.clock == "lockstep"
    assert realtime_clock(cfg, realtime=False, lockstep=False) is False
    assert realtime_clock(cfg, realtime=True, lockstep=False) is True


def test_a_chair_file_runs_on_the_wall_clock_unless_told_lockstep() -> None:
    cfg = load_config(CHAIR_TEMPLATE)
    assert cfg.loop.clock == "realtime"
    assert realtime_clock(cfg, realtime=False, lockstep=False) is True
    assert realtime_clock(cfg, realtime=False, lockstep=True) is False


def test_both_flags_are_refused() -> None:
    with pytest.raises(ConfigError, match="--lockstep and --realtime"):
        realtime_clock(load_config(None), realtime=True, lockstep=True)


def test_an_unknown_clock_names_the_key(tmp_path: Path) -> None:
    bad = tmp_path / "chair.toml"
    bad.write_text('[loop]\nclock = "wall"\n')
    with pytest.raises(ConfigError, match="clock"):
        load_config(bad)
