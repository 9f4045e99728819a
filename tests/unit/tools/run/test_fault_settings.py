"""The three fault settings of a scenario: where a fault acts (the bench's wheel or the
controller's estimate) and whether the diagnosis feeds back into odometry."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import pytest

from controller.config import GeometryParams, load_config
from controller.estimation import Estimation
from controller.types import Pose
from dbc.codec import AxisState, Node, SetAxisState, SetInputVel
from dbc.runtime.errors import ConfigError
from firmware_sim.config import load_bench_config
from firmware_sim.faults import FaultManager
from firmware_sim.faultspec import parse_schedule
from firmware_sim.sim import ChairSim
from tools.run import scenario as scenario_mod

R0 = 0.30
SECONDS = 8.0


def flat_left(setting: str) -> scenario_mod.Scenario:
    """flat-left with its onset moved to 1 s, in ``setting``."""
    scen = scenario_mod.load("flat-left")
    raw = [{"type": "flat-tire", "side": "left", "onset_s": 1.0, "to_radius_m": 0.26}]
    scen = dataclasses.replace(scen, faults=parse_schedule(raw, source="test"))
    return scenario_mod.with_setting(scen, setting)


def bench_left_radius(scen: scenario_mod.Scenario) -> float:
    """The bench's left wheel radius after SECONDS with the scenario's bench faults."""
    cfg = load_bench_config(
        {"drive.require_auth": False, "drive.check_contract": False}, source="test"
    )
    sim = ChairSim(cfg, seed=1)
    mgr = FaultManager(sim, scen.bench_faults, seed=1)
    out: list[object] = []
    for node in (Node.LEFT, Node.RIGHT):
        sim.handle(node, SetAxisState(AxisState.CLOSED_LOOP_CONTROL), out)
        sim.handle(node, SetInputVel(0.3), out)
    for _ in range(round(SECONDS * 100)):
        mgr.on_step(sim.now_ns)
        mgr.take_events()
        sim.advance()
    return float(sim.plant.left.radius_m)


def estimated_heading(scen: scenario_mod.Scenario) -> float:
    """The controller's heading estimate after SECONDS of both wheels turning alike (true
    motion: straight ahead), configured from the scenario."""
    cfg = load_config(overrides=scen.controller_overrides())
    est = Estimation(GeometryParams(), Pose(0.0, 0.0, 0.0), settings=cfg.estimation)
    drives = {n: SimpleNamespace(pos_rev=0.0, encoder_msgs=0) for n in (Node.LEFT, Node.RIGHT)}
    link = SimpleNamespace(drives=drives)
    for k in range(1, round(SECONDS * 100) + 1):
        for d in drives.values():
            d.pos_rev = 0.3 * k * 0.01
            d.encoder_msgs += 1
        est.update(link, round(k * 0.01 * 1e9))  # type: ignore[arg-type]
    return est.estimate().heading_rad


def test_in_the_paper_setting_a_flat_tire_changes_the_estimate_not_the_wheel() -> None:
    scen = flat_left("paper")
    assert bench_left_radius(scen) == R0
    # the left wheel perceived smaller: the estimate turns left while the chair goes straight
    assert estimated_heading(scen) > math.radians(5.0)
    est = load_config(overrides=scen.controller_overrides()).estimation
    assert not est.diagnosis_feedback and est.perceived_flats[0].to_radius_m == 0.26


@pytest.mark.parametrize("setting", ["physical", "diagnosed"])
def test_in_the_physical_settings_the_wheel_changes_and_the_estimate_believes_nominal(
    setting: str,
) -> None:
    scen = flat_left(setting)
    assert bench_left_radius(scen) < 0.265
    assert estimated_heading(scen) == pytest.approx(0.0, abs=1e-9)
    est = load_config(overrides=scen.controller_overrides()).estimation
    assert est.perceived_flats == ()
    assert est.diagnosis_feedback is (setting == "diagnosed")


def test_bumps_stay_on_the_bench_in_every_setting() -> None:
    scen = scenario_mod.load("bump-left")
    for setting in scenario_mod.FAULT_SETTINGS:
        s = scenario_mod.with_setting(scen, setting)
        assert [f.kind for f in s.bench_faults] == ["shaft-bump"]
        assert s.sensor_faults == ()
    assert scenario_mod.effective_setting(scen, "paper") == "physical"
    assert scenario_mod.effective_setting(scenario_mod.load("flat-right"), "paper") == "paper"


def test_a_scenario_file_sets_its_fault_setting_and_overrides(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "s.toml"
    path.write_text(
        '[scenario]\nroute = "short"\nfault_setting = "paper"\n'
        "[controller.limits]\nv_max_mps = 1.2\n"
        "[gains.baseline]\nk_x = 3.0\n"
        '[[faults]]\ntype = "flat-tire"\nside = "right"\nonset_s = 2.0\nto_radius_m = 0.27\n'
    )
    scen = scenario_mod.load(str(path))
    assert scen.bench_faults == () and [f.side for f in scen.sensor_faults] == ["right"]
    cfg = load_config(overrides=scen.controller_overrides())
    assert cfg.limits.v_max_mps == 1.2
    assert cfg.estimation.perceived_flats[0].side == "right"
    assert scen.gains_for("baseline") == {"k_x": 3.0}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('fault_setting = "real"', "fault_setting = 'real' is not one of"),
        ("[controller.limits]\nv_max_mps = 9.0", "limits.v_max_mps = 9.0 is above its maximum"),
        ("[gains.baseline]\nk_q = 1.0", "unknown key 'baseline.k_q'"),
        ("[gains.nope]\nk = 1.0", r"\[gains.nope\]: unknown controller"),
    ],
)
def test_a_bad_setting_or_override_is_an_error_naming_the_key(
    tmp_path,  # type: ignore[no-untyped-def]
    text: str,
    message: str,
) -> None:
    path = tmp_path / "s.toml"
    head = '[scenario]\nroute = "short"\n'
    body = head + text if text.startswith("fault") else head + "\n" + text
    path.write_text(body + "\n")
    with pytest.raises(ConfigError, match=message):
        scenario_mod.load(str(path))
