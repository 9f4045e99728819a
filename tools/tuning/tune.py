"""``wheelchair-hil tune --controller NAME``: the same tuning for every controller.

One optimiser (:data:`OPTIMISER`: scipy's bounded Nelder-Mead), one objective
(:func:`objective_of`) and one budget of objective evaluations, whatever the controller;
every evaluation runs the tuning scenarios through the same lock-step stack as the
evaluation (:func:`tools.run.experiment.run_experiment`: bench, CAN codec, controller
process logic, recorder).  The tuning scenarios (``scenarios/tuning/tune-*.toml``) are
disjoint from the evaluation's: their own routes, start offsets and seeds, and no fault
(``tests/unit/tools/tuning`` checks it).

What is tuned is the controller's declared gains named in ``scenarios/tuning/space.toml``
(or the class's ``TUNABLE``), each in ``[x0 / spread, x0 * spread]`` around its
``controller/gains.toml`` value, cut to its declared bounds, searched in log scale (the
optimiser sees the box ``[-1, 1]^n``).  The result goes into the tuned gains file
(:mod:`tools.tuning.gainsfile`) with its provenance; ``wheelchair-hil evaluate`` applies it.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import logging
import math
import multiprocessing
import shutil
import sys
import tempfile
import time
import typing
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize

from controller.tracking import registry
from dbc.runtime import jsonsafe
from dbc.runtime import params as params_mod
from dbc.runtime.errors import ConfigError, WheelchairError
from tools.run import scenario as scenario_mod
from tools.run.experiment import run_experiment
from tools.tuning import gainsfile

log = logging.getLogger(__name__)

TUNING_DIR = scenario_mod.SCENARIO_DIR / "tuning"
SPACE_FILE = TUNING_DIR / "space.toml"
GAINS_FILE = TUNING_DIR / "gains.toml"
OPTIMISER = "scipy.optimize.minimize(method='Nelder-Mead', bounds=[-1, 1]^n, log-scaled gains)"
#: Heading error weight of the objective (m per rad): 10 degrees count as 1.7 cm.
HEADING_WEIGHT_M_PER_RAD = 0.1
#: Added per run that does not track its whole route (a safe stop, a failed run), m.
FAILURE_PENALTY_M = 1.0
OBJECTIVE = (
    "mean over the tuning scenarios of (rmse_pos_m + "
    f"{HEADING_WEIGHT_M_PER_RAD} m/rad * rmse_phie_rad), + {FAILURE_PENALTY_M} m per run "
    "that stops early or fails"
)
DEFAULT_BUDGET = 30  # tools.cli.tune.DEFAULT_BUDGET
#: Initial simplex: x0 and x0 + this step along each axis of the [-1, 1] box.
SIMPLEX_STEP = 0.4


class TuningError(WheelchairError):
    """A tuning cannot be set up (unknown controller or gain, bad budget)."""


@dataclass(frozen=True)
class Dim:
    """One tuned gain: its dotted key, start value and log-scale interval."""

    key: str
    x0: float
    lo: float
    hi: float

    def value(self, u: float) -> float:
        """The gain at box coordinate ``u`` in [-1, 1] (0 is ``x0``)."""
        u = min(1.0, max(-1.0, u))
        if u >= 0.0:
            return float(self.x0 * (self.hi / self.x0) ** u)
        return float(self.x0 * (self.x0 / self.lo) ** u)


def tuning_scenarios() -> list[Path]:
    """The tuning scenario files, sorted."""
    return sorted(TUNING_DIR.glob("tune-*.toml"))


def space(name: str, *, path: Path = SPACE_FILE) -> list[Dim]:
    """The gains of controller ``name`` that tuning may change, with their intervals."""
    cls = registry.controller_class(name)
    table = params_mod.load_toml(path)
    spread = table.get("spread", 3.0)
    if not isinstance(spread, int | float) or not spread > 1.0:
        raise ConfigError(f"{path}: spread = {spread!r} must be a number above 1")
    entry = table.get(name)
    keys: Any = entry.get("keys") if isinstance(entry, dict) else getattr(cls, "TUNABLE", None)
    if not keys:
        raise TuningError(
            f"controller {name!r} declares no tunable gains: add [{name}] keys = [...] to "
            f"{path} or a TUNABLE class attribute"
        )
    defaults = registry.load_params(name)
    dims = []
    for key in keys:
        owner, field = _field(cls.Params, defaults, key, source=f"{path} [{name}]")
        x0 = float(getattr(owner, field.name))
        lo_decl = field.metadata.get("lo")
        hi_decl = field.metadata.get("hi")
        if not x0 > 0.0:
            raise TuningError(f"{path} [{name}]: {key} = {x0} must be positive to be tuned")
        lo = x0 / spread
        hi = x0 * spread
        if lo_decl is not None:
            lo = max(
                lo, float(lo_decl) * (1.0 + 1e-9) if field.metadata.get("lo_open") else lo_decl
            )
        if hi_decl is not None:
            hi = min(hi, float(hi_decl))
        if not lo < x0 < hi:
            raise TuningError(
                f"{path} [{name}]: {key} = {x0} sits on a bound of its declared range "
                f"[{lo_decl}, {hi_decl}]: nothing to search on one side"
            )
        dims.append(Dim(key, x0, float(lo), float(hi)))
    return dims


def _field(cls: Any, obj: Any, key: str, *, source: str) -> tuple[Any, dataclasses.Field[Any]]:
    """The (object, field) a dotted ``key`` names in a Params dataclass, or ConfigError."""
    *sections, last = key.split(".")
    for sec in sections:
        if not hasattr(obj, sec) or not dataclasses.is_dataclass(getattr(obj, sec)):
            raise ConfigError(f"{source}: {key!r}: {sec!r} is not a section of the gains")
        obj = getattr(obj, sec)
    fields = {f.name: f for f in dataclasses.fields(obj)}
    if last not in fields:
        raise ConfigError(f"{source}: unknown gain {key!r}; known: {', '.join(sorted(fields))}")
    f = fields[last]
    hints = typing.get_type_hints(type(obj))
    if hints.get(last) is not float:
        raise ConfigError(f"{source}: {key!r} is not a real-valued gain")
    return obj, f


def gains_table(dims: Sequence[Dim], u: Sequence[float]) -> dict[str, Any]:
    """The overrides (nested for dotted keys) at box point ``u``."""
    out: dict[str, Any] = {}
    for d, ui in zip(dims, u, strict=True):
        *sections, last = d.key.split(".")
        node = out
        for sec in sections:
            node = node.setdefault(sec, {})
        node[last] = round(d.value(float(ui)), 6)
    return out


def objective_of(summaries: Sequence[Mapping[str, Any]]) -> float:
    """:data:`OBJECTIVE` from the tuning runs' summaries."""
    total = 0.0
    for s in summaries:
        pos = _finite(s.get("rmse_pos_m"))
        phi = _finite(s.get("rmse_phie_rad"))
        early = _finite(s.get("tracking_ended_early_s")) or 0.0
        if not s.get("error") and pos is not None and phi is not None and early <= 0.5:
            total += pos + HEADING_WEIGHT_M_PER_RAD * phi
        else:
            total += FAILURE_PENALTY_M + (pos or 0.0)
    return total / max(1, len(summaries))


def _finite(v: Any) -> float | None:
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else None


def run_one(
    controller: str, scenario: str, gains_json: str, out: str, keep: bool = True
) -> dict[str, Any]:
    """One tuning run (a worker function: never raises); its summary's figures.  ``keep``
    False deletes the run's directory (log and summary) once it is read."""
    try:
        scen = scenario_mod.load(scenario)
        scen = dataclasses.replace(scen, gains={**scen.gains, controller: json.loads(gains_json)})
        summary = run_experiment(out, scen, controller)
    except Exception as err:  # a failed run is a penalised point, not the end of a tuning
        log.exception("tuning run %s %s failed", controller, scenario)
        return {"error": f"{type(err).__name__}: {err}"}
    finally:
        if not keep:
            shutil.rmtree(out, ignore_errors=True)
    keys = ("rmse_pos_m", "rmse_phie_rad", "stop_reason", "tracking_ended_early_s")
    return {k: summary.get(k) for k in keys}


@dataclass
class Tuning:
    """The state of one tuning: the history of every evaluation."""

    controller: str
    dims: list[Dim]
    scenarios: list[Path]
    budget: int
    history: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    runs: int = 0


def tune(
    controller: str,
    *,
    budget: int = DEFAULT_BUDGET,
    workers: int = 1,
    out: Path | None = None,
    gains_file: Path | None = GAINS_FILE,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Tune ``controller``; write its entry into ``gains_file`` (None: write nothing) and
    return the result (gains, provenance, history)."""
    if budget < 2:
        raise TuningError(f"--budget {budget}: at least 2 objective evaluations")
    dims = space(controller)
    scenarios = tuning_scenarios()
    if not scenarios:
        raise TuningError(f"no tuning scenarios (tune-*.toml) in {TUNING_DIR}")
    for s in scenarios:
        scenario_mod.load(str(s))  # ConfigError naming the file, before any run
    keep = out is not None  # the runs' logs are kept only where the caller asked
    work = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="wheelchair-tune-"))
    work.mkdir(parents=True, exist_ok=True)
    state = Tuning(controller, dims, scenarios, budget)
    t0 = time.monotonic()
    ctx = multiprocessing.get_context("spawn")
    pool: Executor | None = (
        ProcessPoolExecutor(max_workers=min(workers, len(scenarios)), mp_context=ctx)
        if workers > 1
        else None
    )
    cache: dict[tuple[float, ...], float] = {}

    def f(u: np.ndarray) -> float:
        point = tuple(round(float(x), 6) for x in np.clip(u, -1.0, 1.0))
        if point in cache:
            return cache[point]
        if len(state.history) >= budget:  # the budget is spent: no more runs
            return math.inf
        k = len(state.history)
        gains = gains_table(dims, point)
        gj = json.dumps(gains, sort_keys=True)
        args = [
            (controller, str(s), gj, str(work / f"eval{k:03d}" / s.stem), keep) for s in scenarios
        ]
        if pool is not None:
            summaries = list(pool.map(run_one, *zip(*args, strict=True)))
        else:
            summaries = [run_one(*a) for a in args]
        state.runs += len(args)
        value = objective_of(summaries)
        cache[point] = value
        state.history.append({"evaluation": k, "gains": gains, "objective": value})
        if progress:
            progress(f"tune {controller}: evaluation {k + 1}/{budget}: objective {value:.5f}")
        return value

    n = len(dims)
    simplex = np.vstack([np.zeros(n), np.eye(n) * SIMPLEX_STEP])
    try:
        res = optimize.minimize(
            f,
            np.zeros(n),
            method="Nelder-Mead",
            bounds=[(-1.0, 1.0)] * n,
            options={
                "maxfev": budget,
                "initial_simplex": simplex,
                "xatol": 0.02,
                "fatol": 1e-4,
            },
        )
    finally:
        if pool is not None:
            pool.shutdown()
    wall_s = time.monotonic() - t0
    best = min(state.history, key=lambda h: h["objective"])
    start = state.history[0]["objective"]
    converged = bool(res.success) and len(state.history) < budget
    provenance: dict[str, Any] = {
        "date": datetime.datetime.now(datetime.UTC).replace(microsecond=0).isoformat(),
        "optimiser": OPTIMISER,
        "objective": OBJECTIVE,
        "objective_value": float(best["objective"]),
        "objective_start": float(start),
        "budget_evaluations": budget,
        "evaluations": len(state.history),
        "runs": state.runs,
        "wall_s": round(wall_s, 1),
        "converged": converged,
        "message": str(res.message),
        "scenarios": [s.stem for s in scenarios],
        "tuned": [d.key for d in dims],
    }
    gains = best["gains"] if best["objective"] < start else {}
    if not gains:
        provenance["message"] += "; no point beat controller/gains.toml, which is kept"
    result = {"controller": controller, "gains": gains, "provenance": provenance}
    (work / "tuning.json").write_text(
        jsonsafe.dumps({**result, "history": state.history}, indent=1) + "\n"
    )
    if gains_file is not None:
        gainsfile.update(gains_file, controller, gains, provenance)
    if not keep:
        log.info("tuning record: %s", work / "tuning.json")
    return result


def run(args: argparse.Namespace, argv: list[str]) -> int:
    names = registry.names() if args.controller == "all" else args.controller.split(",")
    for name in names:
        registry.controller_class(name)  # ConfigError naming it, before any run
    out = Path(args.out) if args.out else None
    gains_path = Path(args.gains_file)
    if not gains_path.is_absolute() and not gains_path.parent.is_dir():
        # the default, from anywhere: among the packaged scenarios
        parts = gains_path.parts[1:] if gains_path.parts[:1] == ("scenarios",) else gains_path.parts
        gains_path = scenario_mod.SCENARIO_DIR.joinpath(*parts)
    for name in names:
        res = tune(
            name,
            budget=args.budget,
            workers=args.workers,
            out=out / name if out else None,
            gains_file=None if args.dry_run else gains_path,
            progress=None if args.no_progress else (lambda m: print(m, file=sys.stderr)),
        )
        p = res["provenance"]
        print(
            f"tune {name}: objective {p['objective_start']:.5f} -> {p['objective_value']:.5f} "
            f"in {p['evaluations']} evaluations ({p['runs']} runs, {p['wall_s']:.0f} s); "
            f"converged: {p['converged']} ({p['message']})"
        )
        print(f"  gains: {json.dumps(res['gains'], sort_keys=True)}")
    if not args.dry_run:
        print(f"  written to {gains_path}")
    return 0
