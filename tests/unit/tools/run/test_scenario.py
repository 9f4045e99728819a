"""Scenario and route lookup: the packaged scenarios, a directory searched before them, seeds."""

from __future__ import annotations

from pathlib import Path

import pytest

from dbc.runtime.errors import ConfigError
from tools.run import scenario
from tools.run.plan import make_plan

ROOT = Path(__file__).resolve().parents[4]


@pytest.fixture(autouse=True)
def no_scenario_dir(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(scenario.ENV_VAR, "")


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_packaged_scenarios_are_the_checkouts_scenarios_found_through_the_package() -> None:
    assert scenario.packaged_dir() == (ROOT / "scenarios").resolve()
    assert scenario.find("fault-free") == (ROOT / "scenarios" / "fault-free.toml").resolve()
    assert scenario.route_file("paper") == (ROOT / "scenarios" / "routes" / "paper.toml").resolve()


def test_the_directory_in_the_environment_is_searched_before_the_packaged_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    mine = _write(tmp_path / "fault-free.toml", '[scenario]\nroute = "short"\n')
    extra = _write(tmp_path / "mine.toml", '[scenario]\nroute = "short"\n')
    monkeypatch.setenv(scenario.ENV_VAR, str(tmp_path))
    assert scenario.find("fault-free") == mine
    assert scenario.find("mine") == extra
    assert scenario.find("short") == scenario.packaged_dir() / "short.toml"
    # a route name falls back to the packaged routes
    assert scenario.load("mine").route_path == scenario.packaged_dir() / "routes" / "short.toml"


def test_a_route_next_to_the_scenario_file_wins(tmp_path: Path) -> None:
    own = _write(
        tmp_path / "routes" / "short.toml", (ROOT / "scenarios/routes/short.toml").read_text()
    )
    s = _write(tmp_path / "s.toml", '[scenario]\nroute = "short"\n')
    assert scenario.load(str(s)).route_path == own


def test_an_unknown_name_lists_where_it_looked_and_what_is_known(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _write(tmp_path / "mine.toml", "")
    monkeypatch.setenv(scenario.ENV_VAR, str(tmp_path))
    with pytest.raises(ConfigError) as err:
        scenario.find("nowhere")
    text = str(err.value)
    assert str(tmp_path) in text and str(scenario.packaged_dir()) in text
    assert "mine" in text and "fault-free" in text
    s = _write(tmp_path / "s.toml", '[scenario]\nroute = "nowhere"\n')
    with pytest.raises(ConfigError, match=r"s\.toml: scenario\.route = 'nowhere': unknown route"):
        scenario.load(str(s))


def test_a_controller_named_in_any_case_in_a_scenario_file_is_the_registered_one(
    tmp_path: Path,
) -> None:
    s = _write(tmp_path / "s.toml", '[scenario]\nroute = "short"\ncontroller = "ROBUST"\n')
    assert make_plan(scenario.load(str(s)), None, realtime=False).controller == "robust"
    assert make_plan(scenario.load(str(s)), "ANTIFRAGILE", realtime=False).controller == (
        "antifragile"
    )
    bad = _write(tmp_path / "b.toml", '[scenario]\nroute = "short"\ncontroller = "pid"\n')
    with pytest.raises(
        ConfigError, match=r"b\.toml: scenario\.controller: unknown controller 'pid'"
    ):
        make_plan(scenario.load(str(bad)), None, realtime=False)


@pytest.mark.parametrize("seed", [-1, scenario.SEED_MAX + 1, 99999999999])
def test_a_seed_outside_the_scenarios_bounds_is_refused_naming_them(seed: int) -> None:
    with pytest.raises(ConfigError, match=rf"--seed {seed} is outside \[0, 2147483647\]"):
        make_plan(scenario.load("short"), None, realtime=False, seed=seed)


def test_the_command_line_and_a_scenario_file_bound_the_seed_alike(tmp_path: Path) -> None:
    top = _write(
        tmp_path / "top.toml", f'[scenario]\nroute = "short"\nseed = {scenario.SEED_MAX}\n'
    )
    over = _write(
        tmp_path / "over.toml", f'[scenario]\nroute = "short"\nseed = {scenario.SEED_MAX + 1}\n'
    )
    assert scenario.load(str(top)).params.seed == scenario.SEED_MAX
    assert make_plan(scenario.load("short"), None, realtime=False, seed=scenario.SEED_MAX).seed == (
        scenario.SEED_MAX
    )
    with pytest.raises(ConfigError, match="above its maximum 2147483647"):
        scenario.load(str(over))
