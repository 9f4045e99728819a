"""``report.md`` of an evaluation campaign: the paper's table with ours beside it, and the rest.

This module owns the text that compares the paper's published numbers
(:mod:`tools.evaluation.paper`) with ours: the table
laid out as in the paper (one block per error component, one row per controller, our value
next to the paper's in each cell), a plain statement of where the rankings agree, the further
per-cell metrics, and the Monte-Carlo, spectrum and exposure sections when the campaign has
them.  Input is ``results.json``'s content (``tools.evaluation.assemble``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from tools.evaluation.paper import PAPER_RANK, PAPER_TABLE
from tools.evaluation.results import spectrum_view

COMPONENTS = {"rmse_xe_m": "x_e RMSE", "rmse_ye_m": "y_e RMSE", "rmse_phie_rad": "φ_e RMSE"}
SCENARIO_TITLES = {
    "fault-free": "Fault-free",
    "bump-left": "Bump left",
    "bump-right": "Bump right",
    "flat-left": "Flat left",
    "flat-right": "Flat right",
}
FIGURE_TITLES = {
    "fig09_trajectories.png": "Fig. 9: trajectories against the reference (fault-free)",
    "fig10_antifragile_twist.png": "Fig. 10: ANTIFRAGILE velocities and accelerations",
    "fig11_antifragile_errors.png": "Fig. 11: ANTIFRAGILE x_e, y_e, φ_e",
    "fig12_baseline_faults.png": "Fig. 12: BASELINE under each fault",
    "fig13_cascaded_error.png": "Fig. 13: Euclidean error, cascaded faults",
    "fig01_spectrum.png": "Fig. 1, measured: the fragility-robustness-antifragility spectrum",
    "exposure.png": "Gain from exposure: repeated right flat tire",
    "montecarlo.png": "Monte-Carlo: mean, 95 % interval, worst case",
}


def _f(x: Any, digits: int = 4) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.{digits}f}"


def _p(p: float | None) -> str:
    """A p-value with two significant digits (``–`` when there is none)."""
    return "–" if p is None else f"{p:.2g}"


def _name(c: str) -> str:
    return c.upper()


def _ci(st: Mapping[str, Any] | None, scale: float = 1.0, digits: int = 4) -> str:
    ci = (st or {}).get("ci95")
    return f" [{_f(scale * ci[0], digits)}, {_f(scale * ci[1], digits)}]" if ci else ""


def paper_table_markdown(
    results: Mapping[str, Any], block: Mapping[str, Any] | None = None
) -> list[str]:
    """The paper's table, its layout; with Monte-Carlo replicates each cell is "mean [95 % CI]
    (paper)" of the replicates and the rank is on those means, else "nominal (paper)"; the
    reference rows (BASELINE, the variants) are not ranked.  ``block``: one fault setting's
    part of ``results`` (default: the primary)."""
    block = results if block is None else block
    scen = results["meta"]["scenarios"]
    ctrls = results["meta"]["controllers"]
    mc_block = block.get("monte_carlo") or {}
    mc = mc_block.get("table", {})
    verdicts = block.get("verdicts") or {}
    rank_of = mc_block.get("rank") if mc else block["rank"]
    head = "| Control system / fault type | " + " | ".join(SCENARIO_TITLES.get(s, s) for s in scen)
    lines = [
        head + " | Rank ours (paper) |",
        "|---" * (len(scen) + 2) + "|",
    ]
    for metric, title in COMPONENTS.items():
        lines.append(f"| ***{title}*** |" + " |" * (len(scen) + 1))
        ranks = (rank_of or {}).get(metric, {})
        for c in ctrls:
            cells = []
            for s in scen:
                st = mc.get(c, {}).get(s, {}).get(metric)
                if st is not None:  # the replicates' mean, never the nominal run, by its interval
                    ours, band = st.get("mean"), _ci(st)
                else:  # a row without replicates (BASELINE by default): its nominal run, said so
                    ours = block["table"].get(c, {}).get(s, {}).get(metric)
                    band = " nominal" if mc and ours is not None else ""
                paper = PAPER_TABLE.get(metric, {}).get(c, {}).get(s)
                cells.append(
                    f"{_f(ours)}{band} ({_f(paper)})" if paper is not None else _f(ours) + band
                )
            r = ranks.get(c, {}).get("rank")
            pr = PAPER_RANK.get(metric, {}).get(c)
            rank_cell = "reference" if r is None else f"{r} ({pr})" if pr else str(r)
            v = verdicts.get(metric, {}).get(c, {}).get("verdict")
            if v:
                rank_cell += f" **{v}**"
            lines.append(f"| {_name(c)} | " + " | ".join(cells) + f" | {rank_cell} |")
    return lines


def rank_statement(results: Mapping[str, Any], block: Mapping[str, Any] | None = None) -> list[str]:
    """Plain sentences: per component, where our rank agrees with the paper's and where not."""
    block = results if block is None else block
    out = []
    ranked = results["meta"]["ranked_controllers"]
    comparable = [c for c in ranked if c in PAPER_RANK["rmse_xe_m"]]
    full = set(results["meta"]["scenarios"]) == set(SCENARIO_TITLES) and len(comparable) == 4
    if not full:
        out.append(
            "The campaign does not cover the paper's four controllers on its five scenarios, so "
            "the ranks below are over a different set and are not comparable with the paper's."
        )
    agree_total = 0
    for metric, title in COMPONENTS.items():
        ours = block["rank"].get(metric, {})
        order = sorted(ours, key=lambda c: ours[c]["rank"])
        paper_order = sorted(comparable, key=lambda c: PAPER_RANK[metric][c])
        same = [c for c in comparable if ours.get(c, {}).get("rank") == PAPER_RANK[metric][c]]
        agree_total += len(same)
        ours_txt = " < ".join(_name(c) for c in order)
        paper_txt = " < ".join(_name(c) for c in paper_order)
        if order == paper_order:
            verdict = "**the same order as the paper**"
        else:
            diff = [
                f"{_name(c)} {ours[c]['rank']} (paper {PAPER_RANK[metric][c]})"
                for c in comparable
                if c in ours and ours[c]["rank"] != PAPER_RANK[metric][c]
            ]
            verdict = (
                f"agrees for {len(same)} of {len(comparable)} controllers; differs for "
                + ", ".join(diff)
            )
        out.append(f"* **{title}**: ours {ours_txt}; paper {paper_txt}: {verdict}.")
    if full:
        out.append(
            f"* Overall {agree_total} of {3 * len(comparable)} (controller, component) ranks agree."
        )
    return out


def verdict_lines(results: Mapping[str, Any], block: Mapping[str, Any]) -> list[str]:
    """The verdicts: one per pair of ranked controllers and component (paired t tests on the
    Monte-Carlo replicates, Holm over the campaign), then each controller's rank as their
    view (tools.evaluation.results)."""
    verdicts = block.get("verdicts")
    if not verdicts:
        return [
            "No Monte-Carlo replicates (--seeds 1): no noise band, so no rank is judged; "
            "run with --seeds N for the verdicts."
        ]
    mc = block.get("monte_carlo") or {}
    tests = block.get("pair_tests") or {}
    family = next((t.get("family") for m in tests.values() for t in m.values()), None)
    if family is None:
        return [
            f"{mc.get('replicates')} Monte-Carlo replicates besides the nominal run, but no "
            "verdict: the verdicts test the paper's ranks, pair by pair, and this campaign ran "
            "fewer than two of the paper's ranked controllers (ROBUST, ADAPTIVE, RESILIENT, "
            "ANTIFRAGILE); the table above compares every controller it ran."
        ]
    lines = [
        f"{mc.get('replicates')} Monte-Carlo replicates besides the nominal run, every "
        f"controller on the same draws ({results['meta'].get('verdict_definition', '')}; "
        f"{family} pairs in the family).",
        "",
        "| component | pair (paper's order) | mean difference [95 % CI] | failed runs | "
        "p (Holm) | verdict |",
        "|---|---|---|---|---|---|",
    ]
    count = {"borne out": 0, "refuted": 0, "undecided": 0}
    for metric, title in COMPONENTS.items():
        for t in (tests.get(metric) or {}).values():
            count[t["verdict"]] = count.get(t["verdict"], 0) + 1
            pair = f"{_name(t['better'])} < {_name(t['worse'])}"
            lines.append(f"| {title} | {pair} | {_pair_cells(t)} |")
    lines += [
        "",
        f"* Pairs: {count['borne out']} borne out, {count['refuted']} refuted, "
        f"{count['undecided']} undecided.",
        "",
        "| component | controller | paper rank | mean over scenarios [95 % CI] | failed | "
        "rank verdict |",
        "|---|---|---|---|---|---|",
    ]
    ranks = {"reproduced": 0, "contradicted": 0, "not resolved": 0}
    for metric, title in COMPONENTS.items():
        for c, v in (verdicts.get(metric) or {}).items():
            ranks[v["verdict"]] = ranks.get(v["verdict"], 0) + 1
            lines.append(
                f"| {title} | {_name(c)} | {v['paper_rank']} | {_f(v['mean'])}{_ci(v)} | "
                f"{v.get('failed', 0)} of {v.get('n')} | **{v['verdict']}** |"
            )
    lines += [
        "",
        f"* Ranks: {ranks['reproduced']} reproduced, {ranks['contradicted']} contradicted, "
        f"{ranks['not resolved']} not resolved (a refuted pair contradicts both of its ranks).",
    ]
    return lines


def _pair_cells(t: Mapping[str, Any]) -> str:
    """A judged pair's cells after its name: mean difference [95 % CI], failed runs, p (Holm),
    verdict."""
    ci = t.get("ci")
    band = f" [{_f(ci[0])}, {_f(ci[1])}]" if ci else ""
    failed = ", ".join(f"{_name(c)} {k}" for c, k in t["failed"].items() if k) or "none"
    verdict = t.get("verdict", "undecided")
    return f"{_f(t.get('mean'))}{band} | {failed} | {_p(t.get('p_holm'))} | **{verdict}**"


def challenger_lines(results: Mapping[str, Any], block: Mapping[str, Any]) -> list[str]:
    """Each controller of one's own against each of the paper's four: paired tests on the same
    replicates, Holm-adjusted in a family of their own (the paper's pairs keep theirs)."""
    tests = block.get("challenger_tests") or {}
    if not any(tests.values()):
        return []
    family = next((t.get("family") for m in tests.values() for t in m.values()), None)
    untuned = [
        c
        for c in {t["challenger"] for m in tests.values() for t in m.values()}
        if c not in (results["meta"].get("gains") or {})
    ]
    lines = [
        "### Controllers of your own against the paper's four",
        "",
        "Each pair: the challenger's scenario-averaged RMSE minus the other's, per replicate "
        "(the same draws), a two-sided paired t test, Holm-adjusted over the challengers' "
        f"{family} pairs of the campaign (a family of their own; the paper's pairs above keep "
        "theirs): *better* or *worse* where significant, *undecided* otherwise.",
    ]
    if untuned:
        lines += [
            "",
            f"{', '.join(_name(c) for c in sorted(untuned))} ran on its Params defaults: no "
            "tuned gains (`wheelchair-hil tune --controller NAME --space FILE`, "
            "docs/own-controller.md), while the paper's laws ran on tuned ones.",
        ]
    lines += [
        "",
        "| component | challenger - other | mean difference [95 % CI] | failed runs | "
        "p (Holm) | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for metric, title in COMPONENTS.items():
        for t in (tests.get(metric) or {}).values():
            pair = f"{_name(t['challenger'])} - {_name(t['other'])}"
            lines.append(f"| {title} | {pair} | {_pair_cells(t)} |")
    return [*lines, ""]


def variant_lines(block: Mapping[str, Any]) -> list[str]:
    """Each named variant against the controller it varies: the paired difference of every
    cell's figures over the Monte-Carlo replicates (tools.evaluation.verdicts.variant_effect)."""
    variants = block.get("variants") or {}
    lines: list[str] = []
    for v, eff in variants.items():
        of = eff["of"]
        lines += [
            f"### {_name(v)} against {_name(of)}",
            "",
            f"Per cell, the paired difference {_name(v)} − {_name(of)} over the Monte-Carlo "
            "replicates (the same draws for both; negative: the variant's error is smaller), "
            "its 95 % t interval and two-sided p (per cell, not corrected: one question "
            "asked of each).",
            "",
            "| scenario | component | mean difference [95 % CI] | p | failed runs |",
            "|---|---|---|---|---|",
        ]
        for s, row in eff["cells"].items():
            for metric, title in COMPONENTS.items():
                t = row.get(metric)
                if not t:
                    continue
                ci = t.get("ci")
                band = f" [{_f(ci[0])}, {_f(ci[1])}]" if ci else ""
                failed = ", ".join(f"{_name(c)} {k}" for c, k in t["failed"].items() if k)
                lines.append(
                    f"| {SCENARIO_TITLES.get(s, s)} | {title} | {_f(t.get('mean'))}{band} "
                    f"| {_p(t.get('p'))} | {failed or 'none'} |"
                )
        lines.append("")
    return lines


#: Column titles of the envelope's limits (controller.limits.RATE_LIMITS), in its order.
RATE_LIMIT_TITLES = {
    "accel": "accel",
    "turn_accel": "turn accel",
    "speed": "speed",
    "turn_rate": "turn rate",
    "jerk": "jerk",
}


def _pct(x: Any) -> str:
    return _f(None if x is None else 100.0 * x, 2)


def limit_use_lines(block: Mapping[str, Any]) -> list[str]:
    """Per controller, the mean share of its tracking ticks at each limit of the envelope and
    in each of its law's own events, over its runs in one fault setting (``limit_use``)."""
    use = block.get("limit_use") or {}
    if not any(u.get("runs") for u in use.values()):
        return []
    lines = [
        "### How each law met the envelope, and what it did",
        "",
        "Share of the tracking ticks (%), the mean over the controller's runs in this setting "
        "(the table's, their Monte-Carlo replicates, the cascaded runs); *stopped*: how many of "
        "them the host stopped before the route's end (a safe stop such as OFF_PATH).  The "
        "limit columns "
        "are measured alike for every law on the command it returns, before the node's "
        "limiter shapes it, against the one before (at rest before tracking), at or beyond "
        "the limit (within 0.1 %): *accel*, its speed changed at the acceleration limit "
        "(the deceleration limit when slowing); *turn accel*, its turn rate changed at the "
        "turn-acceleration limit; *speed*, at the forward or reverse speed limit; *turn "
        "rate*, at the turn-rate limit; *jerk*, its acceleration changed at the jerk limit.  "
        "*The law's own events* are each law's (its `activity()`): the share of its steps "
        "in which each happened, e.g. ROBUST's outside_boundary1/2 (a sliding surface outside "
        "its boundary layer: the switching acts), ANTIFRAGILE's regime_fragile, ADAPTIVE's "
        "qp_fallback (no solved QP: the previous plan, or braking), RESILIENT's rule_* (the "
        "rule with the largest weight).  *Estimate step*: the largest move of the pose "
        "estimate in one tick beyond what that tick's odometry moved it, over these runs "
        "(cm / mrad; the estimator's bound is 2 cm / 20 mrad, docs/planner.md).",
        "",
        "| controller | runs | stopped | "
        + " | ".join(RATE_LIMIT_TITLES.values())
        + " | estimate step (cm / mrad) | the law's own events |",
        "|---" * (5 + len(RATE_LIMIT_TITLES)) + "|",
    ]
    for c, u in use.items():
        rates = u.get("rate_limit_share") or {}
        acts = u.get("law_activity_share") or {}
        events = ", ".join(f"{k} {_pct(v)}" for k, v in acts.items()) or "–"
        step_m, step_rad = u.get("estimate_step_max_m"), u.get("estimate_step_max_rad")
        step = (
            "–"
            if step_m is None or step_rad is None
            else f"{100 * step_m:.1f} / {1000 * step_rad:.0f}"
        )
        lines.append(
            f"| {_name(c)} | {u.get('runs', 0)} | {u.get('stopped', 0)} | "
            + " | ".join(_pct(rates.get(k)) for k in RATE_LIMIT_TITLES)
            + f" | {step} | {events} |"
        )
    return [*lines, ""]


def _cell_rows(results: Mapping[str, Any]) -> list[str]:
    timing = results.get("timing", {}).get("table", {})
    lines = [
        "| controller | scenario | pos. RMSE (cm) | max error (cm) | max φ_e (deg) | effort (m²/s) "
        "| TV v (m/s) | TV ω (rad/s) | chattering (Hz) | comfort a_v (m/s²) | a_wx / a_wy (m/s²) "
        "| step p50 / p99 (µs) | stop |",
        "|---" * 13 + "|",
    ]
    for c, row in results["table"].items():
        for s, cell in row.items():
            t = (timing.get(c, {}) or {}).get(s) or {}
            lines.append(
                f"| {_name(c)} | {s} | {_f(_cm(cell.get('rmse_pos_m')), 2)} "
                f"| {_f(_cm(cell.get('max_pos_err_m')), 2)} | {_f(_deg(cell.get('max_phie_rad')), 2)} "
                f"| {_f(cell.get('control_effort'), 1)} | {_f(cell.get('tv_v'), 2)} "
                f"| {_f(cell.get('tv_omega'), 1)} | {_f(cell.get('chattering_hz'), 1)} "
                f"| {_f(cell.get('comfort_av_mps2'), 3)} "
                f"| {_f(cell.get('comfort_awx_mps2'), 3)} / {_f(cell.get('comfort_awy_mps2'), 3)} "
                f"| {_f(t.get('controller_step_us_p50'), 1)} / {_f(t.get('controller_step_us_p99'), 1)} "
                f"| {cell.get('stop_reason') or cell.get('error', '–')} |"
            )
    return lines


def _cm(x: Any) -> float | None:
    return None if x is None else 100.0 * x


def _deg(x: Any) -> float | None:
    return None if x is None else math.degrees(x)


def _cascaded(results: Mapping[str, Any], block: Mapping[str, Any] | None = None) -> list[str]:
    block = results if block is None else block
    casc = block.get("cascaded")
    if not casc:
        return []
    names = ["slip 10-28 s", "flat left 28-46 s", "bump right 46-62 s"]
    lines = [
        "### Cascaded faults, the fixed schedule of Fig. 13",
        "",
        "Position RMSE (cm) over the whole route (up to the run's end) and inside each "
        "fault's window; ended: the run's stop reason (ROUTE_DONE, or the safe stop that "
        "ended it first, e.g. OFF_PATH).",
        "",
        "| controller | whole route | " + " | ".join(names) + " | max error (cm) | ended |",
        "|---" * (4 + len(names)) + "|",
    ]
    for c, cell in casc.items():
        w = cell.get("windows") or []
        lines.append(
            f"| {_name(c)} | {_f(_cm(cell.get('rmse_pos_m')), 2)} | "
            + " | ".join(_f(_cm(x.get("rmse_pos_m")), 2) for x in w[: len(names)])
            + f" | {_f(_cm(cell.get('max_pos_err_m')), 2)} | "
            + f"{cell.get('stop_reason') or cell.get('error') or '–'} |"
        )
    lines.append("")
    cmc = block.get("cascaded_mc")
    if cmc:
        lines += [
            f"### Cascaded faults at random moments with random magnitudes "
            f"({cmc['replicates']} Monte-Carlo replicates)",
            "",
            "Each replicate draws: "
            + "; ".join(f"{k}: {v}" for k, v in cmc["variations"].items())
            + ".  Cells: mean [95 % CI of the mean].",
            "",
            "| controller | position RMSE (cm) | x_e RMSE (m) | y_e RMSE (m) | φ_e RMSE (rad) |",
            "|---|---|---|---|---|",
        ]
        for c, row in cmc["table"].items():
            pos = row.get("rmse_pos_m") or {}
            lines.append(
                f"| {_name(c)} | {_f(_cm(pos.get('mean')), 2)}{_ci(pos, 100.0, 2)} | "
                + " | ".join(
                    f"{_f((row.get(m) or {}).get('mean'))}{_ci(row.get(m))}" for m in COMPONENTS
                )
                + " |"
            )
        lines.append("")
    return lines


def _monte_carlo(results: Mapping[str, Any]) -> list[str]:
    mc = results.get("monte_carlo")
    if not mc:
        return []
    lines = [
        f"## Monte-Carlo ({mc['replicates']} replicates per cell)",
        "",
        "Each replicate draws: "
        + "; ".join(f"{k}: {v}" for k, v in mc["variations"].items())
        + ".",
        "Cells: mean [95 % confidence interval of the mean] worst, position RMSE in cm.",
        "",
        "| controller | " + " | ".join(results["meta"]["scenarios"]) + " |",
        "|---" * (1 + len(results["meta"]["scenarios"])) + "|",
    ]
    for c, row in mc["table"].items():
        cells = []
        for s in results["meta"]["scenarios"]:
            st = (row.get(s) or {}).get("rmse_pos_m") or {}
            ci = st.get("ci95")
            cells.append(
                f"{_f(_cm(st.get('mean')), 2)} [{_f(_cm(ci[0]), 2)}, {_f(_cm(ci[1]), 2)}] "
                f"{_f(_cm(st.get('worst')), 2)}"
                if ci
                else _f(_cm(st.get("mean")), 2)
            )
        lines.append(f"| {_name(c)} | " + " | ".join(cells) + " |")
    lines += ["", "Rank on the Monte-Carlo means:", ""]
    for metric, title in COMPONENTS.items():
        r = mc["rank"].get(metric, {})
        lines.append(
            f"* {title}: " + " < ".join(_name(c) for c in sorted(r, key=lambda c: r[c]["rank"]))
        )
    return [*lines, ""]


def spectrum_table(results: Mapping[str, Any]) -> list[str]:
    """Class per controller and fault, with the convexity and its band."""
    spec = spectrum_view(results)
    if not spec:
        return []
    ctrls = list(spec["controllers"])
    faults = list(next(iter(spec["controllers"].values())))
    lines = [
        "| controller | " + " | ".join(faults) + " |",
        "|---" * (1 + len(faults)) + "|",
    ]
    for c in ctrls:
        cells = []
        for f in faults:
            cell = spec["controllers"][c][f]
            band = cell.get("band")
            b = f" [{band[0]:+.2f}, {band[1]:+.2f}]" if band else ""
            k = cell.get("kappa")
            cells.append(f"**{cell['class']}** κ = {k:+.2f}{b}" if k is not None else "–")
        lines.append(f"| {_name(c)} | " + " | ".join(cells) + " |")
    return lines


def _spectrum(results: Mapping[str, Any]) -> list[str]:
    spec = spectrum_view(results)
    if not spec:
        return []
    lines = [
        "## The spectrum, measured",
        "",
        f"Each fault's amplitude swept over {spec['factors']} times the paper's; response: "
        f"position RMSE; {spec['replicates']} replicate(s) per point (nominal, then Monte-Carlo "
        "draws without the amplitude).  κ = H / E(a): Taleb and Douady's heuristic H, averaged "
        "over the symmetric pairs around the paper's amplitude a, relative to the error there; "
        f"fragile if the 95 % band of κ lies above +{spec['tolerance']}, antifragile below "
        f"-{spec['tolerance']}, robust otherwise (docs/evaluation.md).",
        "",
        *spectrum_table(results),
        "",
        "Position RMSE (cm) along the sweep (nominal replicate):",
        "",
    ]
    ctrls = list(spec["controllers"])
    faults = list(next(iter(spec["controllers"].values())))
    lines += ["| controller | fault | " + " | ".join(f"×{f:g}" for f in spec["factors"]) + " |"]
    lines += ["|---" * (2 + len(spec["factors"])) + "|"]
    for c in ctrls:
        for f in faults:
            row = spec["controllers"][c][f]["response"][0]
            lines.append(f"| {_name(c)} | {f} | " + " | ".join(_f(_cm(v), 2) for v in row) + " |")
    return [*lines, ""]


def exposure_table(results: Mapping[str, Any]) -> list[str]:
    exp = results.get("exposure")
    if not exp:
        return []
    lines = [
        "| controller | exposure | window (s) | RMSE repeated (cm) | RMSE first time (cm) "
        "| gain (cm) | detection delay repeated / first (s) |",
        "|---" * 7 + "|",
    ]
    for c, e in exp.items():
        for r in e["exposures"]:
            lines.append(
                f"| {_name(c)} | {r['exposure']} | {_f(r['onset_s'], 0)}-{_f(r['end_s'], 0)} "
                f"| {_f(_cm(r['rmse_pos_m']), 2)} | {_f(_cm(r['rmse_pos_m_first_time']), 2)} "
                f"| {_f(_cm(r['gain_m']), 2)} | {_f(r['detection_delay_s'], 1)} / "
                f"{_f(r['detection_delay_s_first_time'], 1)} |"
            )
    return lines


def _exposure(results: Mapping[str, Any]) -> list[str]:
    if not results.get("exposure"):
        return []
    return [
        "## Gain from exposure",
        "",
        "`repeated-exposure`: a right flat tire three times (12-24 s, 36-48 s, 60-72 s).  Each "
        "window's error is compared with the same window when that exposure is the first "
        "(a run with only that fault): gain = first-time RMSE - repeated RMSE, positive when "
        "the earlier exposures helped.  Exposure 1 is its own first time (gain 0).",
        "",
        *exposure_table(results),
        "",
    ]


def write_report(results: Mapping[str, Any], out_dir: Path, figures: Sequence[str]) -> Path:
    """Write ``out_dir/report.md``; returns its path."""
    meta = results["meta"]
    timing = results.get("timing", {})
    lines = [
        "# Evaluation: the paper's experiments through the CAN stack",
        "",
        f"{meta['runs']} lock-step runs (virtual bus, every frame through the DBC codec), "
        f"seed {meta['seed']}, {timing.get('executor', '')}: "
        f"{_f(timing.get('campaign_wall_s'), 0)} s for the runs "
        f"({_f(timing.get('sim_s'), 0)} s simulated: "
        f"{_f(timing.get('real_time_factor_per_worker'), 1)}x real time per worker), "
        f"{_f(timing.get('total_wall_s'), 0)} s in all.  Errors are the bench's ground truth "
        "against the reference (never the controller's estimate); RMSE over the route.",
        "",
    ]
    if meta.get("failed_runs"):
        lines += ["**Failed runs:** " + ", ".join(meta["failed_runs"]), ""]
    settings = results.get("settings") or {meta.get("setting", ""): results}
    labels = meta.get("setting_labels") or {}
    lines += [
        "Fault settings (docs/evaluation.md): "
        + "; ".join(labels.get(st, st) for st in settings)
        + ".  The paper's own is (a); (b) and (c) are reported beside it.",
        "",
    ]
    if meta.get("gains"):
        lines += [
            "Gains: tuned by `wheelchair-hil tune` (one optimiser, objective and budget for "
            "every controller, on scenarios disjoint from these); provenance:",
            "",
            "| controller | tuned | objective (start → tuned) | evaluations / runs | wall (s) "
            "| converged | date |",
            "|---|---|---|---|---|---|---|",
            *(
                f"| {_name(c)} | {', '.join(g.get('tuned', []))} "
                f"| {_f(g.get('objective_start'), 5)} → {_f(g.get('objective_value'), 5)} "
                f"| {g.get('evaluations')} / {g.get('runs')} | {_f(g.get('wall_s'), 0)} "
                f"| {g.get('converged')} | {g.get('date')} |"
                for c, g in meta["gains"].items()
            ),
            "",
        ]
    else:
        lines += ["Gains: controller/gains.toml as it is (no tuned gains file).", ""]
    for st, block in settings.items():
        lines += [
            f"## Fault setting {labels.get(st, st)}",
            "",
            "### The paper's table, ours next to the paper's",
            "",
            (
                "Each cell: ours, the mean of the Monte-Carlo replicates [its 95 % confidence "
                'interval] (paper); the nominal runs are under "Every cell" and in the '
                "rank statement below.  "
                if block.get("monte_carlo")
                else "Each cell: ours, the nominal run (paper).  "
            )
            + "Ours in metres and radians; the paper states no units, and "
            "its magnitudes under faults (metres of RMSE for a 1.5 cm bump) are not those of "
            "our bench, so compare orders, not values.  Rank: per component, the order of the "
            "average RMSE over the five columns (1 = best; docs/evaluation.md), then the "
            "verdict on the paper's rank; BASELINE and the named variants "
            "(ADAPTIVE-INTEGRAL) are reference rows, not ranked.",
            "",
            *paper_table_markdown(results, block),
            "",
            "### Where the rankings agree (nominal runs)",
            "",
            *rank_statement(results, block),
            "",
            "### The paper's ranks judged with noise",
            "",
            *verdict_lines(results, block),
            "",
            *challenger_lines(results, block),
            *variant_lines(block),
            *_cascaded(results, block),
            *limit_use_lines(block),
        ]
    lines += [
        f"## Every cell, fault setting {meta.get('setting_label', '')}",
        "",
        "Comfort: ISO 2631-1 Wd-weighted rms of the real chair's longitudinal (dv/dt) and "
        "lateral (v·ω) accelerations from the ground truth, vector value with k = 1.4.  "
        "Step: the controller's `step()` time measured in the run (wall clock, shared machine).",
        "",
        *_cell_rows(results),
        "",
        *_monte_carlo(results),
        *_spectrum(results),
        *_exposure(results),
    ]
    if figures:
        lines += ["## Figures", ""]
        for name in figures:
            lines += [f"### {FIGURE_TITLES.get(name, name)}", "", f"![{name}]({name})", ""]
    lines += [
        "## Logs",
        "",
        "Every run's MCAP log is `runs/<setting>/<scenario>/<variation>/<controller>/run.mcap` "
        "(a run that is the same experiment in two settings, e.g. a bump in (a) and (b), is "
        "made once, under the setting it is made in) "
        "(with its `summary.json` and the extracted `series.npz`); `results.json` names each.",
        "",
    ]
    path = out_dir / "report.md"
    path.write_text("\n".join(lines))
    return path


def console_summary(results: Mapping[str, Any], out_dir: Path) -> str:
    """A few lines for the terminal: ranks, failures, time, where the outputs are."""
    t = results.get("timing", {})
    lines = [
        f"evaluate: {results['meta']['runs']} runs in {_f(t.get('campaign_wall_s'), 1)} s "
        f"({_f(t.get('total_wall_s'), 1)} s with figures), {t.get('executor', '')}, "
        f"{_f(t.get('real_time_factor_per_worker'), 1)}x real time per worker",
    ]
    settings = results.get("settings") or {results["meta"].get("setting", ""): results}
    for st, block in settings.items():
        lines.append(f"  fault setting {st}:")
        for metric, title in COMPONENTS.items():
            r = block["rank"].get(metric, {})
            v = (block.get("verdicts") or {}).get(metric, {})
            lines.append(
                f"    rank {title}: "
                + " < ".join(_name(c) for c in sorted(r, key=lambda c: r[c]["rank"]))
                + (
                    "  (paper's rank: "
                    + ", ".join(f"{_name(c)} {x['verdict']}" for c, x in v.items())
                    + ")"
                    if v
                    else ""
                )
            )
    if results["meta"].get("failed_runs"):
        lines.append("  FAILED: " + ", ".join(results["meta"]["failed_runs"]))
    lines.append(f"  {out_dir / 'report.md'}, {out_dir / 'results.json'}")
    return "\n".join(lines)
