"""A tuning's provenance, as the tuned gains file records it (:data:`tools.tuning.gainsfile.
PROVENANCE_KEYS`): the method in one line, the objective, the budget and what was spent, the x0
stage, Nelder-Mead, the widenings, the boxes and the gains left on an edge."""

from __future__ import annotations

import datetime
from collections.abc import Sequence
from typing import Any

import numpy as np

from tools.tuning.objective import OBJECTIVE, conditions_of
from tools.tuning.search import Search
from tools.tuning.space import Method


def optimiser_text(m: Method) -> str:
    """The method in one line, as the gains file records it."""
    return (
        f"scrambled Sobol design of {m.sobol_points} points (seed {m.sobol_seed}) over the "
        "boxes in log scale, its best point x0; scipy.optimize.minimize(method='Nelder-Mead', "
        f"bounded) from x0 in ln(gain) coordinates, xatol = {m.xatol_ln:g} (ln), fatol = "
        f"{m.fatol_m:g} m, initial simplex step {m.simplex_step:g} of each box's log width; "
        f"a gain within {m.edge_fraction:g} of its box's log width from an edge: that side "
        f"x {m.widen_factor:g} (up to its limit), Nelder-Mead again from the best point"
    )


def provenance_of(
    s: Search,
    m: Method,
    *,
    budget: int,
    scenarios: Sequence[str],
    wall_s: float,
) -> dict[str, Any]:
    """The gains file's provenance of search ``s`` (:data:`gainsfile.PROVENANCE_KEYS`)."""
    x0 = s.history[s.x0_index]
    stage = [h["objective"] for h in s.history if h["stage"] == "x0 stage"]
    return {
        "date": datetime.datetime.now(datetime.UTC).replace(microsecond=0).isoformat(),
        "optimiser": optimiser_text(m),
        "objective": OBJECTIVE,
        "objective_value": float(s.history[s.best_index]["objective"]),
        "objective_start": float(x0["objective"]),
        "budget_evaluations": budget,
        "evaluations": len(s.history),
        "runs": len(s.history) * sum(len(conditions_of(sc)) for sc in scenarios),
        "wall_s": round(wall_s, 1),
        "converged": s.converged,
        "message": s.message,
        "scenarios": list(scenarios),
        "tuned": [d.key for d in s.dims],
        "x0_stage": {
            "design": "scipy.stats.qmc.Sobol(d, scramble=True, rng=seed).random_base2(m)",
            "points": m.sobol_points,
            "seed": m.sobol_seed,
            "objective_best": float(x0["objective"]),
            "objective_median": float(np.median(stage)),
            "x0": x0["gains"],
        },
        "nelder_mead": {
            "xatol_ln": m.xatol_ln,
            "fatol_m": m.fatol_m,
            "simplex_step": m.simplex_step,
        },
        "widening": {
            "edge_fraction": m.edge_fraction,
            "factor": m.widen_factor,
            "rounds": s.rounds,
        },
        "box_start": {d.key: [d.lo, d.hi] for d in s.dims_start},
        "box": {d.key: [d.lo, d.hi] for d in s.dims},
        "box_limit": {d.key: [d.limit_lo, d.limit_hi] for d in s.dims},
        "on_edge": s.on_edge,
    }
