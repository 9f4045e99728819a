"""The closed loop over CAN frames on the virtual bus: bench, controller and recorder together."""

from __future__ import annotations

import base64
import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from dbc.codec import TruthPose
from firmware_sim import sim as sim_mod
from tests.integration.conftest import run_stack, setpoints


@pytest.fixture(scope="module")
def short_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("short")
    return out, run_stack(out, "short", "baseline")


def test_baseline_tracks_the_short_route_and_stops_at_its_end(short_run: tuple[Path, dict]) -> None:
    _out, s = short_run
    assert s["tracking_started"]
    assert s["stop_reason"] == "ROUTE_DONE"
    assert s["final_state"] == "DONE"
    assert s["rmse_pos_m"] < 0.03
    assert s["max_pos_err_m"] < 0.05
    assert math.degrees(s["rmse_phie_rad"]) < 3.0
    assert s["deadline_misses"] == 0


def test_summary_has_the_documented_fields(short_run: tuple[Path, dict]) -> None:
    _out, s = short_run
    for key in (
        "controller",
        "scenario",
        "rmse_xe_m",
        "rmse_ye_m",
        "rmse_phie_rad",
        "rmse_pos_m",
        "max_pos_err_m",
        "max_phie_rad",
        "sim_duration_s",
        "wall_s",
        "frames_total",
        "deadline_misses",
        "control_effort",
        "tv_v",
        "tv_omega",
        "chattering_hz",
        "controller_step_us_p50",
        "controller_step_us_p99",
    ):
        assert key in s, key
    assert s["frames_total"] > 1000
    assert all(math.isfinite(s[k]) for k in ("rmse_pos_m", "control_effort", "tv_v", "tv_omega"))


def test_the_summary_splits_a_lockstep_step_into_physics_ticks_and_the_rest(
    short_run: tuple[Path, dict],
) -> None:
    _out, s = short_run
    b = s["lockstep_budget_us"]
    assert b["physics"] > 0.0 and b["controller_tick"] > 0.0 and b["rest"] > 0.0
    # the three parts are the step's wall time, and the ceiling leaves the rest out
    steps = s["sim_duration_s"] * 100.0  # 10 ms bench steps
    per_step_us = s["wall_s"] * 1e6 / steps
    assert math.isclose(b["physics"] + b["controller_tick"] + b["rest"], per_step_us, rel_tol=1e-6)
    assert b["rtf_ceiling"] > s["real_time_factor"]
    assert math.isclose(
        b["rtf_ceiling"], 10_000.0 / (b["physics"] + b["controller_tick"]), rel_tol=1e-6
    )


def test_drive_encoder_speeds_follow_their_setpoints(short_run: tuple[Path, dict]) -> None:
    _out, s = short_run
    wt = s["wheel_speed_tracking_rms_revps"]
    # wheel speeds of ~0.5 rev/s are followed to better than 0.02 rev/s rms (a 10 ms frame lag)
    assert 0.0 < wt["left"] < 0.02
    assert 0.0 < wt["right"] < 0.02


def test_recorded_frames_decode_the_same_as_their_wire_layout(
    short_run: tuple[Path, dict],
) -> None:
    """The decoded channels agree with the raw bytes: the authenticated setpoint (int16 at
    0.1 mrev/s, stop reference u8 at 0.01 rev/s, freshness u8, MAC u32) and ODrive's plain
    encoder estimates (two float32)."""
    out, _s = short_run
    decoded: dict[tuple[int, int], dict] = {}
    raw: dict[tuple[int, int], bytes] = {}
    with (out / "run.mcap").open("rb") as fh:
        for _sch, ch, msg in make_reader(fh).iter_messages(
            topics=["/can/raw", "/can/Left_Set_Input_Vel_Auth", "/can/Right_Get_Encoder_Estimates"]
        ):
            if ch.topic == "/can/raw":
                rec = json.loads(msg.data)
                raw[(rec["arbitration_id"], msg.sequence)] = base64.b64decode(rec["data"])
            else:
                aid = 0x28 if "Left" in ch.topic else 0x49
                decoded[(aid, msg.sequence)] = json.loads(msg.data)
    checked = 0
    for (aid, seq), values in decoded.items():
        frame = raw[(aid, seq)]
        if aid == 0x28:
            vel, stop_ref, fresh, mac = struct.unpack("<hBBI", frame)
            assert fresh == values["Freshness"] and mac == values["Auth_MAC"]
            assert vel * 1e-4 == pytest.approx(values["Input_Vel"], abs=1e-9)
            assert stop_ref * 0.01 == pytest.approx(values["Stop_Ref_Vel"], abs=1e-9)
        else:
            assert struct.unpack("<ff", frame) == (values["Pos_Estimate"], values["Vel_Estimate"])
        checked += 1
    assert checked > 2000


def test_lockstep_runs_are_deterministic(tmp_path: Path, short_run: tuple[Path, dict]) -> None:
    out, s = short_run
    s2 = run_stack(tmp_path / "again", "short", "baseline")
    assert s2["rmse_pos_m"] == s["rmse_pos_m"]
    a, b = setpoints(out), setpoints(tmp_path / "again")
    assert np.array_equal(a["Left"], b["Left"]) and np.array_equal(a["Right"], b["Right"])


def test_the_controller_never_reads_ground_truth(
    tmp_path: Path, short_run: tuple[Path, dict], monkeypatch: pytest.MonkeyPatch
) -> None:
    # The bench now lies about the truth: the controller's setpoints must not change.
    monkeypatch.setattr(sim_mod.ChairSim, "truth_pose", lambda self: TruthPose(12.5, -7.25, 1.0))
    out, _s = short_run
    s2 = run_stack(tmp_path / "lying", "short", "baseline")
    a, b = setpoints(out), setpoints(tmp_path / "lying")
    assert np.array_equal(a["Left"], b["Left"]) and np.array_equal(a["Right"], b["Right"])
    assert s2["rmse_pos_m"] > 1.0  # the metrics did see the (false) truth


def test_a_reference_that_pauses_is_tracked_and_the_chair_rests_during_the_pause(
    tmp_path: Path,
) -> None:
    s = run_stack(tmp_path, "short-pause", "baseline")
    assert s["stop_reason"] == "ROUTE_DONE"
    assert s["max_pos_err_m"] < 0.05
