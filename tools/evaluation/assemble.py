"""``results.json`` assembled from a campaign's runs.

:func:`build_results` gives, per fault setting, the table, the rank, the Monte-Carlo
statistics and the paired verdicts (judged as one family over the whole campaign), the
cascaded runs, and the fragility spectrum (convexity and class per controller and fault) and
the gain from repeated exposure; the statistics themselves are :mod:`tools.evaluation.results`'.
Everything but the ``timing`` section is a function of the options and the seeds
(:func:`deterministic_part`): a campaign run twice gives the same file, whatever the number
of workers.  ``tools.evaluation.report`` writes ``report.md`` and ``tools.evaluation.figures``
the PNGs from the same data.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from tools.evaluation.campaign import Campaign
from tools.evaluation.paper import PAPER_RANK
from tools.evaluation.plan import (
    CELL_METRICS,
    MC_AMPLITUDE_SPREAD,
    MC_CASCADE_FACTOR,
    MC_CASCADE_LAST_S,
    MC_CASCADE_WINDOW_S,
    MC_MASS_SPREAD,
    MC_NOISE_RANGE,
    MC_OFFSET_M,
    MC_ONSET_SHIFT_S,
    RANK_METRICS,
    REFERENCE_CONTROLLERS,
    SHARE_FIELDS,
    SPECTRUM_FACTORS,
    SPECTRUM_METRIC,
    SPECTRUM_TOLERANCE,
    VARIANTS,
)
from tools.evaluation.results import ci95, classify, convexity, mean_shares, rank
from tools.evaluation.task import jsonable
from tools.evaluation.verdicts import (
    FAMILY_ALPHA,
    challenger_tests,
    count_pairs,
    judge_challengers,
    judge_pairs,
    pair_tests,
    rank_verdicts,
    replicate_table,
    variant_effect,
)
from tools.run import scenario as scenario_mod


def build_results(
    camp: Campaign,
    runs: Mapping[str, Mapping[str, Any]],
    wall_s: float,
    workers: str,
    n_workers: int = 1,
) -> dict[str, Any]:
    """``results.json``: everything but ``timing`` depends only on the options and seeds.

    ``settings[name]`` holds each fault setting's table, rank, Monte-Carlo bands, verdicts
    and cascaded runs; the top-level ``table``, ``rank``, ``monte_carlo``, ``verdicts`` and
    ``cascaded`` are the primary setting's (``meta.setting``), which the figures draw.
    """
    opt = camp.options
    ranked = [c for c in opt.controllers if c not in REFERENCE_CONTROLLERS] or list(opt.controllers)
    blocks = {st: _setting_block(camp, runs, st, ranked) for st in opt.settings}
    _judge(blocks)
    primary = opt.settings[0]
    out: dict[str, Any] = {
        "meta": {
            "controllers": list(opt.controllers),
            "ranked_controllers": ranked,
            "scenarios": list(opt.scenarios),
            "seed": opt.seed,
            "seeds": opt.seeds,
            "seeds_per_setting": {st: opt.seeds_for(st) for st in opt.settings},
            "duration_s": opt.duration_s,
            "runs": len(camp.tasks),
            "failed_runs": sorted(k for k, v in runs.items() if v.get("error")),
            "rank_definition": "per metric: mean over the table's scenarios, ascending; 1 = best",
            "setting": primary,
            "setting_label": scenario_mod.FAULT_SETTINGS[primary],
            "settings": list(opt.settings),
            "setting_labels": {st: scenario_mod.FAULT_SETTINGS[st] for st in opt.settings},
            "verdict_definition": (
                "per pair of ranked controllers and component: the paired differences of "
                "their scenario-averaged RMSE over the Monte-Carlo replicates (common random "
                "numbers; a failed run, or one that stopped before its route's end, counts "
                "as its replicate's worst result), a two-sided "
                "t test with n - 1 degrees of freedom, p-values Holm-adjusted over every pair "
                f"of every component and setting of the campaign (family-wise alpha "
                f"{FAMILY_ALPHA}): borne out if significant in the paper's order, refuted if "
                "significant in the other, undecided otherwise; a controller's rank is "
                "reproduced if all its pairs are borne out, contradicted if any is refuted, "
                "not resolved otherwise"
            ),
            "gains": {
                c: {"source": opt.gains, **e["provenance"]} for c, e in sorted(camp.gains.items())
            },
        },
        "settings": {st: {k: v for k, v in b.items() if k != "timing"} for st, b in blocks.items()},
    }
    for k in (
        "table",
        "rank",
        "monte_carlo",
        "verdicts",
        "pair_tests",
        "pair_counts",
        "cascaded",
        "cascaded_mc",
    ):
        if k in blocks[primary]:
            out[k] = blocks[primary][k]
    if camp.spectrum:
        out["meta"]["spectrum"] = _spectrum_method(camp)
        out["spectrum"] = _spectrum(camp, runs)
    if camp.exposure:
        out["exposure"] = _exposure(camp, runs)
    sim_s = sum(
        float((v.get("timing") or {}).get("sim_duration_s") or 0.0)
        for v in runs.values()
        if not (v.get("timing") or {}).get("resumed")
    )
    n_workers = max(1, n_workers)
    out["timing"] = {
        "campaign_wall_s": wall_s,
        "executor": workers,
        # simulated seconds per second of each worker: the campaign's real-time factor
        "sim_s": sim_s,
        "workers": n_workers,
        "real_time_factor_per_worker": sim_s / (wall_s * n_workers) if wall_s > 0 else None,
        "table": blocks[primary]["timing"],
        "settings": {st: b["timing"] for st, b in blocks.items()},
        "runs": {k: v.get("timing") for k, v in sorted(runs.items())},
    }
    return jsonable(out)


def _judge(blocks: Mapping[str, dict[str, Any]]) -> None:
    """The verdicts of every setting's pairs as one family (Holm over all of them), then each
    setting's rank verdicts and pair counts (in place)."""
    family = {
        (st, m, k): t
        for st, b in blocks.items()
        for m, tests in (b.get("pair_tests") or {}).items()
        for k, t in tests.items()
    }
    judge_pairs(family)
    judge_challengers(
        {
            (st, m, k): t
            for st, b in blocks.items()
            for m, tests in (b.get("challenger_tests") or {}).items()
            for k, t in tests.items()
        }
    )
    for b in blocks.values():
        if "pair_tests" not in b:
            continue
        tables = b["monte_carlo"]["replicate_means"]
        b["verdicts"] = {
            m: rank_verdicts(tests, tables[m], PAPER_RANK.get(m, {}))
            for m, tests in b["pair_tests"].items()
        }
        b["pair_counts"] = {m: count_pairs(tests) for m, tests in b["pair_tests"].items()}


def _setting_block(
    camp: Campaign, runs: Mapping[str, Mapping[str, Any]], st: str, ranked: Sequence[str]
) -> dict[str, Any]:
    """One fault setting's part of ``results.json`` (and its ``timing`` table)."""
    opt = camp.options

    def res(key: str | None) -> dict[str, Any]:
        return dict(runs.get(key, {}).get("result") or {}) if key else {}

    def metric(key: str | None, m: str) -> float:
        v = res(key).get(m)
        return float(v) if v is not None else math.nan

    def stopped(key: str | None) -> bool:
        """The run failed or ended in a safe stop (OFF_PATH, DISOBEYED, ...) before its
        route's end; NONE (the bench's duration ended first) is not a stop."""
        if key is None or runs.get(key, {}).get("error"):
            return True
        return res(key).get("stop_reason") not in (None, "ROUTE_DONE", "NONE")

    table: dict[str, dict[str, Any]] = {}
    timing_table: dict[str, dict[str, Any]] = {}
    for (s_, c, s), key in camp.table.items():
        if s_ != st:
            continue
        r = res(key)
        cell = {m: r.get(m) for m in (*CELL_METRICS, *SHARE_FIELDS)}
        cell.update(
            stop_reason=r.get("stop_reason"),
            fault_diagnosis=r.get("fault_diagnosis"),
            log=r.get("log"),
            fault_setting=camp.tasks[key].setting,
        )
        if runs.get(key, {}).get("error"):
            cell["error"] = runs[key]["error"]
        table.setdefault(c, {})[s] = cell
        timing_table.setdefault(c, {})[s] = runs.get(key, {}).get("timing")
    block: dict[str, Any] = {
        "label": scenario_mod.FAULT_SETTINGS[st],
        "table": table,
        "rank": {m: rank(table, ranked, opt.scenarios, m) for m in (*RANK_METRICS, "rmse_pos_m")},
        "timing": timing_table,
    }
    mc_keys = {(c, s): keys for (s_, c, s), keys in camp.monte_carlo.items() if s_ == st}
    if mc_keys:
        mc: dict[str, dict[str, Any]] = {}
        samples: dict[str, dict[str, dict[str, list[float]]]] = {}
        halted: dict[str, dict[str, list[bool]]] = {}
        shares: dict[str, dict[str, dict[str, list[Any]]]] = {f: {} for f in SHARE_FIELDS}
        for (c, s), keys in mc_keys.items():
            halted.setdefault(c, {})[s] = [stopped(k) for k in keys]
            for f in SHARE_FIELDS:
                shares[f].setdefault(c, {})[s] = [res(k).get(f) for k in keys]
            for m in (*RANK_METRICS, *CELL_METRICS[3:]):
                samples.setdefault(m, {}).setdefault(c, {})[s] = [metric(k, m) for k in keys]
            mc.setdefault(c, {})[s] = {
                m: ci95(samples[m][c][s]) for m in (*RANK_METRICS, *CELL_METRICS[3:])
            }
        # per replicate, each controller's scenario mean (None: a run failed); paired by
        # replicate, since every controller saw the same draws
        tables = {
            m: replicate_table(samples[m], ranked, opt.scenarios, halted) for m in RANK_METRICS
        }
        # the same with the figures of the runs that stopped early, as far as they ran: a
        # failure counts as at least as bad as the worst of these (results.worst_filled)
        as_run = {m: replicate_table(samples[m], ranked, opt.scenarios) for m in RANK_METRICS}
        bands = {
            m: {c: ci95([v for v in tables[m][c] if v is not None]) for c in ranked}
            for m in RANK_METRICS
        }
        block["monte_carlo"] = {
            "replicates": opt.seeds_for(st),
            "variations": _mc_description(),
            "table": mc,
            "rank": {
                m: rank(
                    {c: {s: {m: mc[c][s][m]["mean"]} for s in mc[c]} for c in mc},
                    ranked,
                    opt.scenarios,
                    m,
                )
                for m in RANK_METRICS
            },
            "rank_bands": bands,
            # every replicate's figures, per metric, controller and scenario (None: failed),
            # which runs failed or stopped before their route's end (counted as failures),
            # and their scenario means: anyone can recompute a verdict from these
            "samples": samples,
            "stopped": halted,
            "replicate_means": tables,
            # every replicate's shares of ticks at the envelope's limits and in the law's events
            "shares": shares,
        }
        # judged with the campaign's whole family of pairs in build_results
        block["pair_tests"] = {
            m: pair_tests(tables[m], PAPER_RANK.get(m, {}), as_run[m]) for m in RANK_METRICS
        }
        # controllers of one's own against each of the paper's four (their own family)
        challengers = [c for c in ranked if c not in PAPER_RANK[RANK_METRICS[0]]]
        if challengers:
            block["challenger_tests"] = {
                m: challenger_tests(tables[m], challengers, PAPER_RANK.get(m, {}), as_run[m])
                for m in RANK_METRICS
            }
        variants = {v: of for v, of in VARIANTS.items() if v in samples[RANK_METRICS[0]]}
        variants = {v: of for v, of in variants.items() if of in samples[RANK_METRICS[0]]}
        if variants:
            block["variants"] = {
                v: variant_effect(samples, v, of, opt.scenarios) for v, of in variants.items()
            }
    casc = {c: k for (s_, c), k in camp.cascaded.items() if s_ == st}
    if casc:
        block["cascaded"] = {c: _cascaded_cell(res(k)) for c, k in casc.items()}
    casc_mc = {c: keys for (s_, c), keys in camp.cascaded_mc.items() if s_ == st}
    if casc_mc:
        block["cascaded_mc"] = {
            "replicates": opt.cascade_seeds,
            "variations": {
                **_mc_description(),
                "fault_onset": f"sorted U{MC_CASCADE_WINDOW_S} s, each to the next onset, the "
                f"last for U{MC_CASCADE_LAST_S} s",
                "fault_amplitude": f"each fault x U{MC_CASCADE_FACTOR}",
            },
            "table": {
                c: {m: ci95([metric(k, m) for k in keys]) for m in (*RANK_METRICS, "rmse_pos_m")}
                for c, keys in casc_mc.items()
            },
            "draws": {
                c: [res(k).get("faults") for k in keys] for c, keys in list(casc_mc.items())[:1]
            },
            "shares": {
                f: {c: [res(k).get(f) for k in keys] for c, keys in casc_mc.items()}
                for f in SHARE_FIELDS
            },
        }
    block["limit_use"] = _limit_use(camp, runs, st)
    return block


def _limit_use(
    camp: Campaign, runs: Mapping[str, Mapping[str, Any]], st: str
) -> dict[str, dict[str, Any]]:
    """Per controller, the mean over its runs in setting ``st`` (the table's, their
    Monte-Carlo replicates, the cascaded runs) of each share of tracking ticks: at each
    limit of the envelope and in each of the law's own events; ``runs``: how many had them."""
    keys: dict[str, list[str]] = {}
    for (s_, c, _s), k in camp.table.items():
        if s_ == st:
            keys.setdefault(c, []).append(k)
    for (s_, c), k in camp.cascaded.items():
        if s_ == st:
            keys.setdefault(c, []).append(k)
    for group in (camp.monte_carlo, camp.cascaded_mc):
        for key, ks in group.items():
            if key[0] == st:
                keys.setdefault(key[1], []).extend(ks)
    out: dict[str, dict[str, Any]] = {}
    for c, ks in keys.items():
        results = [runs.get(k, {}).get("result") or {} for k in dict.fromkeys(ks)]
        with_shares = [r for r in results if r.get("rate_limit_share")]
        out[c] = {
            "runs": len(with_shares),
            # runs whose host stopped before the route's end (a safe stop: OFF_PATH, ...)
            "stopped": sum(1 for r in results if r.get("stop_reason") not in _FINISHED),
            **{f: mean_shares([r.get(f) for r in with_shares]) for f in SHARE_FIELDS},
            # the largest per-tick step of the estimate beyond odometry over these runs
            **{f: _largest([r.get(f) for r in results]) for f in ESTIMATE_STEP_FIELDS},
        }
    return out


#: The stop reasons of a run that was not stopped before its route's end (NONE: it ran to the
#: scenario's end without the route done, no safe stop; a run without figures has none).
_FINISHED = ("ROUTE_DONE", "NONE", None)

#: A run's largest per-tick estimate step beyond odometry (controller_stats, summary.json).
ESTIMATE_STEP_FIELDS = ("estimate_step_max_m", "estimate_step_max_rad")


def _largest(values: list[Any]) -> float | None:
    finite = [float(v) for v in values if isinstance(v, int | float) and math.isfinite(v)]
    return max(finite) if finite else None


def _cascaded_cell(r: Mapping[str, Any]) -> dict[str, Any]:
    cell = {m: r.get(m) for m in (*CELL_METRICS, *SHARE_FIELDS)}
    cell["windows"] = r.get("windows")
    cell["log"] = r.get("log")
    cell["stop_reason"] = r.get("stop_reason")
    return cell


def _mc_description() -> dict[str, str]:
    return {
        "seed": "every random process of the bench (localizer noise, fault draws)",
        "sensor_noise": f"localizer sigma_xy and sigma_heading x U{MC_NOISE_RANGE}",
        "fault_onset": f"every fault's onset + U(-{MC_ONSET_SHIFT_S}, {MC_ONSET_SHIFT_S}) s",
        "fault_amplitude": f"x U(1 - {MC_AMPLITUDE_SPREAD}, 1 + {MC_AMPLITUDE_SPREAD})",
        "initial_pose": f"along, left U(-{MC_OFFSET_M}, {MC_OFFSET_M}) m; heading U(+-3 deg)",
        "mass": f"chair mass and yaw inertia x U(1 - {MC_MASS_SPREAD}, 1 + {MC_MASS_SPREAD})",
    }


def _spectrum_method(camp: Campaign) -> dict[str, Any]:
    return {
        "metric": SPECTRUM_METRIC,
        "factors": list(SPECTRUM_FACTORS),
        "tolerance": SPECTRUM_TOLERANCE,
        "replicates": camp.options.spectrum_seeds,
        "faults": list(camp.options.spectrum_faults),
        "estimator": "kappa = mean_k((E(c-k) + E(c+k))/2 - E(c)) / E(c), c = paper amplitude",
    }


def _spectrum(camp: Campaign, runs: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """spectrum[controller][fault]: class, convexity, band and the evidence."""
    out: dict[str, Any] = {}
    for (c, fault), reps in camp.spectrum.items():
        stress_axis: list[float] = []
        responses: list[list[float]] = []
        kappas: list[float] = []
        evidence: list[dict[str, Any] | None] = []
        for grid in reps:
            row = []
            for f in SPECTRUM_FACTORS:
                r = runs.get(grid[f], {}).get("result") or {}
                v = r.get(SPECTRUM_METRIC)
                row.append(math.nan if v is None else float(v))
            responses.append(row)
        nominal = runs.get(reps[0][1.0], {}).get("result") or {}
        unit_stress = next((f["stress"] for f in nominal.get("faults", []) if f["stress"]), None)
        if unit_stress is not None:
            stress_axis = [f * unit_stress for f in SPECTRUM_FACTORS]
        for row in responses:
            if all(math.isfinite(v) for v in row):
                est = convexity(list(SPECTRUM_FACTORS), row)
                kappas.append(est["kappa"])
                evidence.append(est)
            else:
                evidence.append(None)
        cls = classify(kappas)
        out.setdefault(c, {})[fault] = {
            **cls,
            "stress": stress_axis,
            "stress_unit": "1" if fault == "slip" else "m",
            "response": responses,
            "estimates": evidence,
            "logs": [[res_log(runs, grid[f]) for f in SPECTRUM_FACTORS] for grid in reps],
        }
    return out


def res_log(runs: Mapping[str, Mapping[str, Any]], key: str) -> str | None:
    return (runs.get(key, {}).get("result") or {}).get("log")


def _exposure(camp: Campaign, runs: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for c, roles in camp.exposure.items():
        rep = runs.get(roles["repeated"], {}).get("result") or {}
        windows = rep.get("windows") or []
        delays = [
            f.get("detection_delay_s") for f in rep.get("fault_diagnosis", {}).get("faults", [])
        ]
        rows = []
        for k, w in enumerate(windows):
            single_key = roles["single"][k] if k < len(roles["single"]) else None
            if single_key is None:
                single = w
                single_delay = delays[k] if k < len(delays) else None
            else:
                sr = runs.get(single_key, {}).get("result") or {}
                single = (sr.get("windows") or [{}])[0]
                sf = sr.get("fault_diagnosis", {}).get("faults", [])
                single_delay = sf[0].get("detection_delay_s") if sf else None
            e_rep, e_single = w.get("rmse_pos_m"), single.get("rmse_pos_m")
            rows.append(
                {
                    "exposure": k + 1,
                    "onset_s": w.get("onset_s"),
                    "end_s": w.get("end_s"),
                    "rmse_pos_m": e_rep,
                    "max_pos_err_m": w.get("max_pos_err_m"),
                    "rmse_pos_m_first_time": e_single,
                    "gain_m": None if e_rep is None or e_single is None else e_single - e_rep,
                    "detection_delay_s": delays[k] if k < len(delays) else None,
                    "detection_delay_s_first_time": single_delay,
                }
            )
        out[c] = {"exposures": rows, "log": rep.get("log")}
    return out


def write_results(results: Mapping[str, Any], path: Path) -> None:
    """``results.json`` with sorted keys, so that equal campaigns give equal files."""
    path.write_text(json.dumps(jsonable(results), indent=1, sort_keys=True, allow_nan=False) + "\n")


def deterministic_part(results: Mapping[str, Any]) -> dict[str, Any]:
    """``results`` without its wall-clock ``timing`` section."""
    return {k: v for k, v in results.items() if k != "timing"}
