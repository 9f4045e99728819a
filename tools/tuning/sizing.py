"""How many objective evaluations the tuning method needs, on stubbed objectives (no runs).

``python -m tools.tuning.sizing [--seeds 0 1 2]`` runs :func:`tools.tuning.search.search` with
the space file's method on quadratic bowls in ``ln(gain)`` over each tunable controller's
boxes, and prints the evaluations each needed to converge (widening included): the figures
behind the default ``--budget`` (docs/evaluation.md "Tuning").

Each bowl: a random centre inside the boxes (three in eight with the first key beyond its
box's top, by e^0.8), a random rotation, curvatures 0.2-4 mm per ``ln(gain)^2`` on a 2 cm
floor, and with ``--ripple`` a deterministic ripple of that amplitude (m).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from tools.tuning.search import search
from tools.tuning.space import Dim, method, space, tunable

BOWLS_PER_CONTROLLER = 8


def bowl(dims: Sequence[Dim], rng: np.random.Generator, trial: int, ripple_m: float) -> Any:
    """A stub objective over ``dims`` (a batch of gains tables -> values)."""
    n = len(dims)
    lo, hi = np.log([d.lo for d in dims]), np.log([d.hi for d in dims])
    centre = lo + rng.uniform(0.1, 1.0, n) * (hi - lo)
    if trial % 3 == 0:
        centre[0] = hi[0] + 0.8
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    h = q @ np.diag(0.02 * 10 ** rng.uniform(-2.0, -0.7, n)) @ q.T

    def value(gains: Mapping[str, Any]) -> float:
        z = np.log([gains[d.key] for d in dims]) - centre
        return float(0.02 + z @ h @ z + ripple_m * math.sin(1e3 * float(np.sum(z))))

    return lambda batch: [value(g) for g in batch]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.tuning.sizing", description=__doc__)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--ripples-m", type=float, nargs="+", default=[0.0, 3e-5, 1e-4])
    args = ap.parse_args(argv)
    m = method()
    counts: list[int] = []
    unconverged = 0
    for seed, ripple in zip(args.seeds, args.ripples_m, strict=False):
        rng = np.random.default_rng(seed)
        for name in tunable():
            dims = space(name)
            for trial in range(BOWLS_PER_CONTROLLER):
                found = search(dims, m, 10_000, bowl(dims, rng, trial, ripple))
                counts.append(len(found.history))
                unconverged += not found.converged
    c = np.array(counts)
    print(
        f"{len(c)} bowls: evaluations to converge median {np.median(c):.0f}, "
        f"90th percentile {np.percentile(c, 90):.0f}, max {c.max()}; "
        f"not converged: {unconverged}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
