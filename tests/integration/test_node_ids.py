"""Drives on other node IDs than the wire contract's ([drives] / drive.*_node_id): the
controller translates at its bus boundary and drives the route as with the contract's IDs."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from dbc.codec import Codec, Heartbeat, Node
from tools.logs.mcap_io import iter_frames
from tools.run import scenario as scenario_mod
from tools.run.experiment import run_experiment

IDS = {"left_node_id": 0, "right_node_id": 5}  # a stock ODrive's axis0 often says 0


def _scenario(controller_ids: dict[str, int]) -> scenario_mod.Scenario:
    scen = scenario_mod.load("fault-free")
    bench = dict(scen.bench)
    bench["drive"] = {**bench.get("drive", {}), **IDS}
    controller = dict(scen.controller)
    controller["drives"] = {**controller.get("drives", {}), **controller_ids}
    return dataclasses.replace(scen, bench=bench, controller=controller)


def test_drives_on_node_0_and_5_are_driven_through_the_route(tmp_path: Path) -> None:
    s = run_experiment(tmp_path / "mapped", _scenario(IDS), "baseline", duration_s=12.0)
    assert s["tracking_started"] and s["final_state"] == "TRACKING"
    assert s["stop_reason"] == "NONE"
    assert s["rmse_pos_m"] < 0.05
    ids = {
        m.arbitration_id
        for _t, m in iter_frames(tmp_path / "mapped" / "run.mcap")
        if not m.is_extended_id
    }
    hb = Codec.default().frame_id(Heartbeat, Node.LEFT) & 0x1F
    assert (0 << 5) | hb in ids and (5 << 5) | hb in ids
    assert not any(i >> 5 in (1, 2) for i in ids)  # nothing on the contract's drive IDs


def test_a_controller_that_expects_the_contract_ids_never_arms(tmp_path: Path) -> None:
    s = run_experiment(tmp_path / "contract", _scenario({}), "baseline", duration_s=6.0)
    assert not s["tracking_started"]
