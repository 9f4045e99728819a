"""The benchmark's plumbing (no timing assertions: figures are printed, not tested)."""

from __future__ import annotations

import math
from typing import Any

from tools.perf import bench as benchmark
from tools.perf import common, costs, laws, live


def test_percentiles_interpolate_like_numpy() -> None:
    values = sorted([5.0, 1.0, 3.0, 2.0, 4.0])
    assert common.pct(values, 50) == 3.0
    assert common.pct(values, 100) == 5.0
    assert common.pct(values, 25) == 2.0
    assert math.isnan(common.pct([], 50))


def test_offline_loop_times_every_step_and_finds_no_leak() -> None:
    r = laws.offline_loop("baseline", steps=300)
    assert r["steps"] == 300
    assert 0.0 < r["p50"] <= r["p99"]
    assert r["net_blocks_per_step"] == 0.0  # a controller that leaked would show here


def test_the_table_reports_every_figure_with_its_target() -> None:
    r = {
        "controller_step_us": {
            "baseline": {"p50": 2.0, "p99": 3.0},
            "adaptive": {"p50": 180.0, "p99": 240.0},
        },
        "adaptive_vs_cvxpy": {
            "states": 50,
            "cvxpy_solve_us_p50": 4700.0,
            "adaptive_step_us_p50": 230.0,
            "adaptive_vs_cvxpy_ratio": 20.4,
            "adaptive_vs_osqp_floor": 2.1,
        },
        "lockstep_rtf": {"baseline": 8.0},
        "rt_lateness_us": {"p50": 90.0, "p99": 160.0, "p999": 300.0, "max": 900.0},
        "rt_missed_cycles": 0,
        "rt_seconds": 60.0,
        "rt_notes": ["SCHED_FIFO not permitted"],
        "e2e_latency_us": {"p50": 500.0, "p99": 900.0},
        "bus_load_pct": 13.0,
        "bus_load_pct_with_bench": 26.8,
        "controller_rss_mb": 120.0,
        "allocations_per_tick": {"baseline": 0.0},
        "codec_us": {"Get_Encoder_Estimates": {"encode": 1.9, "decode": 1.8}},
        "telemetry_log_us": {"in_loop": 24.0, "forked": 4.4},
        "lockstep_budget_us": {
            "baseline": {
                "physics": 96.0,
                "controller_tick": 180.0,
                "rest": 150.0,
                "rtf_ceiling": 36.2,
            }
        },
    }
    table = benchmark.format_table(r)
    assert (
        "| lock-step step, baseline: physics / controller tick / rest | 96 / 180 / 150 us "
        "(physics and ticks alone: 36.2x) |" in table
    )
    assert "| codec, Get_Encoder_Estimates: encode / decode one frame | 1.90 / 1.80 us |" in table
    assert "in the loop / to a forked writer | 24.0 / 4.4 us |" in table
    assert "| step() adaptive, p50 / p99 | 180.0 / 240.0 us | <= 300 us median |" in table
    assert "20.4x | >= 15x |" in table
    assert "90 / 160 / 300 / 900 us | p99 <= 500 us |" in table
    assert "13.0 % / 26.8 % | <= 25 % |" in table


def test_loop_costs_times_the_codec_and_both_ways_of_logging_a_tick() -> None:
    r = costs.loop_costs(200)
    assert set(r["codec_us"]) == {"Get_Encoder_Estimates", "Set_Input_Vel_Auth", "Bench_Truth_Pose"}
    for c in r["codec_us"].values():
        assert c["encode"] > 0.0 and c["decode"] > 0.0
    assert r["telemetry_log_us"]["in_loop"] > 0.0 and r["telemetry_log_us"]["forked"] > 0.0


def test_lockstep_budget_splits_the_wall_time_of_a_step() -> None:
    from tools.logs.runlog import lockstep_budget

    bench = {"steps": 1000, "wall_s": 0.5, "physics_s": 0.1, "sim_time_s": 10.0}
    b = lockstep_budget(bench, {"tick_s_total": 0.15})
    assert b["physics"] == 100.0 and b["controller_tick"] == 150.0
    assert math.isclose(b["rest"], 250.0)
    assert math.isclose(b["rtf_ceiling"], 10_000.0 / 250.0)
    # statistics without a figure (an older log) give NaN, never a wrong number
    old = lockstep_budget({"steps": 1000, "wall_s": 0.5, "sim_time_s": 10.0}, {})
    assert all(math.isnan(v) for v in old.values())
    assert all(math.isnan(v) for v in lockstep_budget({}, {}).values())


def test_the_live_table_has_a_row_per_case_with_its_tick_and_what_the_client_got() -> None:
    cases: dict[str, Any] = {
        name: {
            "tick_us_p50": 100.0 + i,
            "tick_us_p99": 200.0 + i,
            "lateness_us_p99": 50.0,
            "missed_ticks": 0,
            "view_messages": 1000 if view else None,
            "feed_dropped": 0 if view else None,
            "client_messages": 900 if client else None,
            "client_channels": 52 if client else None,
        }
        for i, (name, view, client, _) in enumerate(live.LIVE_CASES)
    }
    cases["broken"] = {"error": "run failed"}
    table = live.format_live({"live_tick_us": cases, "live_seconds": 20.0})
    rows = table.splitlines()
    assert len(rows) == 2 + len(live.LIVE_CASES) + 1
    assert "| no view | 100.0 / 200.0 us | 50.0 us | 0 | - | - |" in rows
    assert (
        "| view, client on every channel | 102.0 / 202.0 us | 50.0 us | 0 | 1000 / 0 | 900 (52) |"
        in rows
    )
    assert rows[-1].startswith("| broken | run failed")


def test_steps_only_times_the_chosen_controllers_and_prints_only_their_rows() -> None:
    names = benchmark.chosen_controllers("baseline,robust")
    r = benchmark.run(names, argv=["--steps-only"], quick=True, steps_only=True)
    assert set(r["controller_step_us"]) == {"baseline", "robust"}
    table = benchmark.format_table(r)
    assert "| step() robust, p50 / p99 |" in table and "lock-step" not in table
