"""``wheelchair-hil tune --controller NAME``: the same tuning for every controller.

One method, one objective (:func:`objective_of`) and one budget of objective evaluations,
whatever the controller; every evaluation runs the tuning scenarios through the same
lock-step stack as the evaluation (:func:`tools.run.experiment.run_experiment`: bench, CAN
codec, controller process logic, recorder).  The tuning scenarios
(``scenarios/tuning/tune-*.toml``) are disjoint from the evaluation's: their own routes, start
offsets and seeds, and no fault (``tests/unit/tools/tuning`` checks it).

What is tuned, and where, is declared in ``scenarios/tuning/space.toml``: for each tunable
controller the same number of its declared gains, each with an explicit box ``[lo, hi]``
chosen from the physics of the law, not from ``controller/gains.toml`` (whose values only
remain the defaults of the keys that are not tuned).  The method (:class:`Method`, the
``[method]`` table of the same file):

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

The Sobol points count in the budget.  The result goes into the tuned gains file
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
from scipy.stats import qmc

from controller.tracking import registry
from dbc.runtime import jsonsafe
from dbc.runtime import params as params_mod
from dbc.runtime.errors import ConfigError, WheelchairError
from dbc.runtime.params import param
from tools.cli.tune import DEFAULT_BUDGET
from tools.evaluation.plan import MC_MASS_SPREAD, MC_NOISE_RANGE
from tools.evaluation.task import collected_series, comfort
from tools.evaluation.variation import Variation, apply_variation
from tools.metrics.tracking import BusCollector
from tools.run import scenario as scenario_mod
from tools.run.experiment import run_experiment
from tools.tuning import gainsfile

log = logging.getLogger(__name__)

TUNING_DIR = scenario_mod.SCENARIO_DIR / "tuning"
SPACE_FILE = TUNING_DIR / "space.toml"
GAINS_FILE = TUNING_DIR / "gains.toml"
#: Heading error weight of the objective (m per rad): 10 degrees count as 1.7 cm.
HEADING_WEIGHT_M_PER_RAD = 0.1
#: Added per run that does not track its whole route (a safe stop, a failed run), m.
FAILURE_PENALTY_M = 1.0
#: How a run ended when it tracked its route (or the bench's duration ended first); any
#: other stop reason (OFF_PATH, DISOBEYED, NON_FINITE, ...) is a safe stop, charged as a
#: failure (as the evaluation counts it) even where it came in the route's last half second.
COMPLETED_STOPS = ("ROUTE_DONE", "NONE")
#: The limits of the envelope whose use the objective charges (summary ``rate_limit_share``):
#: a law that rides on them leaves the chair's limiter to shape its command.  Jerk is
#: reported, not charged: a law without dynamics of its own (BASELINE, RESILIENT) passes the
#: pose estimate's step at each localization fix (10 Hz) straight into its speed, two ticks
#: at the jerk limit per fix (9-13 % of the ticks on scenario `short` at the default gains);
#: charging that would tune those gains to the fixes' noise, not to the tracking.
CHARGED_RATE_LIMITS = ("accel", "turn_accel", "speed", "turn_rate")
#: The share of the tracking ticks a run may spend at each charged limit free of charge.
RATE_LIMIT_FREE_SHARE = 0.01
#: What each percent of the ticks above that costs, per limit (m).
RATE_LIMIT_WEIGHT_M = 0.1
#: The ride every controller must give: the ISO 2631-1 weighted rms vector value of the
#: chair's real horizontal accelerations (as the evaluation's ``comfort_av_mps2``) above
#: which the objective charges the run; 0.5 m/s^2 is where Annex C's "fairly uncomfortable"
#: begins.  The reference itself is planned within 0.315 m/s^2 ("not uncomfortable").
COMFORT_BOUND_MPS2 = 0.5
#: What each m/s^2 above the bound costs (m): a ride at 1 m/s^2 costs 5 cm of tracking error.
COMFORT_WEIGHT_M_PER_MPS2 = 0.1
#: The far corner of the evaluation's Monte-Carlo envelope (tools/evaluation/plan.py:
#: localizer noise x U(0.5, 1.5), mass x U(0.8, 1.2)): every tuning scenario is also run
#: there (the full-length one only there: STRESS_ONLY), so gains that track on the nominal
#: chair but ring (or diverge) with more noise on a heavier chair are charged for it.
STRESS = Variation(noise_factor=MC_NOISE_RANGE[1], mass_factor=1.0 + MC_MASS_SPREAD)
OBJECTIVE = (
    "mean over the tuning runs (each scenario run nominal and at the Monte-Carlo envelope's "
    f"far corner, the full-length route only there: localizer noise x {STRESS.noise_factor:g}, mass x {STRESS.mass_factor:g}), of "
    f"(rmse_pos_m + {HEADING_WEIGHT_M_PER_RAD} m/rad * rmse_phie_rad + "
    f"{COMFORT_WEIGHT_M_PER_MPS2} m per m/s^2 of ISO 2631-1 a_v above "
    f"{COMFORT_BOUND_MPS2} m/s^2 + {RATE_LIMIT_WEIGHT_M} m per percent of the tracking ticks "
    f"above {100 * RATE_LIMIT_FREE_SHARE:g} % that the law's command spends at each of the "
    f"envelope's limits {', '.join(CHARGED_RATE_LIMITS)}), + {FAILURE_PENALTY_M} m per run "
    "that stops early (a safe stop, or tracking ended more than 0.5 s before the route's "
    "end) or fails"
)
#: The conditions each tuning scenario runs in, by name: the scenario as it is, and STRESS.
CONDITIONS = ("nominal", "stressed")
#: Tuning scenarios run at STRESS only: the full-length route is there to charge gains that
#: hold a short route but ring or drift off late on a long one at the envelope's worst; run
#: nominal too it would add 40 % to every evaluation's cost and no failure of its own.
STRESS_ONLY = ("tune-long",)


def conditions_of(scenario: Path | str) -> tuple[str, ...]:
    """The conditions tuning scenario ``scenario`` (a file or its stem) runs in."""
    return ("stressed",) if Path(scenario).stem in STRESS_ONLY else CONDITIONS


#: Significant digits of a tuned gain (the values the runs use and the gains file holds).
GAIN_DIGITS = 6
#: The space file's table that is the method, not a controller.
METHOD_TABLE = "method"
#: A controller's subtable of the space file with the widest its boxes may grow.
LIMITS_TABLE = "limits"

#: Objective of a batch of points: each a table of gain overrides, values in order.
Evaluate = Callable[[Sequence[Mapping[str, Any]]], Sequence[float]]


class TuningError(WheelchairError):
    """A tuning cannot be set up (unknown controller or gain, bad box or budget)."""


class _BudgetSpentError(Exception):
    """Raised inside Nelder-Mead's objective when no evaluation is left."""


@dataclass(frozen=True)
class Method:
    """How every controller is tuned (``[method]`` of the space file)."""

    sobol_points: int = param(
        32,
        unit="evaluations",
        lo=2,
        hi=1024,
        doc="points of the x0 stage's scrambled Sobol design (a power of 2)",
    )
    sobol_seed: int = param(
        2027, unit="1", lo=0, hi=2**31 - 1, doc="seed of the Sobol design's scrambling"
    )
    simplex_step: float = param(
        0.25,
        unit="1",
        lo=0.01,
        hi=0.5,
        doc="initial simplex: a step of this fraction of each box's log width along each axis",
    )
    xatol_ln: float = param(
        0.1,
        unit="1 (ln of a gain)",
        lo=1e-4,
        hi=1.0,
        doc="Nelder-Mead's xatol: every vertex within this of the best in every ln(gain)",
    )
    fatol_m: float = param(
        1e-4,
        unit="m",
        lo=1e-7,
        hi=0.01,
        doc="Nelder-Mead's fatol: every vertex's objective within this of the best",
    )
    edge_fraction: float = param(
        0.02,
        unit="1",
        lo=0.0,
        hi=0.25,
        doc="a gain this close to its box's edge, as a fraction of the box's log width, "
        "is on the edge",
    )
    widen_factor: float = param(
        3.0, unit="1", lo=1.1, hi=100.0, doc="an edge of a box is moved out by this factor"
    )


@dataclass(frozen=True)
class Dim:
    """One tuned gain: its dotted key, its box ``[lo, hi]`` and the widest it may grow,
    ``[limit_lo, limit_hi]`` (``limit_lo`` 0: no lower limit in log scale)."""

    key: str
    lo: float
    hi: float
    limit_lo: float
    limit_hi: float

    def widened(self, side: str, factor: float) -> Dim:
        """This box with its ``side`` ("lo" or "hi") moved out by ``factor``, cut to the
        limit."""
        if side == "hi":
            return dataclasses.replace(self, hi=min(self.hi * factor, self.limit_hi))
        return dataclasses.replace(self, lo=max(self.lo / factor, self.limit_lo))

    def at_limit(self, side: str) -> bool:
        """Whether the box's ``side`` is as far out as it may go."""
        if side == "hi":
            return self.hi >= self.limit_hi * (1.0 - 1e-12)
        return self.lo <= self.limit_lo * (1.0 + 1e-12)


def tuning_scenarios() -> list[Path]:
    """The tuning scenario files, sorted."""
    return sorted(TUNING_DIR.glob("tune-*.toml"))


def tunable(*, path: Path = SPACE_FILE) -> list[str]:
    """The controllers the space file gives boxes to, in its order (``--controller all``)."""
    return [k for k, v in params_mod.load_toml(path).items() if k != METHOD_TABLE and v]


def method(*, path: Path = SPACE_FILE) -> Method:
    """The space file's ``[method]``, validated (unit, bounds; a power-of-2 design); a space
    file of one's own without it (``tune --space``) takes the packaged file's, so that every
    controller is tuned the same way."""
    table = params_mod.load_toml(path).get(METHOD_TABLE) or params_mod.load_toml(SPACE_FILE).get(
        METHOD_TABLE, {}
    )
    m = params_mod.load(Method, table, source=str(path), prefix=METHOD_TABLE)
    if m.sobol_points & (m.sobol_points - 1):
        raise ConfigError(f"{path}: method.sobol_points = {m.sobol_points} must be a power of 2")
    return m


def space(name: str, *, path: Path = SPACE_FILE) -> list[Dim]:
    """The gains of controller ``name`` that tuning may change, with their boxes."""
    name = registry.canonical(name)
    cls = registry.controller_class(name)
    table = params_mod.load_toml(path)
    entry = table.get(name)
    if not isinstance(entry, dict) or not entry:
        raise TuningError(
            f"controller {name!r} is not tuned: {path} has no [{name}] with its gains' boxes; "
            f"tunable: {', '.join(tunable(path=path))} (a controller of your own: --space FILE "
            f"with its [{name}] boxes, docs/own-controller.md)"
        )
    limits = entry.get(LIMITS_TABLE, {})
    if not isinstance(limits, dict):
        raise ConfigError(f"{path}: [{name}.{LIMITS_TABLE}] must be a table")
    boxes = {k: v for k, v in entry.items() if k != LIMITS_TABLE}
    for key in limits:
        if key not in boxes:
            raise ConfigError(f"{path}: {name}.{LIMITS_TABLE}.{key}: {key!r} has no box")
    defaults = registry.load_params(name)
    dims = []
    for key, box in boxes.items():
        src = f"{path}: {name}.{key}"
        field = _field(cls.Params, defaults, key, source=f"{path} [{name}]")
        lo, hi = _interval(box, src)
        if not 0.0 < lo < hi:
            raise ConfigError(f"{src} = [{lo}, {hi}]: need 0 < lo < hi (searched in log scale)")
        decl_lo, decl_hi, lo_open = _declared(field)
        lim_lo, lim_hi = decl_lo, decl_hi
        if key in limits:
            lim_lo, lim_hi = _interval(limits[key], f"{path}: {name}.{LIMITS_TABLE}.{key}")
            if lim_lo < decl_lo or lim_hi > decl_hi:
                raise ConfigError(
                    f"{path}: {name}.{LIMITS_TABLE}.{key} = [{lim_lo}, {lim_hi}] leaves the "
                    f"declared bounds [{decl_lo}, {decl_hi}] of {name}.{key}"
                )
        if lo < lim_lo or hi > lim_hi:
            raise ConfigError(
                f"{src} = [{lo}, {hi}] leaves [{lim_lo}, {lim_hi}], the widest {key} may be "
                f"({'its limit in ' + LIMITS_TABLE if key in limits else 'its declared bounds'})"
            )
        if lo_open and lim_lo == decl_lo and lo <= lim_lo:
            raise ConfigError(f"{src} = [{lo}, {hi}]: {key} must exceed {decl_lo}")
        if lo_open and lim_lo == decl_lo > 0.0:
            lim_lo *= 1.0 + 1e-9  # an open bound: widening stops just above it
        dims.append(Dim(key, lo, hi, max(0.0, lim_lo), lim_hi))
    if not dims:
        raise TuningError(f"{path}: [{name}] declares no gain to tune")
    return dims


def _interval(value: Any, src: str) -> tuple[float, float]:
    ok = (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    )
    if not ok or not all(math.isfinite(v) for v in value):
        raise ConfigError(f"{src} must be an interval [lo, hi] of two finite numbers")
    return float(value[0]), float(value[1])


def _declared(field: dataclasses.Field[Any]) -> tuple[float, float, bool]:
    """The declared bounds of a gain (infinite where none) and whether ``lo`` is open."""
    lo = field.metadata.get("lo")
    hi = field.metadata.get("hi")
    lo_f = -math.inf if lo is None else float(lo)
    return lo_f, math.inf if hi is None else float(hi), bool(field.metadata.get("lo_open"))


def _field(cls: Any, obj: Any, key: str, *, source: str) -> dataclasses.Field[Any]:
    """The field a dotted ``key`` names in a Params dataclass, or ConfigError."""
    *sections, last = key.split(".")
    for sec in sections:
        if not hasattr(obj, sec) or not dataclasses.is_dataclass(getattr(obj, sec)):
            raise ConfigError(f"{source}: {key!r}: {sec!r} is not a section of the gains")
        obj = getattr(obj, sec)
    fields = {f.name: f for f in dataclasses.fields(obj)}
    if last not in fields:
        raise ConfigError(f"{source}: unknown gain {key!r}; known: {', '.join(sorted(fields))}")
    hints = typing.get_type_hints(type(obj))
    if hints.get(last) is not float:
        raise ConfigError(f"{source}: {key!r} is not a real-valued gain")
    return fields[last]


def gain(value: float) -> float:
    """A gain rounded to :data:`GAIN_DIGITS` significant digits."""
    return float(f"{value:.{GAIN_DIGITS}g}")


def gains_table(dims: Sequence[Dim], values: Sequence[float]) -> dict[str, Any]:
    """The overrides (nested for dotted keys) that set ``dims`` to ``values``."""
    out: dict[str, Any] = {}
    for d, v in zip(dims, values, strict=True):
        *sections, last = d.key.split(".")
        node = out
        for sec in sections:
            node = node.setdefault(sec, {})
        node[last] = gain(float(v))
    return out


def objective_of(summaries: Sequence[Mapping[str, Any]]) -> float:
    """:data:`OBJECTIVE` from the tuning runs' summaries."""
    total = 0.0
    for s in summaries:
        pos = _finite(s.get("rmse_pos_m"))
        phi = _finite(s.get("rmse_phie_rad"))
        early = _finite(s.get("tracking_ended_early_s")) or 0.0
        stopped = s.get("stop_reason") not in (None, *COMPLETED_STOPS)
        if (
            not s.get("error")
            and pos is not None
            and phi is not None
            and early <= 0.5
            and not stopped
        ):
            a_v = _finite(s.get("comfort_av_mps2")) or 0.0
            rough = max(0.0, a_v - COMFORT_BOUND_MPS2)
            total += pos + HEADING_WEIGHT_M_PER_RAD * phi + COMFORT_WEIGHT_M_PER_MPS2 * rough
            total += rate_limit_charge(s.get("rate_limit_share"))
        else:
            total += FAILURE_PENALTY_M + (pos or 0.0)
    return total / max(1, len(summaries))


def rate_limit_charge(shares: Mapping[str, Any] | None) -> float:
    """What a run's use of the envelope's limits costs (m): :data:`RATE_LIMIT_WEIGHT_M` per
    percent of its tracking ticks above :data:`RATE_LIMIT_FREE_SHARE` at each of
    :data:`CHARGED_RATE_LIMITS` (a share missing or NaN costs nothing)."""
    total = 0.0
    for k in CHARGED_RATE_LIMITS:
        share = _finite((shares or {}).get(k))
        if share is not None and share > RATE_LIMIT_FREE_SHARE:
            total += RATE_LIMIT_WEIGHT_M * 100.0 * (share - RATE_LIMIT_FREE_SHARE)
    return total


def _finite(v: Any) -> float | None:
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else None


def run_one(
    controller: str,
    scenario: str,
    gains_json: str,
    out: str,
    keep: bool = True,
    condition: str = "nominal",
) -> dict[str, Any]:
    """One tuning run (a worker function: never raises); its summary's figures and the
    ride's comfort.  ``condition`` "stressed" runs the scenario at :data:`STRESS`.  ``keep``
    False deletes the run's directory (its summary) once it is read.  The run keeps no MCAP
    log (``run_experiment(log=False)``: the same figures, a third of the time)."""
    try:
        scen = scenario_mod.load(scenario)
        if condition == "stressed":
            scen = apply_variation(scen, STRESS)
        elif condition != "nominal":
            raise TuningError(f"unknown tuning condition {condition!r}; known: {CONDITIONS}")
        scen = dataclasses.replace(scen, gains={**scen.gains, controller: json.loads(gains_json)})
        collector = BusCollector()
        summary = run_experiment(out, scen, controller, log=False, collector=collector)
    except Exception as err:  # a failed run is a penalised point, not the end of a tuning
        log.exception("tuning run %s %s (%s) failed", controller, scenario, condition)
        return {"error": f"{type(err).__name__}: {err}"}
    finally:
        if not keep:
            shutil.rmtree(out, ignore_errors=True)
    keys = (
        "rmse_pos_m",
        "rmse_phie_rad",
        "stop_reason",
        "tracking_ended_early_s",
        "rate_limit_share",
    )
    out_ = {k: summary.get(k) for k in keys}
    out_["comfort_av_mps2"] = _ride_comfort(collector)
    return out_


def _ride_comfort(collector: BusCollector) -> float:
    """ISO 2631-1 a_v (m/s^2) of the bench's true twist over the whole run (NaN if absent)."""
    tw = collected_series(collector)["Bench_Truth_Twist"]
    return float(comfort(tw["t"], tw["V"], tw["Omega"])["comfort_av_mps2"])


class StackObjective:
    """:data:`OBJECTIVE` on the lock-step stack: each point runs every tuning scenario in
    every condition (:data:`CONDITIONS`); a batch's runs are spread over ``pool`` (None: one
    after another)."""

    def __init__(
        self,
        controller: str,
        scenarios: Sequence[Path],
        work: Path,
        *,
        keep: bool,
        pool: Executor | None,
    ) -> None:
        self.controller = controller
        self.scenarios = list(scenarios)
        self.work = work
        self.keep = keep
        self.pool = pool
        self.points = 0  # evaluated so far: names the run directories
        self.runs_per_point = sum(len(conditions_of(s)) for s in self.scenarios)

    def __call__(self, batch: Sequence[Mapping[str, Any]]) -> list[float]:
        args = []
        for i, gains in enumerate(batch):
            gj = json.dumps(gains, sort_keys=True)
            k = self.points + i
            for s in self.scenarios:
                for cond in conditions_of(s):
                    out = str(self.work / f"eval{k:03d}" / f"{s.stem}-{cond}")
                    args.append((self.controller, str(s), gj, out, self.keep, cond))
        self.points += len(batch)
        if self.pool is not None:
            summaries = list(self.pool.map(run_one, *zip(*args, strict=True)))
        else:
            summaries = [run_one(*a) for a in args]
        per = self.runs_per_point
        return [objective_of(summaries[i * per : (i + 1) * per]) for i in range(len(batch))]


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


def tune(
    controller: str,
    *,
    budget: int = DEFAULT_BUDGET,
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


def summary_line(name: str, p: Mapping[str, Any]) -> str:
    """One line per tuned controller: objective start -> end, evaluations, converged,
    keys on an edge."""
    edges = ", ".join(
        f"{k} ({e['side']}{', at its limit' if e['at_limit'] else ''})"
        for k, e in p["on_edge"].items()
    )
    return (
        f"tune {name}: objective {p['objective_start']:.5f} -> {p['objective_value']:.5f}, "
        f"{p['evaluations']}/{p['budget_evaluations']} evaluations ({p['runs']} runs, "
        f"{p['wall_s']:.0f} s), converged: {'yes' if p['converged'] else 'no'}, "
        f"on an edge: {edges or 'none'}"
    )


def run(args: argparse.Namespace, argv: list[str]) -> int:
    space_file = Path(args.space) if getattr(args, "space", None) else SPACE_FILE
    if not space_file.is_file():
        raise ConfigError(f"--space {space_file}: no such file")
    names = (
        tunable(path=space_file)
        if args.controller == "all"
        else [registry.canonical(n) for n in args.controller.split(",")]
    )
    m = method(path=space_file)
    for name in names:  # TuningError or ConfigError naming it, before any run
        check_budget(args.budget, m, len(space(name, path=space_file)), name)
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
            space_file=space_file,
            progress=None if args.no_progress else (lambda m: print(m, file=sys.stderr)),
        )
        print(summary_line(name, res["provenance"]))
        print(f"  gains: {json.dumps(res['gains'], sort_keys=True)}")
    if not args.dry_run:
        print(f"  written to {gains_path}")
    return 0
