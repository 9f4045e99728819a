"""Drives and the localizer on other node IDs than the wire contract's ([drives] *_node_id,
[bus] localizer_node_id; the bench's drive.*_node_id, localizer.node_id): the controller
translates at its bus boundary and drives the route as with the contract's IDs."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from dbc.codec import Codec, Heartbeat, Node, PoseFix
from tools.logs.mcap_io import iter_frames
from tools.run import scenario as scenario_mod
from tools.run.experiment import run_experiment

#: drives on 3 and 4 (the contract's localizer ID among them), the localizer moved to 5
IDS = {"left_node_id": 3, "right_node_id": 4}
LOCALIZER = 5


def _scenario(controller_ids: dict[str, int], localizer: int = LOCALIZER) -> scenario_mod.Scenario:
    scen = scenario_mod.load("fault-free")
    bench = dict(scen.bench)
    bench["drive"] = {**bench.get("drive", {}), **IDS}
    bench["localizer"] = {**bench.get("localizer", {}), "node_id": LOCALIZER}
    controller = dict(scen.controller)
    controller["drives"] = {**controller.get("drives", {}), **controller_ids}
    controller["bus"] = {**controller.get("bus", {}), "localizer_node_id": localizer}
    return dataclasses.replace(scen, bench=bench, controller=controller)


def test_drives_on_node_3_and_4_are_driven_through_the_route(tmp_path: Path) -> None:
    s = run_experiment(tmp_path / "mapped", _scenario(IDS), "baseline", duration_s=12.0)
    assert s["tracking_started"] and s["final_state"] == "TRACKING"
    assert s["stop_reason"] == "NONE"
    assert s["rmse_pos_m"] < 0.05
    ids = {
        m.arbitration_id
        for _t, m in iter_frames(tmp_path / "mapped" / "run.mcap")
        if not m.is_extended_id
    }
    codec = Codec.default()
    hb = codec.frame_id(Heartbeat, Node.LEFT) & 0x1F
    assert (3 << 5) | hb in ids and (4 << 5) | hb in ids
    fix = codec.frame_id(PoseFix, Node.LOCALIZER) & 0x1F
    assert (LOCALIZER << 5) | fix in ids  # the localizer's fixes, as node 5
    assert not any(i >> 5 in (1, 2) for i in ids)  # nothing on the contract's drive IDs
    assert s["estimate_step_max_m"] > 0.0  # the fixes corrected the estimate


def test_a_controller_that_expects_the_contract_ids_never_arms(tmp_path: Path) -> None:
    s = run_experiment(tmp_path / "contract", _scenario({}, 3), "baseline", duration_s=6.0)
    assert not s["tracking_started"]


def test_a_controller_that_expects_the_localizer_elsewhere_runs_on_odometry(
    tmp_path: Path,
) -> None:
    s = run_experiment(tmp_path / "no-fix", _scenario(IDS, 6), "baseline", duration_s=8.0)
    assert s["tracking_started"]  # the drives are where it expects them
    assert s["estimate_step_max_m"] == 0.0  # no fix ever reached the estimate
