"""The paired tests of a campaign and their verdicts: per pair of controllers, the paired
differences over the Monte-Carlo replicates (a failed run counted as its replicate's worst),
Student's t interval and p-value; Holm's correction over the whole family; the verdict on
each pair and each of the paper's ranks; a named variant's effect.  Pure functions of
numbers, used by ``assemble.build_results`` (docs/evaluation.md states the method)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy import stats

from tools.evaluation.results import ci95

#: The three verdicts on one of the paper's ranks.
VERDICTS = ("reproduced", "contradicted", "not resolved")
#: The verdicts on one pair of controllers' order.
PAIR_VERDICTS = ("borne out", "refuted", "undecided")
#: The family-wise error rate of a campaign's verdicts (Holm over every pair it judges).
FAMILY_ALPHA = 0.05


def replicate_table(
    samples: Mapping[str, Mapping[str, Sequence[float]]],
    controllers: Sequence[str],
    scenarios: Sequence[str],
    stopped: Mapping[str, Mapping[str, Sequence[bool]]] | None = None,
) -> dict[str, list[float | None]]:
    """Per controller, per Monte-Carlo replicate: the mean of one metric over ``scenarios``,
    or None where a run of that replicate failed: a missing or non-finite value, or a run
    ``stopped[c][scenario][r]`` marks (a safe stop before the route's end).

    ``samples[c][scenario][r]`` is replicate ``r``'s value; every controller sees the same
    draws in replicate ``r`` (common random numbers), so the rows pair up.
    """
    n = min((len(samples.get(c, {}).get(s, ())) for c in controllers for s in scenarios), default=0)
    out: dict[str, list[float | None]] = {}
    for c in controllers:
        row: list[float | None] = []
        for r in range(n):
            vals = [samples[c][s][r] for s in scenarios]
            halted = stopped is not None and any(stopped[c][s][r] for s in scenarios)
            ok = not halted and all(v is not None and math.isfinite(v) for v in vals)
            row.append(float(sum(vals)) / len(vals) if ok else None)
        out[c] = row
    return out


def worst_filled(
    table: Mapping[str, Sequence[float | None]],
    as_run: Mapping[str, Sequence[float | None]] | None = None,
) -> dict[str, list[float]]:
    """``table`` with each failed run counted as the worst result of its replicate.

    A failed run (None) takes the largest (worst) value reached in that replicate: by any
    controller that finished it, and by any that failed it, as far as it ran (``as_run``:
    the same table with the figures of the runs that stopped early, None where there are
    none; its own figure included).  So it ranks last there, tied at most with another
    failure, or with the worst finished run where every failure's own figure is smaller;
    where every controller failed without a figure, all tie.  A controller that fails is
    never favoured, and the pairing by replicate is kept.
    """
    n = min((len(v) for v in table.values()), default=0)
    own = as_run or {}
    worst: list[float] = []
    for r in range(n):
        done = [float(x) for v in table.values() if (x := v[r]) is not None]
        done += [float(x) for v in own.values() if (x := v[r]) is not None and math.isfinite(x)]
        worst.append(max(done) if done else 0.0)
    out: dict[str, list[float]] = {}
    for c, v in table.items():
        out[c] = [worst[r] if (x := v[r]) is None else float(x) for r in range(n)]
    return out


def paired_t(diffs: Sequence[float], level: float = 0.95) -> dict[str, Any]:
    """Mean of paired differences, its two-sided ``level`` Student-t interval (n - 1 degrees
    of freedom), the t statistic and the two-sided p-value of "mean difference = 0"."""
    d = np.asarray(diffs, dtype=float)
    n = int(d.size)
    if n < 2:
        return {"n": n, "mean": float(d.mean()) if n else None, "ci": None, "t": None, "p": None}
    mean = float(d.mean())
    sd = float(d.std(ddof=1))
    if sd == 0.0:  # identical differences: certain unless they are all zero
        p = 1.0 if mean == 0.0 else 0.0
        return {"n": n, "mean": mean, "ci": [mean, mean], "t": None, "p": p}
    se = sd / math.sqrt(n)
    t = mean / se
    half = float(stats.t.ppf(0.5 + level / 2, n - 1)) * se
    p = float(2.0 * stats.t.sf(abs(t), n - 1))
    return {"n": n, "mean": mean, "ci": [mean - half, mean + half], "t": t, "p": p}


def holm(pvalues: Mapping[Any, float | None]) -> dict[Any, float | None]:
    """Holm-Bonferroni adjusted p-values (a test with no p-value stays None)."""
    tested = sorted((p, k) for k, p in pvalues.items() if p is not None)
    m = len(tested)
    out: dict[Any, float | None] = {k: None for k in pvalues}
    running = 0.0
    for i, (p, k) in enumerate(tested):
        running = max(running, min(1.0, (m - i) * p))
        out[k] = running
    return out


def pair_tests(
    table: Mapping[str, Sequence[float | None]],
    paper_rank: Mapping[str, int],
    as_run: Mapping[str, Sequence[float | None]] | None = None,
) -> dict[str, dict[str, Any]]:
    """One paired test per pair of ranked controllers, keyed ``"c|d"`` with ``c`` the one the
    paper ranks better: the differences ``c - d`` per replicate (failed runs counted as the
    replicate's worst, :func:`worst_filled` with ``as_run``), their mean, 95 % t interval and
    raw p-value.  :func:`judge_pairs` turns them into verdicts once the campaign's whole
    family is known."""
    ranked = sorted((c for c in paper_rank if c in table), key=lambda c: paper_rank[c])
    own = {c: as_run[c] for c in ranked if c in as_run} if as_run else None
    filled = worst_filled({c: table[c] for c in ranked}, own)
    out: dict[str, dict[str, Any]] = {}
    for i, c in enumerate(ranked):
        for d in ranked[i + 1 :]:
            out[f"{c}|{d}"] = {
                "better": c,
                "worse": d,
                "claim": f"{c} < {d}",
                **_paired(table, filled, c, d),
            }
    return out


def _paired(
    table: Mapping[str, Sequence[float | None]],
    filled: Mapping[str, Sequence[float]],
    c: str,
    d: str,
) -> dict[str, Any]:
    """The paired test of ``c - d`` over the replicates (``filled``: failures as the worst):
    each side's failed runs, the differences, their mean, 95 % t interval and raw p-value."""
    diffs = [a - b for a, b in zip(filled[c], filled[d], strict=True)]
    return {
        "failed": {c: sum(v is None for v in table[c]), d: sum(v is None for v in table[d])},
        "diffs": diffs,
        **{k: v for k, v in paired_t(diffs).items() if k != "n"},
        "n": len(diffs),
    }


def challenger_tests(
    table: Mapping[str, Sequence[float | None]],
    challengers: Sequence[str],
    paper_rank: Mapping[str, int],
    as_run: Mapping[str, Sequence[float | None]] | None = None,
) -> dict[str, dict[str, Any]]:
    """One paired test per challenger (a controller the paper does not rank: one of one's own)
    and each of the paper's ranked controllers, keyed ``"challenger|other"``: the differences
    ``challenger - other`` per replicate (failed runs counted as the replicate's worst among
    these, :func:`worst_filled`), their mean, 95 % t interval and raw p-value, two-sided (the
    paper claims no order for it).  :func:`judge_challengers` gives the verdicts, in a family
    of their own: the paper's 54-pair family stays as it is."""
    ranked = sorted((c for c in paper_rank if c in table), key=lambda c: paper_rank[c])
    names = [c for c in challengers if c in table] + ranked
    own = {c: as_run[c] for c in names if c in as_run} if as_run else None
    filled = worst_filled({c: table[c] for c in names}, own)
    out: dict[str, dict[str, Any]] = {}
    for ch in (c for c in challengers if c in table):
        for d in ranked:
            out[f"{ch}|{d}"] = {"challenger": ch, "other": d, **_paired(table, filled, ch, d)}
    return out


def judge_challengers(tests: Mapping[Any, dict[str, Any]], alpha: float = FAMILY_ALPHA) -> None:
    """Holm-adjust the challengers' tests (their own family) and give each its verdict in
    place: *better* or *worse* than the paper's controller (adjusted p < ``alpha``, by the
    sign of the mean difference: lower RMSE is better), *undecided* otherwise."""
    _judge(tests, alpha, below="better", above="worse")


def judge_pairs(tests: Mapping[Any, dict[str, Any]], alpha: float = FAMILY_ALPHA) -> None:
    """Holm-adjust the p-values of every test in ``tests`` (one family) and give each its
    verdict in place: *borne out* (adjusted p < ``alpha``, mean difference below 0: the
    paper's order), *refuted* (adjusted p < ``alpha``, above 0), *undecided* otherwise."""
    _judge(tests, alpha, below="borne out", above="refuted")


def _judge(tests: Mapping[Any, dict[str, Any]], alpha: float, *, below: str, above: str) -> None:
    """Holm over ``tests`` (one family), in place: ``p_holm``, ``family`` and the verdict,
    ``below`` or ``above`` by the sign of a significant mean difference, else undecided."""
    adjusted = holm({k: t.get("p") for k, t in tests.items()})
    family = len([v for v in adjusted.values() if v is not None])
    for k, t in tests.items():
        p = adjusted[k]
        t["p_holm"] = p
        t["family"] = family
        if p is None or p >= alpha or not t.get("mean"):
            t["verdict"] = "undecided"
        else:
            t["verdict"] = below if t["mean"] < 0 else above


def rank_verdicts(
    tests: Mapping[str, Mapping[str, Any]],
    table: Mapping[str, Sequence[float | None]],
    paper_rank: Mapping[str, int],
) -> dict[str, dict[str, Any]]:
    """Each ranked controller's verdict from its judged pairs (:func:`judge_pairs`).

    The paper's rank of ``c`` claims an order against every other ranked controller;
    ``c``'s rank is *reproduced* if every one of its pairs is borne out, *contradicted* if
    any is refuted, *not resolved* otherwise.  A refuted pair thus touches both ranks: the
    campaign counts pairs (:func:`count_pairs`) as its verdicts, ranks only as a view.
    ``mean``/``ci95`` are the controller's scenario-averaged metric over its finished
    replicates; ``failed`` counts the others.
    """
    ranked = [c for c in paper_rank if c in table]
    out: dict[str, dict[str, Any]] = {}
    for c in ranked:
        pairs: dict[str, str] = {}
        for t in tests.values():
            if c in (t["better"], t["worse"]):
                other = t["worse"] if c == t["better"] else t["better"]
                pairs[other] = str(t.get("verdict", "undecided"))
        if any(v == "refuted" for v in pairs.values()):
            verdict = "contradicted"
        elif pairs and all(v == "borne out" for v in pairs.values()):
            verdict = "reproduced"
        else:
            verdict = "not resolved"
        band = ci95([v for v in table[c] if v is not None])
        out[c] = {
            "paper_rank": paper_rank[c],
            "mean": band["mean"],
            "ci95": band["ci95"],
            "n": len(table[c]),
            "failed": sum(v is None for v in table[c]),
            "verdict": verdict,
            "pairs": pairs,
        }
    return out


def count_pairs(tests: Mapping[str, Mapping[str, Any]]) -> dict[str, int]:
    """How many pairs are borne out, refuted and undecided."""
    count = dict.fromkeys(PAIR_VERDICTS, 0)
    for t in tests.values():
        count[str(t.get("verdict", "undecided"))] += 1
    return count


def variant_effect(
    samples: Mapping[str, Mapping[str, Mapping[str, Sequence[float | None]]]],
    variant: str,
    of: str,
    scenarios: Sequence[str],
) -> dict[str, Any]:
    """What a named variant changes against the controller it varies, cell by cell.

    ``samples[metric][controller][scenario]`` holds each Monte-Carlo replicate's figure; the
    variant and its controller saw the same draws in replicate ``r``, so per cell and metric
    the differences ``variant - of`` are paired (:func:`paired_t`; a failed run counts as the
    worse of the two in its replicate, :func:`worst_filled`).  A negative mean: the variant's
    error is smaller.  Not part of the paper's verdicts (no multiplicity correction: one
    question, stated per cell).
    """
    cells: dict[str, dict[str, Any]] = {}
    for s in scenarios:
        row: dict[str, Any] = {}
        for m, by_ctl in samples.items():
            a, b = by_ctl.get(variant, {}).get(s), by_ctl.get(of, {}).get(s)
            if a is None or b is None:
                continue
            nan_free = {
                k: [None if x is None or not math.isfinite(x) else float(x) for x in v]
                for k, v in ((variant, a), (of, b))
            }
            filled = worst_filled(nan_free)
            diffs = [x - y for x, y in zip(filled[variant], filled[of], strict=True)]
            row[m] = {
                **paired_t(diffs),
                "failed": {k: sum(x is None for x in v) for k, v in nan_free.items()},
            }
        if row:
            cells[s] = row
    return {"of": of, "difference": f"{variant} - {of}", "cells": cells}
