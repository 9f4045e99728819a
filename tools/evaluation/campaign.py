"""A campaign's plan: which runs make up the paper's experiments, each once, and what role each plays.

:func:`plan_campaign` turns the command line's :class:`Options` into a :class:`Campaign`: the
paper's table (per fault setting), the Monte-Carlo cells, the cascaded runs and their random
replicates, the amplitude sweeps of the fragility spectrum and the repeated-exposure study,
deduplicated (the same experiment asked for twice is one run).  The runs are executed by
:mod:`tools.evaluation.execute`, one run's result is :mod:`tools.evaluation.task`'s,
``results.json`` is assembled by :mod:`tools.evaluation.assemble`, and
:mod:`tools.evaluation.pipeline` runs a campaign end to end.  docs/evaluation.md states the
method (rank, estimator, thresholds, variations).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controller.tracking import registry
from tools.evaluation.plan import (
    CASCADED,
    DEFAULT_CONTROLLERS,
    EXPOSURE_SCENARIO,
    FAULT_FREE,
    FAULT_SETTINGS,
    PAPER_SCENARIOS,
    REFERENCE_CONTROLLER,
    SPECTRUM_FACTORS,
    SPECTRUM_FAULTS,
    VARIANT_SCENARIOS,
    VARIANTS,
    EvaluationError,
)
from tools.evaluation.task import Task
from tools.evaluation.variation import NOMINAL, Variation, draw_cascade, draw_variation
from tools.run import scenario as scenario_mod
from tools.tuning import gainsfile

#: --logs: which runs of a campaign keep their MCAP log (Options.logs)
LOG_CHOICES = ("nominal", "all")


@dataclass(frozen=True)
class Options:
    """What a campaign runs (the command line's options)."""

    controllers: tuple[str, ...] = DEFAULT_CONTROLLERS
    scenarios: tuple[str, ...] = PAPER_SCENARIOS
    seed: int = 1
    #: Monte-Carlo replicates per cell besides the nominal run (1: none), in every setting
    #: that ``seeds_per_setting`` does not name
    seeds: int = 1
    #: fault setting -> its replicates (``--seeds paper=20,physical=10``)
    seeds_per_setting: tuple[tuple[str, int], ...] = ()
    cascaded: bool = True
    spectrum: bool = False
    spectrum_faults: tuple[str, ...] = SPECTRUM_FAULTS
    spectrum_seeds: int = 3
    exposure: bool = False
    duration_s: float | None = None
    #: fault settings (plan.FAULT_SETTINGS); the first is the primary one
    settings: tuple[str, ...] = FAULT_SETTINGS
    #: tuned gains file (tools.tuning.gainsfile); None: controller/gains.toml as it is
    gains: str | None = None
    #: which runs keep their MCAP log and time series: "nominal" (the primary setting's
    #: nominal runs: every run the figures draw, one logged run per cell of the paper's
    #: table), "all"
    logs: str = "nominal"
    #: Monte-Carlo replicates for the reference row (BASELINE) too, not only for the ranked
    #: controllers and the variants
    reference_mc: bool = False
    #: replicates of the cascaded run with faults at random moments (0: the fixed schedule only)
    cascade_seeds: int = 0

    def seeds_for(self, setting: str) -> int:
        """The replicates of ``setting``'s cells (besides the nominal run; 1: none)."""
        return dict(self.seeds_per_setting).get(setting, self.seeds)


@dataclass
class Campaign:
    """The tasks of a campaign (deduplicated) and the role each plays in the results."""

    options: Options
    tasks: dict[str, Task] = field(default_factory=dict)
    #: (setting, controller, scenario) -> key
    table: dict[tuple[str, str, str], str] = field(default_factory=dict)
    monte_carlo: dict[tuple[str, str, str], list[str]] = field(default_factory=dict)
    #: (setting, controller) -> key; and the random cascades (Monte-Carlo)
    cascaded: dict[tuple[str, str], str] = field(default_factory=dict)
    cascaded_mc: dict[tuple[str, str], list[str]] = field(default_factory=dict)
    #: controller -> its tuned gains and their provenance (empty: controller/gains.toml)
    gains: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: (controller, fault) -> replicate -> factor -> key
    spectrum: dict[tuple[str, str], list[dict[float, str]]] = field(default_factory=dict)
    #: controller -> {"repeated": key, "single": [key or None per exposure]}
    exposure: dict[str, dict[str, Any]] = field(default_factory=dict)

    def add(self, task: Task) -> str:
        """Add ``task`` once (the same experiment asked for twice is one run, logged if either
        asks for a log)."""
        old = self.tasks.get(task.key)
        if old is None or (task.log and not old.log):
            self.tasks[task.key] = task
        return task.key


def plan_campaign(opt: Options) -> Campaign:
    """Every run the options ask for, each once (see the module doc and docs/evaluation.md)."""

    if not opt.controllers:
        raise EvaluationError("--controllers: at least one controller is needed")
    for c in opt.controllers:
        if c not in registry.names():
            raise EvaluationError(
                f"--controllers: unknown controller {c!r}; known: {', '.join(registry.names())}"
            )
    per = [n for _s, n in opt.seeds_per_setting]
    if min([opt.seeds, *per]) < 1 or opt.spectrum_seeds < 1 or opt.cascade_seeds < 0:
        raise EvaluationError(
            "--seeds and --spectrum-seeds must be at least 1, --cascade-seeds at least 0"
        )
    for st, _n in opt.seeds_per_setting:
        if st not in opt.settings:
            raise EvaluationError(
                f"--seeds: {st}={_n} names a setting the campaign does not run "
                f"(--settings {','.join(opt.settings)})"
            )
    if opt.logs not in LOG_CHOICES:
        raise EvaluationError(f"--logs: choose one of {', '.join(LOG_CHOICES)}, got {opt.logs!r}")
    scenario_mod.check_seed(opt.seed)
    for s in opt.scenarios:
        scenario_mod.find(s)  # ConfigError naming the scenario
    if not opt.settings:
        raise EvaluationError("--settings: at least one fault setting is needed")
    for st in opt.settings:
        if st not in FAULT_SETTINGS:
            raise EvaluationError(
                f"--settings: unknown fault setting {st!r}; known: {', '.join(FAULT_SETTINGS)}"
            )
    camp = Campaign(opt)
    if opt.gains is not None:
        tuned = gainsfile.load(Path(opt.gains))
        # a variant runs with the tuned gains of the controller it varies
        camp.gains = {
            c: tuned[VARIANTS.get(c, c)] for c in opt.controllers if VARIANTS.get(c, c) in tuned
        }
    gains_json = {c: json.dumps(e["gains"], sort_keys=True) for c, e in camp.gains.items()}
    scenarios: dict[str, Any] = {}

    def task(c: str, s: str, var: Variation = NOMINAL, setting: str | None = None) -> str:
        # runs that are the same experiment in two settings are made once
        scen = scenarios.get(s)
        if scen is None:
            scen = scenarios[s] = scenario_mod.load(s)
        eff = scenario_mod.effective_setting(scen, setting or opt.settings[0])
        logged = opt.logs == "all" or (
            var.replicate == 0 and (setting or opt.settings[0]) == opt.settings[0]
        )
        return camp.add(
            Task(
                c,
                s,
                var,
                opt.duration_s,
                opt.seed,
                setting=eff,
                gains=gains_json.get(c, ""),
                log=logged,
            )
        )

    for st in opt.settings:
        for c in opt.controllers:
            # a variant answers one question: what it changes in the cells it concerns, in the
            # primary setting (the paper's, where the question arose)
            if c in VARIANTS and st != opt.settings[0]:
                continue
            cells = [s for s in opt.scenarios if c not in VARIANTS or s in VARIANT_SCENARIOS]
            n_mc = opt.seeds_for(st)
            replicated = n_mc > 1 and (c != REFERENCE_CONTROLLER or opt.reference_mc)
            for s in cells:
                camp.table[(st, c, s)] = task(c, s, setting=st)
                if replicated:
                    camp.monte_carlo[(st, c, s)] = [
                        task(c, s, draw_variation(opt.seed, r), st) for r in range(1, n_mc + 1)
                    ]
            if opt.cascaded and c not in VARIANTS:
                camp.cascaded[(st, c)] = task(c, CASCADED, setting=st)
                if opt.cascade_seeds > 0:
                    n = len(scenario_mod.load(CASCADED).faults)
                    camp.cascaded_mc[(st, c)] = [
                        task(c, CASCADED, draw_cascade(opt.seed, r, n), st)
                        for r in range(1, opt.cascade_seeds + 1)
                    ]
    if opt.spectrum:
        unknown = sorted(set(opt.spectrum_faults) - set(SPECTRUM_FAULTS))
        if unknown:
            raise EvaluationError(
                f"--spectrum-faults: unknown fault {unknown[0]!r}; known: {', '.join(SPECTRUM_FAULTS)}"
            )
        for c in opt.controllers:
            for fault in opt.spectrum_faults:
                reps: list[dict[float, str]] = []
                for r in range(opt.spectrum_seeds):
                    base = draw_variation(opt.seed, r, vary_amplitude=False) if r else NOMINAL
                    grid = {}
                    for f in SPECTRUM_FACTORS:
                        if f == 0.0:  # no fault at all: the fault-free run of that replicate
                            grid[f] = task(c, FAULT_FREE, base)
                        else:
                            grid[f] = task(c, fault, dataclasses.replace(base, amplitude_factor=f))
                    reps.append(grid)
                camp.spectrum[(c, fault)] = reps
    if opt.exposure:
        n = len(scenario_mod.load(EXPOSURE_SCENARIO).faults)
        for c in opt.controllers:
            camp.exposure[c] = {
                "repeated": task(c, EXPOSURE_SCENARIO),
                # the first exposure alone is the repeated run up to its end: no extra run
                "single": [None]
                + [task(c, EXPOSURE_SCENARIO, Variation(only_fault=k)) for k in range(1, n)],
            }
    return camp
