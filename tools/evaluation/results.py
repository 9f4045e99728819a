"""What a campaign's runs add up to: the paper's rank, confidence intervals, convexity classes.

A leaf: pure functions of numbers, used by the campaign (``build_results``), the report and the
figures alike.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy import stats

from tools.evaluation.plan import SPECTRUM_TOLERANCE


def rank(
    table: Mapping[str, Mapping[str, Mapping[str, Any]]],
    controllers: Sequence[str],
    scenarios: Sequence[str],
    metric: str,
) -> dict[str, dict[str, Any]]:
    """The paper's rank of ``controllers`` on ``metric``: the order of their average RMSE.

    Our reading of the table's caption ("rank as the ordered average RMSE in faulty and
    fault-free operation", one rank per error component): average the component's RMSE
    over the scenarios (fault-free and the four faults, equally weighted), then number
    the controllers 1, 2, ... from the lowest average.  Ties (and a missing value, which
    ranks last) are broken by name so that the rank is deterministic.
    """
    means: dict[str, float] = {}
    for c in controllers:
        vals = [table.get(c, {}).get(s, {}).get(metric) for s in scenarios]
        ok = [float(v) for v in vals if v is not None and math.isfinite(float(v))]
        means[c] = sum(ok) / len(ok) if ok and len(ok) == len(vals) else math.inf
    order = sorted(controllers, key=lambda c: (means[c], c))
    return {
        c: {"mean": means[c] if math.isfinite(means[c]) else None, "rank": i + 1}
        for i, c in enumerate(order)
    }


def ci95(values: Sequence[float]) -> dict[str, Any]:
    """Mean, two-sided 95 % confidence interval of the mean (Student t), worst (max), n."""
    x = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    n = int(x.size)
    if n == 0:
        return {"n": 0, "mean": None, "ci95": None, "worst": None, "std": None}
    mean = float(np.mean(x))
    if n < 2:
        return {"n": 1, "mean": mean, "ci95": None, "worst": float(x.max()), "std": None}
    sd = float(np.std(x, ddof=1))
    half = float(stats.t.ppf(0.975, n - 1)) * sd / math.sqrt(n)
    return {
        "n": n,
        "mean": mean,
        "ci95": [mean - half, mean + half],
        "worst": float(x.max()),
        "std": sd,
    }


def convexity(stress: Sequence[float], response: Sequence[float]) -> dict[str, Any]:
    """Taleb and Douady's fragility heuristic on a uniform, odd-sized stress grid.

    With ``E`` the response (here an error: harm) at the grid's centre ``c`` (the paper's
    amplitude) and ``Delta_k = k h``, ``k = 1..c``::

        H = mean_k ( (E(c - k) + E(c + k)) / 2 - E(c) )     (metres, like E)
        kappa = H / E(c)                                      (dimensionless)

    ``H > 0``: the error at the paper's amplitude lies below the chords through the
    symmetric points, i.e. the error grows faster than linearly with the stress (convex
    harm: fragile); ``H < 0``: it grows slower (concave harm: antifragile in Taleb's
    sense); linear or flat responses give 0.  Also returned: the local second differences
    ``E[i-1] - 2 E[i] + E[i+1]`` (the evidence plotted) and the least-squares slope.
    """
    s = np.asarray(stress, dtype=float)
    e = np.asarray(response, dtype=float)
    if s.shape != e.shape or s.ndim != 1 or s.size < 3 or s.size % 2 == 0:
        raise ValueError(f"need an odd number (>= 3) of stress points, got {s.size} and {e.size}")
    h = np.diff(s)
    if not np.all(h > 0) or not np.allclose(h, h[0], rtol=1e-6, atol=1e-12):
        raise ValueError(f"the stress grid must be increasing and uniform, got {s.tolist()}")
    c = s.size // 2
    terms = [0.5 * (e[c - k] + e[c + k]) - e[c] for k in range(1, c + 1)]
    big_h = float(np.mean(terms))
    kappa = big_h / float(e[c]) if e[c] > 0 and math.isfinite(e[c]) else math.nan
    second = (e[:-2] - 2.0 * e[1:-1] + e[2:]).tolist()
    slope = float(np.polyfit(s, e, 1)[0]) if np.all(np.isfinite(e)) else math.nan
    return {"H": big_h, "kappa": kappa, "second_differences": second, "slope": slope}


def classify(kappas: Sequence[float], tolerance: float = SPECTRUM_TOLERANCE) -> dict[str, Any]:
    """Class from the convexity of each replicate: fragile, robust or antifragile.

    The band is the 95 % confidence interval of the mean ``kappa`` over replicates (none
    with one replicate).  Fragile if the whole band lies above ``+tolerance``, antifragile
    if it lies below ``-tolerance``, robust otherwise (no curvature distinguishable from
    linear within the tolerance and the noise).
    """
    st = ci95(kappas)
    if st["mean"] is None:
        return {"class": None, "kappa": None, "band": None, "n": 0, "tolerance": tolerance}
    lo, hi = st["ci95"] if st["ci95"] is not None else (st["mean"], st["mean"])
    if lo > tolerance:
        cls = "fragile"
    elif hi < -tolerance:
        cls = "antifragile"
    else:
        cls = "robust"
    return {
        "class": cls,
        "kappa": st["mean"],
        "band": st["ci95"],
        "n": st["n"],
        "tolerance": tolerance,
    }


def spectrum_view(results: Mapping[str, Any]) -> dict[str, Any] | None:
    """The spectrum with its method in one dict (``controllers``, ``factors``, ``tolerance``,
    ``replicates``, ``metric``), or None if the campaign has none."""
    if not results.get("spectrum"):
        return None
    return {**results["meta"]["spectrum"], "controllers": results["spectrum"]}


def replicate_means(
    samples: Mapping[str, Sequence[float]], scenarios: Sequence[str]
) -> list[float]:
    """Per Monte-Carlo replicate, the mean over ``scenarios`` of one controller's metric.

    ``samples[scenario][r]`` is replicate ``r``'s value (the same draws in every scenario:
    common random numbers); a replicate with a missing value in any scenario is left out,
    as :func:`rank` ranks a controller with a missing cell last.
    """
    n = min((len(samples.get(s, ())) for s in scenarios), default=0)
    out = []
    for r in range(n):
        vals = [samples[s][r] for s in scenarios]
        if all(v is not None and math.isfinite(v) for v in vals):
            out.append(float(sum(vals)) / len(vals))
    return out


#: The three verdicts on one of the paper's ranks.
VERDICTS = ("reproduced", "contradicted", "not resolved")


def rank_verdicts(
    bands: Mapping[str, Mapping[str, Any]], paper_rank: Mapping[str, int]
) -> dict[str, dict[str, Any]]:
    """Whether the noise bands bear out the paper's rank of each controller.

    ``bands[c]`` is :func:`ci95` of controller ``c``'s scenario-averaged metric over the
    Monte-Carlo replicates.  The paper's rank of ``c`` claims, for every other ranked
    controller ``d``, that ``c`` is better (lower) or worse.  A claim is *borne out* when
    the two 95 % intervals are separated in the claimed order and *refuted* when they are
    separated in the other order; with overlapping intervals (or none) it is undecided.
    ``c``'s rank is *reproduced* if every claim is borne out, *contradicted* if any is
    refuted, *not resolved* otherwise.  Only controllers in both mappings take part.
    """
    ranked = [c for c in paper_rank if c in bands]
    out: dict[str, dict[str, Any]] = {}
    for c in ranked:
        pairs: dict[str, str] = {}
        for d in ranked:
            if d == c:
                continue
            ci_c, ci_d = bands[c].get("ci95"), bands[d].get("ci95")
            if not ci_c or not ci_d:
                pairs[d] = "undecided"
                continue
            below, above = ci_c[1] < ci_d[0], ci_c[0] > ci_d[1]
            claim_better = paper_rank[c] < paper_rank[d]
            borne, refuted = (below, above) if claim_better else (above, below)
            pairs[d] = "borne out" if borne else ("refuted" if refuted else "undecided")
        if any(v == "refuted" for v in pairs.values()):
            verdict = "contradicted"
        elif pairs and all(v == "borne out" for v in pairs.values()):
            verdict = "reproduced"
        else:
            verdict = "not resolved"
        out[c] = {
            "paper_rank": paper_rank[c],
            "mean": bands[c].get("mean"),
            "ci95": bands[c].get("ci95"),
            "n": bands[c].get("n"),
            "verdict": verdict,
            "pairs": pairs,
        }
    return out
