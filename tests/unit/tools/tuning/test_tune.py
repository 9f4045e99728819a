"""Tuning: its scenarios are disjoint from the evaluation's, its boxes are declared gains'
intervals, its method (Sobol x0 stage, Nelder-Mead, widening) on stubbed objectives, its
objective and the tuned gains file (no runs)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest

from controller import planner
from controller.tracking import registry
from dbc.runtime.errors import ConfigError
from tools.cli import tune as tune_command
from tools.evaluation import plan
from tools.evaluation.variation import draw_variation
from tools.run import scenario as scenario_mod
from tools.tuning import gainsfile, objective, provenance, search, space, tune

#: Every scenario an evaluation campaign can run.
EVALUATION = sorted(
    {
        *plan.PAPER_SCENARIOS,
        plan.CASCADED,
        plan.EXPOSURE_SCENARIO,
        *plan.SPECTRUM_FAULTS,
    }
)


def _evaluation_scenarios() -> list[scenario_mod.Scenario]:
    return [scenario_mod.load(s) for s in EVALUATION]


def test_there_are_tuning_scenarios_and_they_load() -> None:
    paths = objective.tuning_scenarios()
    assert len(paths) >= 2
    for p in paths:
        scenario_mod.load(str(p))


def test_tuning_scenarios_are_disjoint_from_the_evaluations() -> None:
    tuning = [scenario_mod.load(str(p)) for p in objective.tuning_scenarios()]
    evaluation = _evaluation_scenarios()
    # other routes (files and waypoints)
    eval_routes = {s.route_path.resolve() for s in evaluation}
    eval_waypoints = {tuple(map(tuple, s.route.waypoints_m)) for s in evaluation}
    for s in tuning:
        assert s.route_path.resolve() not in eval_routes, s.name
        assert tuple(map(tuple, s.route.waypoints_m)) not in eval_waypoints, s.name
    # other seeds: the scenario seeds and every Monte-Carlo replicate's drawn seed
    eval_seeds = {s.params.seed for s in evaluation}
    eval_seeds |= {draw_variation(1, r).seed for r in range(1, 51)}
    assert not eval_seeds & {s.params.seed for s in tuning}
    # other start offsets: none is the evaluation's nominal start or inside its draws
    for s in tuning:
        along, left, heading = s.params.initial_offset
        assert (along, left, heading) not in {e.params.initial_offset for e in evaluation}
        inside = (
            abs(along) <= plan.MC_OFFSET_M
            and abs(left) <= plan.MC_OFFSET_M
            and abs(heading) <= plan.MC_OFFSET_RAD
        )
        assert not inside, s.name
    # a disturbance in every tuning scenario, none of them a fault an evaluation scenario has
    # (the same kind with the same parameters), and all on the tuning routes only
    eval_faults = {(f.kind, f.params) for e in evaluation for f in e.faults}
    assert {k for k, _ in eval_faults} >= {"flat-tire", "shaft-bump", "slip"}
    for s in tuning:
        assert s.faults, s.name
        assert not {(f.kind, f.params) for f in s.faults} & eval_faults, s.name
    # and the evaluation does not use a tuning scenario by name
    assert not {s.name for s in tuning} & set(EVALUATION)


@pytest.mark.parametrize("name", plan.PAPER_CONTROLLERS)
def test_every_paper_controller_has_five_declared_gains_with_boxes_inside_their_bounds(
    name: str,
) -> None:
    dims = space.space(name)
    assert len(dims) == 5
    assert len(space.space(plan.REFERENCE_CONTROLLER)) == 3
    for d in space.space(name) + space.space(plan.REFERENCE_CONTROLLER):
        assert 0.0 < d.lo < d.hi
        assert d.limit_lo <= d.lo and d.hi <= d.limit_hi


def test_only_the_controllers_the_space_file_gives_boxes_to_are_tunable() -> None:
    assert set(space.tunable()) == {*plan.PAPER_CONTROLLERS, plan.REFERENCE_CONTROLLER}
    assert "method" not in space.tunable()


@pytest.mark.parametrize("name", sorted(set(registry.names()) - set(space.tunable())))
def test_a_controller_without_boxes_is_refused_with_the_tunable_list(name: str) -> None:
    with pytest.raises(space.TuningError, match=rf"{name!r} is not tuned: .*tunable: baseline"):
        space.space(name)


def test_the_cli_refuses_an_untuned_controller_before_any_run(tmp_path: Path) -> None:
    args = argparse.Namespace(
        controller="baseline,adaptive-integral",
        out=None,
        gains_file=str(tmp_path / "gains.toml"),
        budget=100,
        workers=1,
        dry_run=True,
        no_progress=True,
    )
    with pytest.raises(space.TuningError, match="'adaptive-integral' is not tuned"):
        tune_command.main(args, [])
    assert not (tmp_path / "gains.toml").exists()


def _space(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "space.toml"
    path.write_text(body)
    return path


def test_an_unknown_gain_or_a_bad_box_is_an_error_naming_it(tmp_path: Path) -> None:
    bad = _space(tmp_path, "[robust]\nk1_per_s = [0.3, 5.0]\ngain_of_nothing = [1.0, 2.0]\n")
    with pytest.raises(ConfigError, match="unknown gain 'gain_of_nothing'"):
        space.space("robust", path=bad)
    bad = _space(tmp_path, "[robust]\nk1_per_s = [0.3, 80.0]\n")
    with pytest.raises(ConfigError, match=r"robust.k1_per_s = \[0.3, 80.0\] leaves .*declared"):
        space.space("robust", path=bad)
    bad = _space(tmp_path, "[robust]\nk1_per_s = [2.0, 1.0]\n")
    with pytest.raises(ConfigError, match="need 0 < lo < hi"):
        space.space("robust", path=bad)
    bad = _space(tmp_path, '[robust]\nk1_per_s = ["a", 1.0]\n')
    with pytest.raises(ConfigError, match="must be an interval"):
        space.space("robust", path=bad)
    bad = _space(tmp_path, "[robust]\nk1_per_s = [0.3, 5.0]\n[robust.limits]\nk2_per_s = [1, 2]\n")
    with pytest.raises(ConfigError, match="k2_per_s' has no box"):
        space.space("robust", path=bad)
    bad = _space(tmp_path, "[robust]\nk1_per_s = [0.3, 5.0]\n[robust.limits]\nk1_per_s = [0, 90]\n")
    with pytest.raises(ConfigError, match="leaves the declared bounds"):
        space.space("robust", path=bad)
    bad = _space(tmp_path, "[robust]\nk1_per_s = [0.3, 5.0]\n[robust.limits]\nk1_per_s = [1, 5]\n")
    with pytest.raises(ConfigError, match="the widest k1_per_s may be"):
        space.space("robust", path=bad)


def test_a_limit_narrower_than_the_declared_bound_caps_the_box() -> None:
    (l0,) = [d for d in space.space("antifragile") if d.key == "lambda0_mps"]
    assert l0.limit_hi == 0.22 < 5.0  # antifragile.Params refuses more (space.toml)


def test_the_method_is_validated(tmp_path: Path) -> None:
    assert space.method().sobol_points & (space.method().sobol_points - 1) == 0
    bad = _space(tmp_path, "[method]\nsobol_points = 12\n")
    with pytest.raises(ConfigError, match="must be a power of 2"):
        space.method(path=bad)
    bad = _space(tmp_path, "[method]\nxatol = 0.1\n")
    with pytest.raises(ConfigError, match=r"unknown key 'method\.xatol'"):
        space.method(path=bad)


def test_gains_table_nests_dotted_keys_and_keeps_six_significant_digits() -> None:
    dims = [space.Dim("a", 0.5, 2.0, 0.0, 10.0), space.Dim("inner.k", 1e-7, 1e-5, 0.0, 1.0)]
    assert space.gains_table(dims, [2.0, 3.4567891e-6]) == {"a": 2.0, "inner": {"k": 3.45679e-6}}


def test_the_objective_penalises_a_run_that_stops_early_or_fails() -> None:
    ok = {"rmse_pos_m": 0.02, "rmse_phie_rad": 0.1}
    assert objective.objective_of([ok, ok]) == pytest.approx(0.03)
    early = {**ok, "tracking_ended_early_s": 4.0}
    assert objective.objective_of([ok, early]) == pytest.approx((0.03 + 1.0 + 0.02) / 2)
    assert objective.objective_of([{"error": "boom"}]) == pytest.approx(1.0)
    assert math.isfinite(objective.objective_of([{"rmse_pos_m": math.nan}]))


def test_a_safe_stop_is_charged_as_a_failure_even_in_the_routes_last_half_second() -> None:
    """OFF_PATH (or any safe stop) ends tracking early, which is charged; a stop close
    enough to the end that tracking_ended_early_s stays within 0.5 s, or after the route's
    end, is charged by its stop reason."""
    ok = {"rmse_pos_m": 0.02, "rmse_phie_rad": 0.1, "stop_reason": "ROUTE_DONE"}
    assert objective.objective_of([ok]) == pytest.approx(0.03)
    # still tracking when the scenario (route and tail) ended: the route's end not reached
    assert objective.objective_of([{**ok, "stop_reason": "NONE"}]) == pytest.approx(
        objective.FAILURE_PENALTY_M + 0.02
    )
    off = {**ok, "stop_reason": "OFF_PATH", "tracking_ended_early_s": 12.0}
    assert objective.objective_of([off]) == pytest.approx(objective.FAILURE_PENALTY_M + 0.02)
    for late in ({"tracking_ended_early_s": 0.3}, {}):
        for reason in ("OFF_PATH", "DISOBEYED", "NON_FINITE"):
            run = {**ok, "stop_reason": reason, **late}
            assert objective.objective_of([run]) == pytest.approx(
                objective.FAILURE_PENALTY_M + 0.02
            )
    assert "safe stop" in objective.OBJECTIVE


def test_the_objective_charges_each_percent_of_ticks_above_one_at_a_limit_of_the_envelope() -> None:
    ok = {"rmse_pos_m": 0.02, "rmse_phie_rad": 0.1}
    free = {"accel": 0.01, "turn_accel": 0.005, "speed": 0.0, "turn_rate": 0.01, "jerk": 0.0}
    assert objective.objective_of([{**ok, "rate_limit_share": free}]) == pytest.approx(0.03)
    riding = {**free, "accel": 0.04, "turn_rate": 0.02}  # 3 % and 1 % above the free 1 %
    charge = objective.RATE_LIMIT_WEIGHT_M * (3 + 1)
    assert objective.rate_limit_charge(riding) == pytest.approx(charge)
    assert objective.objective_of([{**ok, "rate_limit_share": riding}]) == pytest.approx(
        0.03 + charge
    )
    # jerk is reported, not charged; a share that was not measured costs nothing
    jerky = {**free, "jerk": 0.5, "speed": None, "turn_accel": math.nan}
    assert objective.objective_of([{**ok, "rate_limit_share": jerky}]) == pytest.approx(0.03)
    assert objective.RATE_LIMIT_WEIGHT_M == 0.1 and objective.RATE_LIMIT_FREE_SHARE == 0.01
    assert "0.1 m per percent of the tracking ticks above 1 %" in objective.OBJECTIVE


def test_a_tuning_run_carries_its_summarys_shares_of_ticks_at_the_limits(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    shares = {"accel": 0.2, "turn_accel": 0.0, "speed": 0.0, "turn_rate": 0.0, "jerk": 0.0}

    def fake_experiment(out: Any, scen: Any, controller: str, **kw: Any) -> dict[str, Any]:
        assert kw["log"] is False
        return {
            "rmse_pos_m": 0.02,
            "rmse_phie_rad": 0.1,
            "stop_reason": "ROUTE_DONE",
            "rate_limit_share": shares,
        }

    monkeypatch.setattr(objective, "run_experiment", fake_experiment)
    monkeypatch.setattr(objective, "_ride_comfort", lambda collector: 0.0)
    scen = objective.tuning_scenarios()[0]
    run = objective.run_one("baseline", str(scen), "{}", str(tmp_path / "run"), keep=False)
    assert run["rate_limit_share"] == shares
    assert objective.objective_of([run]) == pytest.approx(0.03 + 0.1 * 19)


def test_the_objective_charges_a_rough_ride_above_the_comfort_bound_only() -> None:
    ok = {"rmse_pos_m": 0.02, "rmse_phie_rad": 0.1}
    smooth = {**ok, "comfort_av_mps2": objective.COMFORT_BOUND_MPS2 - 0.1}
    rough = {**ok, "comfort_av_mps2": objective.COMFORT_BOUND_MPS2 + 0.5}
    assert objective.objective_of([smooth]) == pytest.approx(0.03)
    assert objective.objective_of([rough]) == pytest.approx(
        0.03 + 0.5 * objective.COMFORT_WEIGHT_M_PER_MPS2
    )
    assert objective.objective_of([rough]) > objective.objective_of([smooth])


def test_every_tuning_scenario_is_also_run_at_the_monte_carlo_envelopes_far_corner() -> None:
    assert objective.CONDITIONS == ("nominal", "stressed")
    assert objective.STRESS.noise_factor == max(plan.MC_NOISE_RANGE)
    assert objective.STRESS.mass_factor == 1.0 + plan.MC_MASS_SPREAD
    calls: list[tuple[Any, ...]] = []

    def fake(*args: Any) -> dict[str, Any]:
        calls.append(args)
        return {"rmse_pos_m": 0.01 if args[-1] == "nominal" else 0.03, "rmse_phie_rad": 0.0}

    obj = objective.StackObjective(
        "baseline", [Path("a.toml"), Path("b.toml")], Path("/w"), keep=False, pool=None
    )
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(objective, "run_one", fake)
        assert obj([{"k_x": 1.0}]) == [pytest.approx(0.02)]
    assert sorted((Path(c[1]).stem, c[-1]) for c in calls) == [
        ("a", "nominal"),
        ("a", "stressed"),
        ("b", "nominal"),
        ("b", "stressed"),
    ]


def test_the_full_length_route_runs_at_the_far_corner_only() -> None:
    stems = [p.stem for p in objective.tuning_scenarios()]
    assert set(objective.STRESS_ONLY) <= set(stems)
    long = scenario_mod.load(str(space.TUNING_DIR / "tune-long.toml"))
    paper = scenario_mod.load("fault-free")
    # as long as the paper's route, within 15 %
    long_s = planner.plan(long.route).duration_s
    assert long_s >= 0.85 * planner.plan(paper.route).duration_s
    assert objective.conditions_of("tune-long") == ("stressed",)
    assert objective.conditions_of(Path("x/tune-sweep.toml")) == objective.CONDITIONS
    calls: list[tuple[Any, ...]] = []

    def fake(*args: Any) -> dict[str, Any]:
        calls.append(args)
        return {"rmse_pos_m": 0.01, "rmse_phie_rad": 0.0}

    obj = objective.StackObjective(
        "baseline", [Path("a.toml"), Path("tune-long.toml")], Path("/w"), keep=False, pool=None
    )
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(objective, "run_one", fake)
        assert obj([{"k_x": 1.0}, {"k_x": 2.0}]) == [pytest.approx(0.01)] * 2
    assert sorted({(Path(c[1]).stem, c[-1]) for c in calls}) == [
        ("a", "nominal"),
        ("a", "stressed"),
        ("tune-long", "stressed"),
    ]
    assert len(calls) == 6


# -- the method on stubbed objectives -------------------------------------------------------

METHOD = space.Method(sobol_points=16)


class Bowl:
    """A quadratic bowl in ln(gain) with its minimum at ``centre`` (the gains' values), 1 cm
    deep; records the size of every batch it is asked to evaluate."""

    def __init__(self, centre: Mapping[str, float]) -> None:
        self.centre = dict(centre)
        self.batches: list[int] = []

    def value(self, gains: Mapping[str, Any]) -> float:
        return 0.01 + sum(
            (math.log(gains[k]) - math.log(c)) ** 2 * 0.01 for k, c in self.centre.items()
        )

    def __call__(self, batch: Sequence[Mapping[str, Any]]) -> list[float]:
        self.batches.append(len(batch))
        return [self.value(g) for g in batch]


def _dims(limit_hi: float = 100.0) -> list[space.Dim]:
    return [space.Dim("a", 0.5, 2.0, 0.0, limit_hi), space.Dim("b", 1.0, 10.0, 0.0, 100.0)]


def test_an_optimum_beyond_a_box_edge_widens_that_side_until_it_lies_inside() -> None:
    bowl = Bowl({"a": 12.0, "b": 3.0})  # a's minimum is 6x beyond its box's hi edge
    found = search.search(_dims(), METHOD, 400, bowl)
    assert found.converged
    assert found.on_edge == {}
    box = {d.key: d for d in found.dims}
    assert box["a"].hi == pytest.approx(2.0 * 3.0**2)  # two widenings by 3: 18 > 12
    assert box["a"].lo == 0.5 and (box["b"].lo, box["b"].hi) == (1.0, 10.0)
    assert [(w["key"], w["side"]) for w in found.widenings] == [("a", "hi"), ("a", "hi")]
    assert found.rounds == 2
    best = found.history[found.best_index]["gains"]
    assert best["a"] == pytest.approx(12.0, rel=0.1) and best["b"] == pytest.approx(3.0, rel=0.1)
    assert [d.hi for d in found.dims_start] == [2.0, 10.0]


def test_a_limit_that_stops_the_widening_leaves_the_key_reported_on_its_edge() -> None:
    bowl = Bowl({"a": 12.0, "b": 3.0})
    found = search.search(_dims(limit_hi=5.0), METHOD, 400, bowl)
    assert found.converged  # Nelder-Mead's own test ended it, at the limit
    assert found.on_edge == {"a": {"side": "hi", "at_limit": True}}
    assert found.dims[0].hi == 5.0
    assert found.history[found.best_index]["gains"]["a"] == pytest.approx(5.0, rel=0.02)


def test_the_sobol_stage_is_one_deterministic_batch_and_its_best_point_is_x0() -> None:
    runs = []
    for seed in (7, 7, 8):
        bowl = Bowl({"a": 1.2, "b": 4.0})
        m = space.Method(sobol_points=16, sobol_seed=seed)
        runs.append((search.search(_dims(), m, 200, bowl), bowl))
    (first, bowl), (again, _), (other, _) = runs
    stage = [h for h in first.history if h["stage"] == "x0 stage"]
    assert len(stage) == 16 and bowl.batches[0] == 16  # one batch: parallel over the pool
    assert all(b == 1 for b in bowl.batches[1:])  # Nelder-Mead: one point at a time
    assert [h["gains"] for h in stage] == [h["gains"] for h in again.history[:16]]
    assert [h["gains"] for h in stage] != [h["gains"] for h in other.history[:16]]
    x0 = min(stage, key=lambda h: h["objective"])
    assert first.history[first.x0_index] is x0
    # Nelder-Mead starts at x0: its first point is x0 itself (already evaluated, not re-run)
    assert first.history[16]["stage"] == "Nelder-Mead"
    assert first.history[first.best_index]["objective"] <= x0["objective"]
    for h in stage:  # the design covers the box in log scale
        assert 0.5 <= h["gains"]["a"] <= 2.0 and 1.0 <= h["gains"]["b"] <= 10.0


def test_converged_is_true_only_when_nelder_meads_own_test_ends_the_search() -> None:
    bowl = Bowl({"a": 1.2, "b": 4.0})
    spent = search.search(_dims(), METHOD, 16 + 8, bowl)
    assert not spent.converged
    assert len(spent.history) <= 24 and "budget of 24" in spent.message
    done = search.search(_dims(), METHOD, 400, Bowl({"a": 1.2, "b": 4.0}))
    assert done.converged and len(done.history) < 400
    assert "terminated successfully" in done.message


def test_a_budget_that_cannot_pay_for_the_sobol_stage_and_a_simplex_is_refused() -> None:
    with pytest.raises(space.TuningError, match="at least 19 objective evaluations"):
        search.search(_dims(), METHOD, 18, Bowl({"a": 1.0, "b": 1.0}))


PROV = {
    "date": "2026-12-02T01:00:00+00:00",
    "optimiser": provenance.optimiser_text(space.Method()),
    "objective": objective.OBJECTIVE,
    "objective_value": 0.01,
    "objective_start": 0.02,
    "budget_evaluations": 100,
    "evaluations": 90,
    "runs": 180,
    "wall_s": 12.5,
    "converged": False,
    "message": 'Maximum number of "function" evaluations',
    "scenarios": ["tune-hook", "tune-slalom"],
    "tuned": ["k_x"],
    "x0_stage": {
        "design": "sobol",
        "points": 32,
        "seed": 2027,
        "objective_best": 0.02,
        "objective_median": 0.05,
        "x0": {"k_x": 2.0},
    },
    "nelder_mead": {"xatol_ln": 0.1, "fatol_m": 1e-4, "simplex_step": 0.25},
    "widening": {"edge_fraction": 0.02, "factor": 3.0, "rounds": 1},
    "box_start": {"k_x": [0.3, 20.0]},
    "box": {"k_x": [0.3, 50.0]},
    "box_limit": {"k_x": [0.0, 50.0]},
    "on_edge": {"k_x": {"side": "hi", "at_limit": True}},
}


def test_the_gains_file_round_trips_and_keeps_other_controllers(tmp_path: Path) -> None:
    path = tmp_path / "gains.toml"
    gainsfile.update(path, "baseline", {"k_x": 2.5}, PROV)
    robust = {**PROV, "tuned": ["k1_per_s"], "on_edge": {}, "box_limit": {"k1_per_s": [0, 50]}}
    robust |= {"box": {"k1_per_s": [0.3, 20.0]}, "box_start": {"k1_per_s": [0.3, 20.0]}}
    gainsfile.update(path, "robust", {"k1_per_s": 3.0}, robust)
    loaded = gainsfile.load(path)
    assert loaded["baseline"]["gains"] == {"k_x": 2.5}
    assert loaded["baseline"]["provenance"] == PROV
    assert loaded["robust"]["gains"] == {"k1_per_s": 3.0}
    assert loaded["robust"]["provenance"]["on_edge"] == {}


def test_a_tuning_writes_its_method_boxes_and_edges_into_the_gains_file(tmp_path: Path) -> None:
    space_file = _space(
        tmp_path,
        "[method]\nsobol_points = 16\n"
        "[baseline]\nk_x = [0.3, 20.0]\nk_y = [0.1, 400.0]\nk_phi = [0.3, 20.0]\n"
        "[baseline.limits]\nk_x = [0.0, 30.0]\n",
    )
    bowl = Bowl({"k_x": 40.0, "k_y": 20.0, "k_phi": 5.0})  # k_x wants more than its limit
    path = tmp_path / "gains.toml"
    res = tune.tune(
        "BASELINE",
        budget=300,
        out=tmp_path / "run",
        gains_file=path,
        objective=bowl,
        space_file=space_file,
    )
    p = gainsfile.load(path)["baseline"]["provenance"]
    assert p == res["provenance"]
    assert p["converged"] is True and p["budget_evaluations"] == 300
    assert p["x0_stage"]["points"] == 16 and p["x0_stage"]["seed"] == 2027
    assert p["objective_start"] == p["x0_stage"]["objective_best"] >= p["objective_value"]
    assert p["box_start"]["k_x"] == [0.3, 20.0] and p["box"]["k_x"] == [0.3, 30.0]
    assert p["box_limit"]["k_x"] == [0.0, 30.0]
    assert p["on_edge"] == {"k_x": {"side": "hi", "at_limit": True}}
    runs_per_point = 2 * len(objective.tuning_scenarios()) - len(objective.STRESS_ONLY)
    assert p["runs"] == p["evaluations"] * runs_per_point
    assert gainsfile.load(path)["baseline"]["gains"] == res["gains"]
    line = tune_command.summary_line("baseline", p)
    assert "converged: yes" in line and "on an edge: k_x (hi, at its limit)" in line
    assert (tmp_path / "run" / "tuning.json").is_file()


def test_gains_that_do_not_fit_the_controller_are_an_error_saying_to_re_tune(
    tmp_path: Path,
) -> None:
    path = tmp_path / "gains.toml"
    gainsfile.update(path, "baseline", {"k_renamed": 2.5}, PROV)
    with pytest.raises(ConfigError, match=r"re-run `wheelchair-hil tune --controller baseline`"):
        gainsfile.load(path)
    gainsfile.update(path, "baseline", {"k_x": 2.5}, {**PROV, "box": {"k_y": [1.0, 2.0]}})
    with pytest.raises(ConfigError, match="the boxes do not name the tuned keys"):
        gainsfile.load(path)
    path.write_text('[baseline]\ndate = "x"\n')
    with pytest.raises(ConfigError, match="lacks its provenance key"):
        gainsfile.load(path)


def test_the_committed_gains_file_fits_todays_controllers() -> None:
    path = scenario_mod.REPO_ROOT / plan.TUNED_GAINS
    entries = gainsfile.load(path)
    assert set(entries) <= set(space.tunable())
    for name, e in entries.items():
        assert e["provenance"]["scenarios"] == [p.stem for p in objective.tuning_scenarios()]
        assert e["provenance"]["tuned"] == [d.key for d in space.space(name)]


def test_a_dotted_gain_stays_one_key_in_the_box_tables(tmp_path: Path) -> None:
    path = tmp_path / "gains.toml"
    dotted = {"inner_loop.k1": [0.1, 1.0]}
    prov = {**PROV, "tuned": ["inner_loop.k1"], "box_start": dotted, "box": dotted}
    prov |= {"box_limit": dotted, "on_edge": {"inner_loop.k1": {"side": "lo", "at_limit": False}}}
    gainsfile.update(path, "antifragile", {"inner_loop": {"k1": 0.2}}, prov)
    loaded = gainsfile.load(path)["antifragile"]
    assert loaded["provenance"]["box"] == dotted
    assert loaded["provenance"]["on_edge"] == prov["on_edge"]
    assert loaded["gains"] == {"inner_loop": {"k1": 0.2}}
