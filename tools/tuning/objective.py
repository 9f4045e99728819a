"""The one objective every controller is tuned on: its runs and its figure.

Each evaluation of a point runs every tuning scenario (``scenarios/tuning/tune-*.toml``,
:func:`tuning_scenarios`) through the same lock-step stack as the evaluation
(:func:`tools.run.experiment.run_experiment`: bench, CAN codec, controller process logic,
recorder), in each of its conditions (:data:`CONDITIONS`: nominal and at the Monte-Carlo
envelope's far corner, :data:`STRESS`); :func:`objective_of` makes :data:`OBJECTIVE` of their
summaries.  :class:`StackObjective` evaluates a batch of points that way, over a worker pool.
The tuning scenarios are disjoint from the evaluation's: their own routes, start offsets and
seeds, and no fault (``tests/unit/tools/tuning`` checks it).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import shutil
from collections.abc import Mapping, Sequence
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

from tools.evaluation.plan import MC_MASS_SPREAD, MC_NOISE_RANGE
from tools.evaluation.task import collected_series, comfort
from tools.evaluation.variation import Variation, apply_variation
from tools.metrics.tracking import BusCollector
from tools.run import scenario as scenario_mod
from tools.run.experiment import run_experiment
from tools.tuning.space import TUNING_DIR, TuningError

log = logging.getLogger(__name__)

#: Heading error weight of the objective (m per rad): 10 degrees count as 1.7 cm.
HEADING_WEIGHT_M_PER_RAD = 0.1
#: Added per run that does not track its whole route (a safe stop, a failed run), m.
FAILURE_PENALTY_M = 1.0
#: How a run ended when it tracked its whole route.  Any other stop reason (OFF_PATH,
#: DISOBEYED, NON_FINITE, ...) is a safe stop, charged as a failure (as the evaluation counts
#: it) even where it came in the route's last half second; and so is ``NONE``: a tuning run
#: lasts its route and the scenario's tail, so a chair still tracking at its end has not
#: reached the route's end (RESILIENT tuned with it counted as done took a 2.6 m carrot
#: that trailed and cut the bends: 77 cm off its path, never parked).
COMPLETED_STOPS = ("ROUTE_DONE",)
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
    "end), has not reached the route's end when the scenario ends, or fails"
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


def tuning_scenarios() -> list[Path]:
    """The tuning scenario files, sorted."""
    return sorted(TUNING_DIR.glob("tune-*.toml"))


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
