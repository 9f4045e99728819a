"""Evaluation campaign: rank, convexity and classification, Monte-Carlo draws, scenario
variations, campaign planning, and the report's comparison with the paper (no runs)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from controller.limits import RATE_LIMITS
from tools.evaluation import paper, plan, report, results, verdicts
from tools.evaluation.assemble import build_results, deterministic_part
from tools.evaluation.campaign import Campaign, Options, plan_campaign
from tools.evaluation.execute import execute
from tools.evaluation.plan import EvaluationError
from tools.evaluation.task import Task, _task_record, comfort, load_cached, window_errors
from tools.evaluation.variation import Variation, apply_variation, draw_variation, stress_of
from tools.run import scenario as scenario_mod

PAPER_SCENARIOS = list(plan.PAPER_SCENARIOS)


def paper_table_as_results() -> dict[str, dict[str, dict[str, float]]]:
    """The paper's own numbers in results.json's layout: table[controller][scenario][metric]."""
    table: dict[str, dict[str, dict[str, float]]] = {}
    for metric, rows in paper.PAPER_TABLE.items():
        for c, cells in rows.items():
            for s, v in cells.items():
                table.setdefault(c, {}).setdefault(s, {})[metric] = v
    return table


# ----------------------------------------------------------------------- rank


def test_rank_reproduces_the_papers_rank_column_from_its_own_table() -> None:
    table = paper_table_as_results()
    for metric, expected in paper.PAPER_RANK.items():
        got = results.rank(table, list(plan.PAPER_CONTROLLERS), PAPER_SCENARIOS, metric)
        assert {c: r["rank"] for c, r in got.items()} == expected, metric


def test_rank_orders_by_the_average_over_scenarios_not_by_columns_won() -> None:
    # A wins four of five columns by a little; B wins one by a lot: B's average is lower.
    table = {
        "a": {s: {"m": 1.0} for s in "pqrs"} | {"t": {"m": 10.0}},
        "b": {s: {"m": 1.1} for s in "pqrs"} | {"t": {"m": 1.0}},
    }
    got = results.rank(table, ["a", "b"], list("pqrst"), "m")
    assert got["b"]["rank"] == 1 and got["a"]["rank"] == 2
    assert got["a"]["mean"] == pytest.approx(14.0 / 5)


def test_rank_puts_a_controller_with_a_missing_cell_last() -> None:
    table = {"a": {"p": {"m": 5.0}, "q": {"m": 5.0}}, "b": {"p": {"m": 0.1}, "q": {"m": None}}}
    got = results.rank(table, ["a", "b"], ["p", "q"], "m")
    assert got["a"]["rank"] == 1 and got["b"]["rank"] == 2 and got["b"]["mean"] is None


# ------------------------------------------------------------ convexity, classes


GRID = np.array(plan.SPECTRUM_FACTORS)


def test_a_convex_error_is_fragile() -> None:
    est = results.convexity(GRID, 0.01 + 0.02 * GRID**2)
    assert est["H"] > 0 and est["kappa"] > plan.SPECTRUM_TOLERANCE
    assert all(d > 0 for d in est["second_differences"])
    assert results.classify([est["kappa"]])["class"] == "fragile"


def test_a_concave_error_is_antifragile() -> None:
    est = results.convexity(GRID, 0.01 + 0.02 * np.sqrt(GRID))
    assert est["H"] < 0 and est["kappa"] < -plan.SPECTRUM_TOLERANCE
    assert results.classify([est["kappa"]])["class"] == "antifragile"


@pytest.mark.parametrize("response", [0.01 + 0.03 * GRID, np.full(GRID.shape, 0.02)])
def test_a_linear_or_flat_error_is_robust(response: np.ndarray) -> None:
    est = results.convexity(GRID, response)
    assert est["H"] == pytest.approx(0.0, abs=1e-15)
    assert results.classify([est["kappa"]])["class"] == "robust"


def test_the_heuristic_is_taleb_douadys_mean_over_symmetric_pairs() -> None:
    e = np.array([1.0, 2.0, 4.0, 7.0, 11.0])
    est = results.convexity(GRID, e)
    h = ((2.0 + 7.0) / 2 - 4.0 + (1.0 + 11.0) / 2 - 4.0) / 2
    assert est["H"] == pytest.approx(h)
    assert est["kappa"] == pytest.approx(h / 4.0)
    assert est["second_differences"] == [1.0, 1.0, 1.0]


def test_the_convexity_needs_a_uniform_odd_grid() -> None:
    with pytest.raises(ValueError, match="odd"):
        results.convexity([0, 1, 2, 3], [0, 1, 2, 3])
    with pytest.raises(ValueError, match="uniform"):
        results.convexity([0, 1, 3], [0, 1, 2])


def test_a_noise_band_across_the_tolerance_is_not_resolved_and_one_within_it_robust() -> None:
    # mean 0.2 (beyond the tolerance) but replicates disagree: the band spans +tolerance,
    # so the noise cannot tell robust from fragile
    assert results.classify([0.5, -0.1, 0.2])["class"] == "not resolved"
    assert results.classify([0.01, -0.01, 0.0])["class"] == "robust"
    tight = results.classify([0.19, 0.2, 0.21])
    assert tight["class"] == "fragile"
    assert tight["band"][0] > plan.SPECTRUM_TOLERANCE
    assert results.classify([-0.3, -0.31, -0.29])["class"] == "antifragile"


def test_ci95_is_the_student_t_interval_of_the_mean_and_worst_is_the_maximum() -> None:
    x = [1.0, 2.0, 4.0, 9.0]
    st = results.ci95(x)
    half = stats.t.ppf(0.975, 3) * np.std(x, ddof=1) / 2.0
    assert st["mean"] == pytest.approx(4.0)
    assert st["ci95"] == pytest.approx([4.0 - half, 4.0 + half])
    assert st["worst"] == 9.0 and st["n"] == 4
    assert results.ci95([3.0])["ci95"] is None
    assert results.ci95([math.nan, None])["n"] == 0  # type: ignore[list-item]


# ---------------------------------------------------------------- variations


def test_monte_carlo_draws_are_reproducible_and_inside_their_ranges() -> None:
    a = [draw_variation(7, r) for r in range(1, 40)]
    b = [draw_variation(7, r) for r in range(1, 40)]
    assert a == b
    assert len({v.seed for v in a}) == len(a)
    for v in a:
        assert 0.8 <= v.mass_factor <= 1.2 and 0.8 <= v.amplitude_factor <= 1.2
        assert plan.MC_NOISE_RANGE[0] <= v.noise_factor <= plan.MC_NOISE_RANGE[1]
        assert abs(v.onset_shift_s) <= plan.MC_ONSET_SHIFT_S
        assert max(abs(v.initial_offset[0]), abs(v.initial_offset[1])) <= plan.MC_OFFSET_M
    assert draw_variation(8, 1) != a[0]
    with pytest.raises(ValueError):
        draw_variation(7, 0)


def test_a_replicate_without_the_amplitude_draw_keeps_every_other_draw() -> None:
    full, fixed = draw_variation(3, 2), draw_variation(3, 2, vary_amplitude=False)
    assert fixed.amplitude_factor == 1.0 and full.amplitude_factor != 1.0
    assert (fixed.seed, fixed.mass_factor, fixed.noise_factor, fixed.initial_offset) == (
        full.seed,
        full.mass_factor,
        full.noise_factor,
        full.initial_offset,
    )


def test_a_variation_scales_and_shifts_faults_and_changes_the_bench_and_the_start() -> None:
    flat = scenario_mod.load("flat-left")
    var = Variation(
        amplitude_factor=0.5,
        onset_shift_s=-1.5,
        mass_factor=1.1,
        noise_factor=2.0,
        initial_offset=(0.01, -0.02, 0.03),
    )
    v = apply_variation(flat, var)
    (f,) = v.faults
    assert f.params.to_radius_m == pytest.approx(0.30 - 0.5 * 0.04)
    assert f.params.onset_s == pytest.approx(18.5)
    assert f.params.time_constant_s == flat.faults[0].params.time_constant_s
    assert v.bench["chair"]["mass_kg"] == pytest.approx(143.0)
    assert v.bench["chair"]["yaw_inertia_kgm2"] == pytest.approx(16.5)
    assert v.bench["localizer"]["sigma_xy_m"] == pytest.approx(0.04)
    assert v.params.initial_offset == pytest.approx((0.01, -0.02, 0.03))
    assert flat.faults[0].params.to_radius_m == 0.26  # the loaded scenario is untouched
    bump = apply_variation(scenario_mod.load("bump-right"), Variation(amplitude_factor=2.0))
    assert bump.faults[0].params.amplitude_m == pytest.approx(0.03)
    slip = apply_variation(scenario_mod.load("slip"), Variation(amplitude_factor=1.5))
    assert slip.faults[0].params.ratio == pytest.approx(0.15)
    assert stress_of(v.faults[0], 0.30) == pytest.approx(0.02)


def test_amplitude_zero_removes_the_faults_and_only_fault_keeps_one() -> None:
    casc = scenario_mod.load("cascaded")
    assert apply_variation(casc, Variation(amplitude_factor=0.0)).faults == ()
    rep = scenario_mod.load("repeated-exposure")
    (only,) = apply_variation(rep, Variation(only_fault=2)).faults
    assert only.params.onset_s == rep.faults[2].params.onset_s
    with pytest.raises(EvaluationError, match="no fault number"):
        apply_variation(rep, Variation(only_fault=5))


def test_a_variation_out_of_a_parameters_bounds_is_an_error_naming_it() -> None:
    from dbc.runtime.errors import ConfigError

    with pytest.raises(ConfigError, match="to_radius_m"):
        apply_variation(scenario_mod.load("flat-left"), Variation(amplitude_factor=7.0))


# ------------------------------------------------------------ per-run metrics


def test_window_errors_take_rms_and_max_inside_each_window() -> None:
    t_ns = np.arange(0, 10_000_000_000, 10_000_000)
    err = np.where(t_ns >= 5_000_000_000, 0.03, 0.01)
    w1, w2 = window_errors(t_ns, err, [(0.0, 5.0), (5.0, None)])
    assert w1["rmse_pos_m"] == pytest.approx(0.01) and w1["samples"] == 500
    assert w2["rmse_pos_m"] == pytest.approx(0.03) and w2["max_pos_err_m"] == 0.03
    (empty,) = window_errors(t_ns, err, [(20.0, 30.0)])
    assert empty["samples"] == 0 and math.isnan(empty["rmse_pos_m"])


def test_comfort_weights_the_real_longitudinal_and_lateral_accelerations() -> None:
    from controller import comfort as iso

    t_ns = np.arange(0, 60_000_000_000, 10_000_000)
    t = t_ns * 1e-9
    still = comfort(t_ns, np.full(t.size, 1.0), np.zeros(t.size))
    assert still["comfort_awx_mps2"] == pytest.approx(0.0, abs=1e-12)
    assert still["comfort_awy_mps2"] == pytest.approx(0.0, abs=1e-12)
    v = 1.0 + 0.1 * np.sin(2 * np.pi * 1.0 * t)  # 1 Hz surging
    w = np.full(t.size, 0.5)
    c = comfort(t_ns, v, w)
    assert c["comfort_awx_mps2"] == pytest.approx(
        iso.weighted_rms(np.gradient(v, t), 100.0, "x"), rel=1e-9
    )
    assert c["comfort_awy_mps2"] == pytest.approx(iso.weighted_rms(v * w, 100.0, "y"))
    assert c["comfort_av_mps2"] == pytest.approx(
        1.4 * math.hypot(c["comfort_awx_mps2"], c["comfort_awy_mps2"])
    )


# ------------------------------------------------------------------ campaign


def test_the_default_campaign_is_the_table_with_baseline_the_variant_and_the_cascaded_runs() -> (
    None
):
    camp = plan_campaign(Options(settings=("diagnosed",)))
    # the four paper controllers and BASELINE on the five columns, the variant on the flats
    assert len(camp.table) == 5 * 5 + 2
    assert {s for _, c, s in camp.table if c == "adaptive-integral"} == set(plan.VARIANT_SCENARIOS)
    assert {c for _, c in camp.cascaded} == set(plan.DEFAULT_CONTROLLERS) - set(plan.VARIANTS)
    assert len(camp.tasks) == 27 + 5
    assert not camp.spectrum and not camp.exposure and not camp.monte_carlo
    assert not camp.cascaded_mc


def test_replicates_go_to_the_ranked_controllers_and_the_variant_not_to_the_reference_row() -> None:
    camp = plan_campaign(Options(settings=("paper", "physical"), seeds=5))
    replicated = {(c, s) for (_, c, s) in camp.monte_carlo}
    assert {c for c, _ in replicated} == {*plan.PAPER_CONTROLLERS, *plan.VARIANTS}
    # the variant in the primary setting only
    assert {st for (st, c, _) in camp.table if c in plan.VARIANTS} == {"paper"}
    assert all(len(v) == 5 for v in camp.monte_carlo.values())
    # every controller sees the same draws in replicate r (common random numbers)
    draws = {
        (s, camp.tasks[k].variation)
        for (_, c, s), keys in camp.monte_carlo.items()
        for k in keys[:1]
    }
    assert len({v for _, v in draws}) == 1
    # only the primary setting's nominal runs keep a log
    logged = {k for k, t in camp.tasks.items() if t.log}
    assert logged and all(camp.tasks[k].variation.replicate == 0 for k in logged)
    assert {camp.tasks[k].setting for k in logged} <= {"paper", "physical"}
    assert camp.tasks[camp.table[("physical", "robust", "flat-left")]].log is False
    assert camp.tasks[camp.table[("paper", "robust", "flat-left")]].log is True
    with_reference = plan_campaign(Options(settings=("paper",), seeds=5, reference_mc=True))
    assert {c for (_, c, _) in with_reference.monte_carlo} >= {plan.REFERENCE_CONTROLLER}


def test_three_settings_share_the_runs_that_are_the_same_experiment() -> None:
    camp = plan_campaign(Options(controllers=("robust",)))
    assert len(camp.table) == 3 * 5
    key = camp.table
    # without a flat tire, (a) paper is (b) physical: one run for both
    for s in ("fault-free", "bump-left", "bump-right"):
        assert key[("paper", "robust", s)] == key[("physical", "robust", s)]
        assert camp.tasks[key[("paper", "robust", s)]].setting == "physical"
        assert key[("diagnosed", "robust", s)] != key[("physical", "robust", s)]
    for s in ("flat-left", "flat-right"):
        assert len({key[(st, "robust", s)] for st in plan.FAULT_SETTINGS}) == 3
        assert camp.tasks[key[("paper", "robust", s)]].setting == "paper"
    # fault-free and two bumps twice, two flats three times, the cascade (a flat) thrice
    assert len(camp.tasks) == 3 * 2 + 2 * 3 + 3


def test_the_fault_setting_names_agree_between_the_plan_and_the_scenarios() -> None:
    assert tuple(scenario_mod.FAULT_SETTINGS) == plan.FAULT_SETTINGS


def test_monte_carlo_cascades_draw_random_moments_and_magnitudes() -> None:
    camp = plan_campaign(
        Options(
            controllers=("robust",), scenarios=("fault-free",), cascade_seeds=3, settings=("paper",)
        )
    )
    draws = [camp.tasks[k].variation for k in camp.cascaded_mc[("paper", "robust")]]
    assert len(draws) == 3 and len({d.cascade for d in draws}) == 3
    casc = scenario_mod.load("cascaded")
    for d in draws:
        assert d.cascade is not None and len(d.cascade) == len(casc.faults)
        onsets = [t for t, _, _ in d.cascade]
        assert onsets == sorted(onsets)
        assert all(plan.MC_CASCADE_WINDOW_S[0] <= t <= plan.MC_CASCADE_WINDOW_S[1] for t in onsets)
        # each fault lasts until the next one begins
        for (t0, dur, _), (t1, _, _) in zip(d.cascade, d.cascade[1:], strict=False):
            assert t0 + dur == pytest.approx(t1)
        assert all(
            plan.MC_CASCADE_FACTOR[0] <= k <= plan.MC_CASCADE_FACTOR[1] for *_, k in d.cascade
        )
        varied = apply_variation(casc, d)
        assert [f.params.onset_s for f in varied.faults] == pytest.approx(onsets)
    # the flat tire's depth follows its factor
    d = draws[0]
    assert d.cascade is not None
    flat = next(i for i, f in enumerate(casc.faults) if f.kind == "flat-tire")
    varied = apply_variation(casc, d)
    loss = 0.30 - varied.faults[flat].params.to_radius_m
    assert loss == pytest.approx(d.cascade[flat][2] * (0.30 - casc.faults[flat].params.to_radius_m))


def test_spectrum_runs_are_shared_where_they_are_the_same_experiment() -> None:
    opt = Options(controllers=("antifragile",), spectrum=True, spectrum_seeds=2, cascaded=False)
    camp = plan_campaign(dataclasses.replace(opt, settings=("diagnosed",)))
    nominal = [grid[0] for grid in camp.spectrum.values()]
    # amplitude 0 is the fault-free run of the replicate, whatever the fault
    for r in range(2):
        assert len({reps[r][0.0] for reps in camp.spectrum.values()}) == 1
    assert nominal[0][0.0] == camp.table[("diagnosed", "antifragile", "fault-free")]
    # the nominal replicate at the paper's amplitude is the table's run
    assert (
        camp.spectrum[("antifragile", "flat-left")][0][1.0]
        == camp.table[("diagnosed", "antifragile", "flat-left")]
    )
    # 5 table runs; nominal replicate: 5 faults x 4 amplitudes, of which the 4 paper faults
    # at the paper's amplitude are table runs; replicate 1: its fault-free run + 5 x 4
    assert len(camp.tasks) == 5 + (5 * 4 - 4) + (1 + 5 * 4)


def test_exposure_adds_one_first_time_run_per_later_exposure() -> None:
    camp = plan_campaign(
        Options(
            controllers=("robust",),
            scenarios=("fault-free",),
            exposure=True,
            cascaded=False,
            settings=("diagnosed",),
        )
    )
    roles = camp.exposure["robust"]
    assert roles["single"][0] is None and len(roles["single"]) == 3
    assert camp.tasks[roles["single"][2]].variation.only_fault == 2
    assert len(camp.tasks) == 1 + 1 + 2


def test_bad_options_are_errors_naming_the_option() -> None:
    from dbc.runtime.errors import ConfigError

    with pytest.raises(EvaluationError, match="unknown controller 'nope'"):
        plan_campaign(Options(controllers=("nope",)))
    with pytest.raises(ConfigError, match="unknown scenario"):
        plan_campaign(Options(scenarios=("nope",)))
    with pytest.raises(EvaluationError, match="spectrum-faults"):
        plan_campaign(Options(spectrum=True, spectrum_faults=("wobble",)))
    with pytest.raises(EvaluationError, match="at least 1"):
        plan_campaign(Options(seeds=0))
    with pytest.raises(EvaluationError, match="unknown fault setting 'real'"):
        plan_campaign(Options(settings=("real",)))


def test_task_keys_name_scenario_variation_and_controller() -> None:
    assert Task("robust", "flat-left").key == "diagnosed/flat-left/nominal/robust"
    var = Variation(replicate=2, amplitude_factor=0.5)
    assert Task("robust", "flat-left", var, setting="paper").key == (
        "paper/flat-left/r02-x0.5/robust"
    )
    assert Task("robust", "fault-free", base_seed=4).key == (
        "diagnosed/fault-free/nominal-s4/robust"
    )


# -------------------------------------------------------------------- report


def _results_from_paper() -> dict[str, object]:
    table = paper_table_as_results()
    ctrls = list(plan.PAPER_CONTROLLERS)
    return {
        "meta": {
            "controllers": ctrls,
            "ranked_controllers": ctrls,
            "scenarios": PAPER_SCENARIOS,
            "runs": 20,
            "seed": 1,
        },
        "table": table,
        "rank": {m: results.rank(table, ctrls, PAPER_SCENARIOS, m) for m in report.COMPONENTS},
    }


def test_the_report_puts_ours_next_to_the_papers_in_the_papers_layout() -> None:
    lines = report.paper_table_markdown(_results_from_paper())
    assert lines[0].startswith("| Control system / fault type | Fault-free | Bump left")
    assert "| ANTIFRAGILE | 0.0025 (0.0025) |" in "\n".join(lines)
    blocks = [ln for ln in lines if ln.startswith("| ***")]
    assert [b.split("***")[1] for b in blocks] == ["x_e RMSE", "y_e RMSE", "φ_e RMSE"]


def test_the_rank_statement_says_where_the_rankings_agree_and_where_not() -> None:
    res = _results_from_paper()
    text = "\n".join(report.rank_statement(res))
    assert text.count("the same order as the paper") == 3
    assert "12 of 12" in text
    ranks = res["rank"]["rmse_phie_rad"]  # type: ignore[index]
    ranks["robust"]["rank"], ranks["resilient"]["rank"] = 2, 1
    text = "\n".join(report.rank_statement(res))
    assert "differs for ROBUST 2 (paper 1), RESILIENT 1 (paper 2)" in text
    assert "10 of 12" in text


def test_the_deterministic_part_leaves_out_only_the_timing() -> None:
    res = {"meta": {}, "table": {}, "timing": {"campaign_wall_s": 3.0}}
    assert deterministic_part(res) == {"meta": {}, "table": {}}


def test_the_dask_path_without_dask_installed_says_what_to_install(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(EvaluationError, match=r"pip install 'wheelchair-hil\[dask\]'"):
        execute(
            [Task("baseline", "short")], tmp_path, scheduler="tcp://127.0.0.1:1", progress=False
        )  # type: ignore[arg-type]


def test_a_cached_run_is_reused_only_for_the_same_task(tmp_path: Path) -> None:
    import json

    task = Task("robust", "short", duration_s=3.0)
    run_dir = tmp_path / "runs" / task.key
    run_dir.mkdir(parents=True)
    record = {"task": _task_record(task), "result": {"rmse_pos_m": 0.01}, "timing": {}}
    (run_dir / "result.json").write_text(json.dumps(record))
    assert load_cached(tmp_path, task) is None  # no series.npz: not complete
    np.savez_compressed(run_dir / "series.npz", x=np.zeros(1))
    cached = load_cached(tmp_path, task)
    assert cached is not None and cached["result"] == {"rmse_pos_m": 0.01}
    assert cached["timing"]["resumed"] is True
    assert load_cached(tmp_path, Task("robust", "short", duration_s=4.0)) is None


def test_a_failing_figure_costs_only_itself(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    from tools.evaluation import figures

    def broken(_results: object, _out: Path) -> Path:
        raise ValueError("x and y must have same first dimension")

    def fine(_results: object, out: Path) -> Path:
        path = out / "fine.png"
        path.write_bytes(b"png")
        return path

    monkeypatch.setattr(figures, "FIGURES", (broken, fine))
    assert figures.make_all({}, tmp_path) == ["fine.png"]
    assert "figure broken failed" in caplog.text


# ------------------------------------------------------------- verdicts on ranks


PAPER = {"antifragile": 1, "adaptive": 2, "robust": 3}


def _judged(table: dict[str, list[float | None]]) -> tuple[dict, dict]:
    tests = verdicts.pair_tests(table, PAPER)
    verdicts.judge_pairs(tests)
    return tests, verdicts.rank_verdicts(tests, table, PAPER)


def test_paired_differences_resolve_an_order_that_separate_intervals_cannot() -> None:
    # a large shared replicate effect (the same draws for all) and a small, steady gap
    shared = [0.0, 3.0, -2.0, 5.0, 1.0, -4.0]
    table = {
        "antifragile": [10 + x for x in shared],
        "adaptive": [10.2 + x + 0.01 * (-1) ** i for i, x in enumerate(shared)],
        "robust": [10.4 + x for x in shared],
    }
    bands = {c: results.ci95(v) for c, v in table.items()}
    assert bands["antifragile"]["ci95"][1] > bands["adaptive"]["ci95"][0]  # they overlap
    tests, v = _judged(table)
    assert {c: x["verdict"] for c, x in v.items()} == dict.fromkeys(PAPER, "reproduced")
    assert tests["antifragile|adaptive"]["verdict"] == "borne out"
    assert v["adaptive"]["pairs"] == {"antifragile": "borne out", "robust": "borne out"}


def test_the_pair_test_is_a_t_test_with_n_minus_one_degrees_of_freedom() -> None:
    d = [0.3, -0.1, 0.5, 0.2, 0.4]
    got = verdicts.paired_t(d)
    want = stats.ttest_1samp(d, 0.0)
    assert got["p"] == pytest.approx(want.pvalue)
    half = stats.t.ppf(0.975, 4) * np.std(d, ddof=1) / math.sqrt(5)
    assert got["ci"] == pytest.approx([np.mean(d) - half, np.mean(d) + half])


def test_an_order_refuted_by_the_pairs_is_one_refuted_pair_and_contradicts_both_ranks() -> None:
    noise = [0.01, -0.02, 0.015, -0.005, 0.0]
    table = {
        "antifragile": [5 + n for n in noise],
        "adaptive": [3 - n for n in noise],
        "robust": [7 + 2 * n for n in noise],
    }
    tests, v = _judged(table)
    assert tests["antifragile|adaptive"]["verdict"] == "refuted"
    assert verdicts.count_pairs(tests) == {"borne out": 2, "refuted": 1, "undecided": 0}
    assert v["antifragile"]["verdict"] == v["adaptive"]["verdict"] == "contradicted"
    assert v["robust"]["verdict"] == "reproduced"


def test_a_failed_run_counts_as_the_worst_of_its_replicate_and_keeps_the_pairing() -> None:
    # ANTIFRAGILE is best wherever it finishes, but fails in three of six replicates:
    # dropping those (as before) would call it better; counted as the worst, it is not
    table = {
        "antifragile": [1.0, None, 1.0, None, 1.0, None],
        "adaptive": [2.0, 2.1, 2.0, 2.1, 2.0, 2.1],
        "robust": [3.0, 3.1, 3.0, 3.1, 3.0, 3.1],
    }
    filled = verdicts.worst_filled(table)
    assert filled["antifragile"] == [1.0, 3.1, 1.0, 3.1, 1.0, 3.1]
    tests, v = _judged(table)
    assert tests["antifragile|adaptive"]["failed"] == {"antifragile": 3, "adaptive": 0}
    assert tests["antifragile|adaptive"]["verdict"] == "undecided"
    assert v["antifragile"]["verdict"] == "not resolved"
    assert v["antifragile"]["failed"] == 3 and v["antifragile"]["n"] == 6


def test_a_run_stopped_early_is_worse_than_every_finished_run_when_its_own_figures_say_so() -> None:
    # replicate 1: only ADAPTIVE finishes; the others stopped, ROBUST after going far off
    table = {"adaptive": [2.0, 2.0], "robust": [3.0, None], "antifragile": [1.0, None]}
    as_run = {"adaptive": [2.0, 2.0], "robust": [3.0, 9.0], "antifragile": [1.0, 0.5]}
    filled = verdicts.worst_filled(table, as_run)
    # both failures rank below ADAPTIVE, at the worst figure reached, ROBUST's own 9.0
    assert filled == {"adaptive": [2.0, 2.0], "robust": [3.0, 9.0], "antifragile": [1.0, 9.0]}
    # without the figures of the stopped runs they would tie with the only finisher
    assert verdicts.worst_filled(table)["antifragile"] == [1.0, 2.0]


def test_holm_adjusts_each_p_value_for_the_whole_family() -> None:
    adj = verdicts.holm({"a": 0.01, "b": 0.04, "c": 0.03, "d": None})
    assert adj == {
        "a": pytest.approx(0.03),
        "b": pytest.approx(0.06),
        "c": pytest.approx(0.06),
        "d": None,
    }
    # a pair significant alone is undecided in a family of 54
    tests = {k: {"p": 0.01, "mean": -1.0} for k in range(54)}
    verdicts.judge_pairs(tests)
    assert {t["verdict"] for t in tests.values()} == {"undecided"}
    assert tests[0]["family"] == 54


def test_one_replicate_judges_nothing() -> None:
    tests, v = _judged({c: [1.0 + r] for r, c in enumerate(PAPER)})
    assert {t["verdict"] for t in tests.values()} == {"undecided"}
    assert {x["verdict"] for x in v.values()} == {"not resolved"}


def test_replicate_table_averages_each_replicate_over_the_scenarios() -> None:
    samples = {"c": {"a": [1.0, 2.0, 3.0], "b": [3.0, math.nan, 5.0]}}
    assert verdicts.replicate_table(samples, ["c"], ["a", "b"]) == {"c": [2.0, None, 4.0]}


def test_a_run_stopped_before_its_routes_end_fails_its_replicate() -> None:
    samples = {"c": {"a": [1.0, 2.0, 3.0], "b": [3.0, 4.0, 5.0]}}
    stopped = {"c": {"a": [False, False, True], "b": [False, False, False]}}
    table = verdicts.replicate_table(samples, ["c"], ["a", "b"], stopped)
    assert table == {"c": [2.0, 3.0, None]}
    # and so counts as that replicate's worst result in a paired comparison
    filled = verdicts.worst_filled({"c": table["c"], "d": [1.0, 1.0, 9.0]})
    assert filled["c"] == [2.0, 3.0, 9.0]


def _runs_for(camp: Campaign, value: object) -> dict[str, dict[str, object]]:
    """Every run of ``camp`` with result ``value(task)`` for every rank metric."""
    out: dict[str, dict[str, object]] = {}
    for key, task in camp.tasks.items():
        v = value(task)  # type: ignore[operator]
        out[key] = {"result": {m: v for m in (*plan.CELL_METRICS, "rmse_pos_m")}}
    return out


def test_results_label_every_setting_and_judge_the_papers_ranks_in_each() -> None:
    opt = Options(
        controllers=(*plan.PAPER_CONTROLLERS, "baseline"),
        seeds=4,
        cascaded=False,
        settings=("paper", "diagnosed"),
    )
    camp = plan_campaign(opt)
    order = {"antifragile": 1.0, "adaptive": 2.0, "robust": 3.0, "resilient": 4.0, "baseline": 0}

    def value(task: Task) -> float:
        # the paper's x_e order everywhere, with a little replicate noise
        return order[task.controller] + 0.01 * task.variation.replicate

    res = build_results(camp, _runs_for(camp, value), 1.0, "test")
    assert res["meta"]["setting"] == "paper"
    assert set(res["settings"]) == {"paper", "diagnosed"}
    assert res["meta"]["setting_labels"]["paper"].startswith("(a) paper")
    for st in ("paper", "diagnosed"):
        v = res["settings"][st]["verdicts"]["rmse_xe_m"]
        assert {c: x["verdict"] for c, x in v.items()} == dict.fromkeys(
            plan.PAPER_CONTROLLERS, "reproduced"
        )
        # the paper's phi_e order is not the x_e order: ADAPTIVE (4th there) is 2nd here
        assert res["settings"][st]["verdicts"]["rmse_phie_rad"]["adaptive"]["verdict"] == (
            "contradicted"
        )
        cell = res["settings"][st]["monte_carlo"]["table"]["robust"]["flat-left"]["rmse_xe_m"]
        assert cell["n"] == 4 and cell["ci95"][0] < 3.025 < cell["ci95"][1]
    assert res["table"] == res["settings"]["paper"]["table"]
    assert res["table"]["robust"]["flat-left"]["fault_setting"] == "paper"
    assert res["table"]["robust"]["bump-left"]["fault_setting"] == "physical"
    text = report.verdict_lines(res, res["settings"]["paper"])
    assert any("| x_e RMSE | ANTIFRAGILE | 1 |" in ln and "**reproduced**" in ln for ln in text)
    table = "\n".join(report.paper_table_markdown(res, res["settings"]["diagnosed"]))
    assert "1 (1) **reproduced**" in table
    summary = report.console_summary(res, Path("out"))
    assert "fault setting paper:" in summary and "fault setting diagnosed:" in summary


def test_a_controller_that_stops_off_its_path_is_counted_failed_however_small_its_figures() -> None:
    opt = Options(controllers=plan.PAPER_CONTROLLERS, seeds=4, cascaded=False, settings=("paper",))
    camp = plan_campaign(opt)
    order = {"antifragile": 1.0, "adaptive": 2.0, "robust": 3.0, "resilient": 4.0}
    runs = _runs_for(camp, lambda t: order[t.controller] + 0.01 * t.variation.replicate)
    for key, task in camp.tasks.items():
        if task.controller == "antifragile" and task.scenario.endswith("flat-left"):
            runs[key]["result"]["stop_reason"] = "OFF_PATH"  # type: ignore[index]
    res = build_results(camp, runs, 1.0, "test")
    mc = res["settings"]["paper"]["monte_carlo"]
    assert mc["stopped"]["antifragile"]["flat-left"] == [True] * 4
    assert mc["samples"]["rmse_xe_m"]["antifragile"]["flat-left"][0] == pytest.approx(1.01)
    assert mc["replicate_means"]["rmse_xe_m"]["antifragile"] == [None] * 4
    tests = res["settings"]["paper"]["pair_tests"]["rmse_xe_m"]
    pair = tests["antifragile|resilient"]
    assert pair["failed"]["antifragile"] == 4 and pair["verdict"] != "borne out"
    v = res["settings"]["paper"]["verdicts"]["rmse_xe_m"]["antifragile"]["verdict"]
    assert v != "reproduced"


def test_each_runs_shares_are_kept_and_the_report_gives_each_controllers_mean(
    tmp_path: Path,
) -> None:
    """Every run's share of ticks at each limit of the envelope and in each of its law's
    events is kept beside its figures; per setting and controller, their mean over its runs
    (table, replicates, cascaded) is a table of report.md."""
    opt = Options(controllers=("robust", "adaptive"), seeds=3, settings=("paper",))
    camp = plan_campaign(opt)
    runs = _runs_for(camp, lambda t: 1.0 + 0.01 * t.variation.replicate)
    for key, task in camp.tasks.items():
        r = runs[key]["result"]
        accel = 0.1 * task.variation.replicate  # 0 nominal, then 0.1, 0.2, 0.3
        r["rate_limit_share"] = {  # type: ignore[index]
            "accel": accel,
            "turn_accel": 0.0,
            "speed": 0.5,
            "turn_rate": None,
            "jerk": 0.0,
        }
        r["law_activity_share"] = (  # type: ignore[index]
            {"outside_boundary1": 0.2} if task.controller == "robust" else {"qp_fallback": 0.0}
        )
        r["estimate_step_max_m"] = 0.001 * (1 + task.variation.replicate)  # type: ignore[index]
        r["estimate_step_max_rad"] = 0.002  # type: ignore[index]
    failed = camp.monte_carlo[("paper", "robust", "fault-free")][0]
    runs[failed] = {"error": "boom", "result": {}}
    off = camp.monte_carlo[("paper", "adaptive", "fault-free")][1]
    runs[off]["result"]["stop_reason"] = "OFF_PATH"  # type: ignore[index]
    res = build_results(camp, runs, 1.0, "test")
    block = res["settings"]["paper"]
    cell = block["table"]["robust"]["fault-free"]
    assert cell["rate_limit_share"]["speed"] == 0.5
    assert cell["law_activity_share"] == {"outside_boundary1": 0.2}
    reps = block["monte_carlo"]["shares"]["rate_limit_share"]["robust"]["fault-free"]
    assert reps[0] is None and [r["accel"] for r in reps[1:]] == pytest.approx([0.2, 0.3])
    assert block["cascaded"]["adaptive"]["rate_limit_share"]["accel"] == 0.0
    use = block["limit_use"]
    n_adaptive = 1 + len(opt.scenarios) * (1 + opt.seeds) + opt.cascade_seeds
    assert use["adaptive"]["runs"] == n_adaptive
    assert use["robust"]["runs"] == n_adaptive - 1  # the failed run has none
    assert use["adaptive"]["stopped"] == 1 and use["robust"]["stopped"] == 0
    assert use["robust"]["rate_limit_share"]["speed"] == pytest.approx(0.5)
    assert use["robust"]["rate_limit_share"]["turn_rate"] is None  # never measured
    assert use["robust"]["law_activity_share"] == {"outside_boundary1": pytest.approx(0.2)}
    # the largest estimate step over the runs, not a mean
    assert use["adaptive"]["estimate_step_max_m"] == pytest.approx(0.001 * (1 + opt.seeds))
    assert use["adaptive"]["estimate_step_max_rad"] == pytest.approx(0.002)
    lines = report.limit_use_lines(block)
    text = "\n".join(lines)
    assert (
        "| controller | runs | stopped | accel | turn accel | speed | turn rate | jerk "
        "| estimate step (cm / mrad) |" in text
    )
    assert f"| {100 * 0.001 * (1 + opt.seeds):.1f} / 2 |" in text
    assert "| ROBUST |" in text and "outside_boundary1 20.00" in text
    assert "qp_fallback 0.00" in text and "before the node's limiter" in text
    assert list(report.RATE_LIMIT_TITLES) == list(RATE_LIMITS)
    md = report.write_report(res, tmp_path, []).read_text()
    assert md.count("### How each law met the envelope, and what it did") == 1
    # a campaign whose runs have no shares (e.g. resumed from before) shows no such table
    assert report.limit_use_lines({"limit_use": {"robust": {"runs": 0}}}) == []


def test_off_a_terminal_the_campaign_prints_plain_progress_lines_and_each_failure(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A CI log gets one plain line per tenth of the runs (here: per run, there are three),
    with the count, the time so far and the estimate, and never a carriage return."""
    tasks = [Task(c, "short", duration_s=3.0) for c in ("baseline", "robust", "adaptive")]

    def fake_run(task: Task, root: str) -> dict[str, object]:
        return {"key": task.key, "error": "boom" if task.controller == "robust" else ""}

    monkeypatch.setattr("tools.evaluation.execute.run_task", fake_run)
    out = execute(tasks, tmp_path, workers=1)
    assert set(out) == {t.key for t in tasks}
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    progress = [ln for ln in lines if ln.startswith("evaluate: ")]
    assert [ln.split(",")[0] for ln in progress] == [
        "evaluate: 1/3 runs (33 %)",
        "evaluate: 2/3 runs (66 %)",
        "evaluate: 3/3 runs (100 %)",
    ]
    assert all(" elapsed" in ln for ln in progress)
    assert " left" in progress[0] and " left" not in progress[-1]
    # each line names the run just finished; the longest run (adaptive) goes first
    assert [ln.rsplit("; last: ", 1)[1] for ln in progress] == [
        tasks[2].key,
        tasks[0].key,
        tasks[1].key,
    ]
    assert f"run {tasks[1].key} failed: boom" in lines


def test_without_progress_the_campaign_prints_nothing(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr("tools.evaluation.execute.run_task", lambda t, root: {"key": t.key})
    execute([Task("baseline", "short")], tmp_path, progress=False)
    assert capsys.readouterr().err == ""


def test_a_challenger_is_judged_against_each_of_the_papers_laws_in_its_own_family() -> None:
    from tools.evaluation.verdicts import challenger_tests, judge_challengers

    paper_rank = {"robust": 1, "antifragile": 2}
    table = {
        "robust": [0.10, 0.11, 0.12, 0.10, 0.11, 0.12],
        "antifragile": [0.05, 0.051, 0.049, 0.05, 0.052, 0.048],
        "mine": [0.07, 0.071, 0.069, 0.07, 0.072, None],  # its last replicate failed
    }
    tests = challenger_tests(table, ["mine"], paper_rank)
    assert set(tests) == {"mine|robust", "mine|antifragile"}
    # a failed run counts as the replicate's worst: robust's 0.12 there
    assert tests["mine|robust"]["diffs"][-1] == 0.0
    assert tests["mine|robust"]["failed"] == {"mine": 1, "robust": 0}
    judge_challengers(tests)
    assert {t["family"] for t in tests.values()} == {2}
    assert tests["mine|antifragile"]["verdict"] == "worse"  # higher RMSE on every draw
    assert tests["mine|robust"]["verdict"] in ("better", "undecided")
    assert tests["mine|robust"]["mean"] < 0


def test_replicates_per_setting_plan_that_many_runs_per_cell_and_are_checked() -> None:
    opt = Options(
        controllers=("robust", "baseline"),
        scenarios=("fault-free",),
        seeds=3,
        seeds_per_setting=(("paper", 7),),
        settings=("paper", "physical"),
        cascaded=False,
    )
    camp = plan_campaign(opt)
    assert len(camp.monte_carlo[("paper", "robust", "fault-free")]) == 7
    assert len(camp.monte_carlo[("physical", "robust", "fault-free")]) == 3
    assert ("paper", "baseline", "fault-free") not in camp.monte_carlo  # the reference row
    # the first replicates of a setting are the same draws whatever the count
    a = camp.monte_carlo[("paper", "robust", "fault-free")][:3]
    b = camp.monte_carlo[("physical", "robust", "fault-free")]
    assert [camp.tasks[k].variation for k in a] == [camp.tasks[k].variation for k in b]
    with pytest.raises(EvaluationError, match="diagnosed=4 names a setting"):
        plan_campaign(dataclasses.replace(opt, seeds_per_setting=(("diagnosed", 4),)))
    with pytest.raises(EvaluationError, match="at least 1"):
        plan_campaign(dataclasses.replace(opt, seeds_per_setting=(("paper", 0),)))


def test_the_seeds_option_takes_a_count_or_one_per_setting() -> None:
    from tools.cli.evaluate import _seeds

    assert _seeds("5") == (5, ())
    assert _seeds("paper=20,physical=10,diagnosed=10") == (
        1,
        (("paper", 20), ("physical", 10), ("diagnosed", 10)),
    )
    assert _seeds("5,paper=20") == (5, (("paper", 20),))
    with pytest.raises(Exception, match="a bare N comes first"):
        _seeds("paper=20,5")
    with pytest.raises(Exception, match="SETTING=N"):
        _seeds("paper=many")
