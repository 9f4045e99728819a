"""The figures of a campaign's runs: the rank by mean error, confidence intervals, the
convexity of a stress response and its class, the mean shares of limits and events.

Pure functions of numbers, used by ``assemble.build_results`` and read back by the report
and the figures; the paired tests and their verdicts are :mod:`tools.evaluation.verdicts`.
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

    The band is the 95 % confidence interval of the mean ``kappa`` over replicates (with
    one replicate there is none, and the one value decides).  Fragile if the whole band lies
    above ``+tolerance``, antifragile if it lies below ``-tolerance``, robust if it lies
    within ``[-tolerance, +tolerance]`` (no curvature distinguishable from linear), *not
    resolved* if it straddles ``+tolerance`` or ``-tolerance`` (the noise cannot tell).
    """
    st = ci95(kappas)
    if st["mean"] is None:
        return {"class": None, "kappa": None, "band": None, "n": 0, "tolerance": tolerance}
    lo, hi = st["ci95"] if st["ci95"] is not None else (st["mean"], st["mean"])
    if lo > tolerance:
        cls = "fragile"
    elif hi < -tolerance:
        cls = "antifragile"
    elif -tolerance <= lo and hi <= tolerance:
        cls = "robust"
    else:
        cls = "not resolved"
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


def mean_shares(shares: Sequence[Mapping[str, Any] | None]) -> dict[str, float]:
    """Per name, the mean of the runs' shares (``rate_limit_share`` or ``law_activity_share``
    dicts; a run without one, or without a finite value for a name, leaves it out), in the
    order the names first appear."""
    sums: dict[str, float] = {}
    counts: dict[str, int] = {}
    for run in shares:
        for k, v in (run or {}).items():
            if isinstance(v, int | float) and math.isfinite(v):
                sums[k] = sums.get(k, 0.0) + float(v)
                counts[k] = counts.get(k, 0) + 1
            else:
                sums.setdefault(k, 0.0)
                counts.setdefault(k, 0)
    return {k: sums[k] / counts[k] if counts[k] else math.nan for k in sums}
