"""Tuning: its scenarios are disjoint from the evaluation's, its search space is each
controller's declared gains, its objective and the tuned gains file (no runs)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from controller.tracking import registry
from dbc.runtime.errors import ConfigError
from tools.evaluation import campaign as ev
from tools.evaluation import plan
from tools.run import scenario as scenario_mod
from tools.tuning import gainsfile, tune

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
    paths = tune.tuning_scenarios()
    assert len(paths) >= 2
    for p in paths:
        scenario_mod.load(str(p))


def test_tuning_scenarios_are_disjoint_from_the_evaluations() -> None:
    tuning = [scenario_mod.load(str(p)) for p in tune.tuning_scenarios()]
    evaluation = _evaluation_scenarios()
    # other routes (files and waypoints)
    eval_routes = {s.route_path.resolve() for s in evaluation}
    eval_waypoints = {tuple(map(tuple, s.route.waypoints_m)) for s in evaluation}
    for s in tuning:
        assert s.route_path.resolve() not in eval_routes, s.name
        assert tuple(map(tuple, s.route.waypoints_m)) not in eval_waypoints, s.name
    # other seeds: the scenario seeds and every Monte-Carlo replicate's drawn seed
    eval_seeds = {s.params.seed for s in evaluation}
    eval_seeds |= {ev.draw_variation(1, r).seed for r in range(1, 51)}
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
    # no evaluation fault (nor any other)
    for s in tuning:
        assert s.faults == (), s.name
    # and the evaluation does not use a tuning scenario by name
    assert not {s.name for s in tuning} & set(EVALUATION)


@pytest.mark.parametrize("name", plan.PAPER_CONTROLLERS)
def test_every_paper_controller_has_the_same_number_of_tunable_declared_gains(name: str) -> None:
    dims = tune.space(name)
    assert len(dims) == len(tune.space("robust"))
    p = registry.load_params(name)
    for d in dims:
        assert d.lo < d.x0 < d.hi
        assert d.value(0.0) == pytest.approx(d.x0)
        assert d.value(1.0) == pytest.approx(d.hi) and d.value(-1.0) == pytest.approx(d.lo)
        assert getattr(p, d.key.split(".")[-1]) == d.x0 or "." in d.key


def test_an_unknown_or_undeclared_gain_is_an_error_naming_it(tmp_path: Path) -> None:
    bad = tmp_path / "space.toml"
    bad.write_text('spread = 3.0\n[robust]\nkeys = ["k1_per_s", "gain_of_nothing"]\n')
    with pytest.raises(ConfigError, match="unknown gain 'gain_of_nothing'"):
        tune.space("robust", path=bad)
    bad.write_text("spread = 3.0\n[baseline]\nkeys = []\n")
    with pytest.raises(tune.TuningError, match="declares no tunable gains"):
        tune.space("baseline", path=bad)


def test_gains_table_nests_dotted_keys() -> None:
    dims = [tune.Dim("a", 1.0, 0.5, 2.0), tune.Dim("inner.k", 4.0, 2.0, 8.0)]
    assert tune.gains_table(dims, [1.0, -1.0]) == {"a": 2.0, "inner": {"k": 2.0}}


def test_the_objective_penalises_a_run_that_stops_early_or_fails() -> None:
    ok = {"rmse_pos_m": 0.02, "rmse_phie_rad": 0.1}
    assert tune.objective_of([ok, ok]) == pytest.approx(0.03)
    early = {**ok, "tracking_ended_early_s": 4.0}
    assert tune.objective_of([ok, early]) == pytest.approx((0.03 + 1.0 + 0.02) / 2)
    assert tune.objective_of([{"error": "boom"}]) == pytest.approx(1.0)
    assert math.isfinite(tune.objective_of([{"rmse_pos_m": math.nan}]))


PROV = {
    "date": "2026-12-02T01:00:00+00:00",
    "optimiser": tune.OPTIMISER,
    "objective": tune.OBJECTIVE,
    "objective_value": 0.01,
    "objective_start": 0.02,
    "budget_evaluations": 10,
    "evaluations": 10,
    "runs": 20,
    "wall_s": 12.5,
    "converged": False,
    "message": 'Maximum number of "function" evaluations',
    "scenarios": ["tune-hook", "tune-slalom"],
    "tuned": ["k_x"],
}


def test_the_gains_file_round_trips_and_keeps_other_controllers(tmp_path: Path) -> None:
    path = tmp_path / "gains.toml"
    gainsfile.update(path, "baseline", {"k_x": 2.5}, PROV)
    gainsfile.update(path, "robust", {"k1_per_s": 3.0}, {**PROV, "tuned": ["k1_per_s"]})
    loaded = gainsfile.load(path)
    assert loaded["baseline"]["gains"] == {"k_x": 2.5}
    assert loaded["baseline"]["provenance"] == PROV
    assert loaded["robust"]["gains"] == {"k1_per_s": 3.0}


def test_gains_that_do_not_fit_the_controller_are_an_error_saying_to_re_tune(
    tmp_path: Path,
) -> None:
    path = tmp_path / "gains.toml"
    gainsfile.update(path, "baseline", {"k_renamed": 2.5}, PROV)
    with pytest.raises(ConfigError, match=r"re-run `wheelchair-hil tune --controller baseline`"):
        gainsfile.load(path)
    path.write_text('[baseline]\ndate = "x"\n')
    with pytest.raises(ConfigError, match="lacks its provenance key"):
        gainsfile.load(path)


def test_the_committed_gains_file_fits_todays_controllers() -> None:
    path = scenario_mod.REPO_ROOT / plan.TUNED_GAINS
    entries = gainsfile.load(path)
    assert set(entries) <= set(registry.names())
    for e in entries.values():
        assert e["provenance"]["scenarios"] == [p.stem for p in tune.tuning_scenarios()]
