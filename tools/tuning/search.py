"""The search, the same for every controller: a scrambled Sobol design for x0, Nelder-Mead from
it, and widening where the best point touches an edge of its box (:class:`Method`).

1. **x0 stage**: a scrambled Sobol design of ``sobol_points`` points (fixed seed) over the
   boxes in log scale, evaluated as one batch (in parallel over the worker pool); its best
   point is x0.
2. **Nelder-Mead** (scipy, bounded) from x0 in ``ln(gain)`` coordinates within the boxes,
   ended by its own test (``xatol_ln``, ``fatol_m``) or by the budget.
3. **Widening**: if a gain of the best point lies within ``edge_fraction`` of its box's log
   width from an edge, that side of its box is moved out by ``widen_factor`` (never past the
   key's limit: its declared bound, or a tighter ``[NAME.limits]`` entry of the space file)
   and Nelder-Mead continues from the best point; until no gain is on an edge, every edge is
   at its limit, or the budget is spent.

The Sobol points count in the budget.  :func:`search` minimises any :data:`Evaluate` (the
runs on the stack, :class:`tools.tuning.objective.StackObjective`, or a stub in the tests and
:mod:`tools.tuning.sizing`).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize
from scipy.stats import qmc

from tools.tuning.space import Dim, Method, TuningError, gain, gains_table

#: Objective of a batch of points: each a table of gain overrides, values in order.
Evaluate = Callable[[Sequence[Mapping[str, Any]]], Sequence[float]]


class _BudgetSpentError(Exception):
    """Raised inside Nelder-Mead's objective when no evaluation is left."""


@dataclass
class Search:
    """What one tuning found and how (the material of the gains file's provenance)."""

    dims_start: list[Dim]
    dims: list[Dim]  # the boxes at the end (widened where an optimum touched an edge)
    history: list[dict[str, Any]]
    x0_index: int  # the Sobol stage's best point, in history
    best_index: int
    converged: bool
    message: str
    widenings: list[dict[str, Any]]
    rounds: int  # Nelder-Mead runs begun after a widening
    on_edge: dict[str, dict[str, Any]]


def check_budget(budget: int, m: Method, n: int, controller: str = "") -> None:
    """TuningError unless ``budget`` pays for the x0 stage and one simplex of ``n`` gains."""
    least = m.sobol_points + n + 1
    if budget < least:
        who = f" for {controller}" if controller else ""
        raise TuningError(
            f"--budget {budget}: at least {least} objective evaluations{who} (the x0 stage's "
            f"{m.sobol_points} points and one Nelder-Mead simplex of {n + 1})"
        )


def search(
    dims: Sequence[Dim],
    m: Method,
    budget: int,
    evaluate: Evaluate,
    *,
    progress: Callable[[str], None] | None = None,
) -> Search:
    """Minimise ``evaluate`` over the boxes ``dims`` by :class:`Method` within ``budget``
    objective evaluations (the Sobol points included)."""
    n = len(dims)
    check_budget(budget, m, n)
    dims = list(dims)
    dims_start = list(dims)
    history: list[dict[str, Any]] = []
    cache: dict[tuple[float, ...], float] = {}

    def key_of(z: np.ndarray) -> tuple[float, ...]:
        return tuple(gain(math.exp(float(x))) for x in z)

    def run_batch(zs: Sequence[np.ndarray], stage: str) -> list[float]:
        keys = [key_of(z) for z in zs]
        new = list(dict.fromkeys(k for k in keys if k not in cache))
        if len(history) + len(new) > budget:
            raise _BudgetSpentError
        if new:
            tables = [gains_table(dims, k) for k in new]
            values = [float(v) for v in evaluate(tables)]
            if len(values) != len(new):
                raise TuningError(f"the objective gave {len(values)} values for {len(new)}")
            for k, t, v in zip(new, tables, values, strict=True):
                v = v if math.isfinite(v) else math.inf
                cache[k] = v
                history.append(
                    {"evaluation": len(history), "stage": stage, "gains": t, "objective": v}
                )
                if progress:
                    progress(f"evaluation {len(history)}/{budget} ({stage}): objective {v:.5f}")
        return [cache[k] for k in keys]

    # 1. x0 stage: a scrambled Sobol design over the boxes, in log scale, one batch
    lo, hi = _ln_box(dims)
    unit = qmc.Sobol(n, scramble=True, rng=m.sobol_seed).random_base2(
        int(math.log2(m.sobol_points))
    )
    run_batch([lo + u * (hi - lo) for u in unit], "x0 stage")
    x0_index = _best(history)

    # 2. Nelder-Mead from x0, 3. widening where the best point touches an edge
    z = np.log(np.array(list(_values(dims, history[x0_index]["gains"]))))
    widened: dict[int, str] = {}
    widenings: list[dict[str, Any]] = []
    converged = False
    message = ""
    nm_round = 0
    while True:
        nm_round += 1
        lo, hi = _ln_box(dims)
        z = np.clip(z, lo, hi)  # a rounded gain may lie a hair outside its box
        stage = "Nelder-Mead" if nm_round == 1 else f"Nelder-Mead {nm_round}"

        def f(u: np.ndarray, lo: np.ndarray = lo, hi: np.ndarray = hi, stage: str = stage) -> float:
            return run_batch([np.clip(u, lo, hi)], stage)[0]

        simplex = _simplex(z, lo, hi, m.simplex_step, widened)
        try:
            res = optimize.minimize(
                f,
                z,
                method="Nelder-Mead",
                bounds=list(zip(lo, hi, strict=True)),
                options={
                    "initial_simplex": simplex,
                    "xatol": m.xatol_ln,
                    "fatol": m.fatol_m,
                    "maxfev": sys.maxsize,
                    "maxiter": sys.maxsize,
                },
            )
            converged = res.status == 0
            message = str(res.message)
        except _BudgetSpentError:
            converged = False
            message = f"the budget of {budget} objective evaluations was spent"
        best_index = _best(history)
        z = np.log(np.array(list(_values(dims, history[best_index]["gains"]))))
        edges = _edges(dims, z, m.edge_fraction)
        if not converged or not edges:
            break
        widened = {}
        for i, side in edges.items():
            d = dims[i]
            if d.at_limit(side):
                continue
            dims[i] = d.widened(side, m.widen_factor)
            widened[i] = side
            old, new = (d.lo, dims[i].lo) if side == "lo" else (d.hi, dims[i].hi)
            widenings.append({"key": d.key, "side": side, "from": old, "to": new})
            if progress:
                progress(f"{d.key} on its box's {side} edge: {side} {old:.6g} -> {new:.6g}")
        if not widened:
            break
    on_edge = {
        dims[i].key: {"side": side, "at_limit": dims[i].at_limit(side)}
        for i, side in _edges(dims, z, m.edge_fraction).items()
    }
    return Search(
        dims_start=dims_start,
        dims=dims,
        history=history,
        x0_index=x0_index,
        best_index=best_index,
        converged=converged,
        message=message,
        widenings=widenings,
        rounds=nm_round - 1,
        on_edge=on_edge,
    )


def _ln_box(dims: Sequence[Dim]) -> tuple[np.ndarray, np.ndarray]:
    return np.log([d.lo for d in dims]), np.log([d.hi for d in dims])


def _best(history: Sequence[Mapping[str, Any]]) -> int:
    """The index of the lowest objective (the earliest of equals)."""
    return min(range(len(history)), key=lambda i: (history[i]["objective"], i))


def _values(dims: Sequence[Dim], gains: Mapping[str, Any]) -> list[float]:
    out = []
    for d in dims:
        node: Any = gains
        for part in d.key.split("."):
            node = node[part]
        out.append(float(node))
    return out


def _simplex(
    z: np.ndarray, lo: np.ndarray, hi: np.ndarray, step: float, widened: Mapping[int, str]
) -> np.ndarray:
    """z and, along each axis, a step of ``step`` times the box's log width: towards the
    side just widened, else towards the side with more room; never out of the box."""
    rows = [z.copy()]
    for i in range(len(z)):
        room_up, room_down = hi[i] - z[i], z[i] - lo[i]
        side = widened.get(i, "hi" if room_up >= room_down else "lo")
        room = room_up if side == "hi" else room_down
        if room <= 0.0:  # a just-widened side the point cannot reach (cannot happen)
            side, room = ("lo", room_down) if side == "hi" else ("hi", room_up)
        s = min(step * (hi[i] - lo[i]), room)
        row = z.copy()
        row[i] += s if side == "hi" else -s
        rows.append(row)
    return np.array(rows)


def _edges(dims: Sequence[Dim], z: np.ndarray, fraction: float) -> dict[int, str]:
    """Index -> side ("lo"/"hi") of the gains within ``fraction`` of their box's log width
    from an edge."""
    out = {}
    lo, hi = _ln_box(dims)
    for i in range(len(dims)):
        tol = fraction * (hi[i] - lo[i])
        if z[i] >= hi[i] - tol:
            out[i] = "hi"
        elif z[i] <= lo[i] + tol:
            out[i] = "lo"
    return out
