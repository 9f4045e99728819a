"""``wheelchair-hil tune --controller NAME``'s tuning: the same for every controller.

One method (:mod:`tools.tuning.search`), one objective (:mod:`tools.tuning.objective`) and
one budget of objective evaluations, whatever the controller, over the boxes the search space
file declares (:mod:`tools.tuning.space`).  :func:`tune` runs it for one controller and writes
the result into the tuned gains file (:mod:`tools.tuning.gainsfile`) with its provenance
(:mod:`tools.tuning.provenance`); ``wheelchair-hil evaluate`` applies it.  The command itself
is tools/cli/tune.py.
"""

from __future__ import annotations

import logging
import multiprocessing
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import Executor, ProcessPoolExecutor
from pathlib import Path
from typing import Any

from controller.tracking import registry
from dbc.runtime import jsonsafe
from tools.run import scenario as scenario_mod
from tools.tuning import gainsfile
from tools.tuning.objective import StackObjective, tuning_scenarios
from tools.tuning.provenance import provenance_of
from tools.tuning.search import Evaluate, check_budget, search
from tools.tuning.space import SPACE_FILE, TUNING_DIR, TuningError, method, space

log = logging.getLogger(__name__)

GAINS_FILE = TUNING_DIR / "gains.toml"


def tune(
    controller: str,
    *,
    budget: int,
    workers: int = 1,
    out: Path | None = None,
    gains_file: Path | None = GAINS_FILE,
    progress: Callable[[str], None] | None = None,
    objective: Evaluate | None = None,
    space_file: Path = SPACE_FILE,
) -> dict[str, Any]:
    """Tune ``controller``; write its entry into ``gains_file`` (None: write nothing) and
    return the result (gains, provenance, history).  ``objective`` replaces the runs on the
    stack (:class:`StackObjective`) by another evaluation of a batch of points."""
    controller = registry.canonical(controller)
    dims = space(controller, path=space_file)
    m = method(path=space_file)
    scenarios = tuning_scenarios()
    if not scenarios:
        raise TuningError(f"no tuning scenarios (tune-*.toml) in {TUNING_DIR}")
    for sc in scenarios:
        scenario_mod.load(str(sc))  # ConfigError naming the file, before any run
    check_budget(budget, m, len(dims), controller)
    keep = out is not None  # the runs' logs are kept only where the caller asked
    work = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="wheelchair-tune-"))
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    pool: Executor | None = None
    if objective is None and workers > 1:
        ctx = multiprocessing.get_context("spawn")
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx)
    say = (lambda msg: progress(f"tune {controller}: {msg}")) if progress else None
    try:
        evaluate = objective or StackObjective(controller, scenarios, work, keep=keep, pool=pool)
        found = search(dims, m, budget, evaluate, progress=say)
    finally:
        if pool is not None:
            pool.shutdown()
    names = [sc.stem for sc in scenarios]
    provenance = provenance_of(
        found, m, budget=budget, scenarios=names, wall_s=time.monotonic() - t0
    )
    gains = found.history[found.best_index]["gains"]
    result = {"controller": controller, "gains": gains, "provenance": provenance}
    record = {**result, "widenings": found.widenings, "history": found.history}
    (work / "tuning.json").write_text(jsonsafe.dumps(record, indent=1) + "\n")
    if gains_file is not None:
        gainsfile.update(gains_file, controller, gains, provenance)
    if not keep:
        log.info("tuning record: %s", work / "tuning.json")
    return result
