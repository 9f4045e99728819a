"""What a campaign is made of: the paper's controllers and scenarios, the metrics, the grids.

Constants (and the registry's variants), so that the command line can show the defaults
without importing the campaign (docs/evaluation.md states the method these numbers belong to),
and :class:`EvaluationError`, which every part of a campaign raises.
"""

from __future__ import annotations

import math

from controller.tracking import registry
from dbc.runtime.errors import WheelchairError
from tools.logs.summary_keys import LATE_COUNT_KEYS, WALL_CLOCK_KEYS


class EvaluationError(WheelchairError):
    """A campaign cannot be set up or executed (bad option, missing optional dependency)."""


#: The paper's four controllers, in the order of its table.
PAPER_CONTROLLERS: tuple[str, ...] = ("robust", "adaptive", "resilient", "antifragile")
#: Kanayama's law: a reference row of the table and the paper's Fig. 12.
REFERENCE_CONTROLLER = "baseline"
#: Named variants of a paper controller (controller.tracking.registry.VARIANTS), each an
#: extra row (not ranked) compared, cell by cell and replicate by replicate, with the
#: controller it varies: ADAPTIVE with the integral action the paper's cost does not have.
VARIANTS: dict[str, str] = {v: law for v, (law, _keys) in registry.VARIANTS.items()}
#: The cells a variant is run in, in the primary fault setting: the question it answers
#: (ADAPTIVE's integral action was held to explain its lead on the flat tires in (a)).
VARIANT_SCENARIOS: tuple[str, ...] = ("flat-left", "flat-right")
#: Rows of the table that are shown, not ranked.
REFERENCE_CONTROLLERS: tuple[str, ...] = (REFERENCE_CONTROLLER, *VARIANTS)
DEFAULT_CONTROLLERS: tuple[str, ...] = (*PAPER_CONTROLLERS, *REFERENCE_CONTROLLERS)
#: The paper's table columns, in its order.
PAPER_SCENARIOS: tuple[str, ...] = (
    "fault-free",
    "bump-left",
    "bump-right",
    "flat-left",
    "flat-right",
)
FAULT_FREE = "fault-free"
CASCADED = "cascaded"
EXPOSURE_SCENARIO = "repeated-exposure"
#: The components the paper ranks, as summary keys.
RANK_METRICS: tuple[str, ...] = ("rmse_xe_m", "rmse_ye_m", "rmse_phie_rad")
#: Per-cell metrics of the table (deterministic; compute time is in ``timing``).
CELL_METRICS: tuple[str, ...] = (
    "rmse_xe_m",
    "rmse_ye_m",
    "rmse_phie_rad",
    "rmse_pos_m",
    "max_pos_err_m",
    "max_phie_rad",
    "final_pos_err_m",
    "control_effort",
    "tv_v",
    "tv_omega",
    "chattering_hz",
    "comfort_awx_mps2",
    "comfort_awy_mps2",
    "comfort_av_mps2",
)
#: Per-run shares of the tracking ticks (summary keys, tools.logs.runlog): at each limit of
#: the envelope (the law's command, before the limiter), and in each of the law's own events.
SHARE_FIELDS: tuple[str, ...] = ("rate_limit_share", "law_activity_share")
#: Summary fields kept in a run's ``timing`` section: its simulated length, the wall-clock
#: figures (tools.logs.summary_keys.WALL_CLOCK_KEYS but the step budget's table and the memory,
#: which `wheelchair-hil bench` reports) and the counts of what came late.
TIMING_FIELDS: tuple[str, ...] = (
    "sim_duration_s",
    *(k for k in WALL_CLOCK_KEYS if k not in ("lockstep_budget_us", "controller_peak_rss_mb")),
    *LATE_COUNT_KEYS,
)
#: Faults swept for the spectrum: the scenario that holds each at the paper's amplitude.
SPECTRUM_FAULTS: tuple[str, ...] = ("flat-left", "flat-right", "bump-left", "bump-right", "slip")
#: Stress grid as multiples of the paper's amplitude: uniform, centred on it.
SPECTRUM_FACTORS: tuple[float, ...] = (0.0, 0.5, 1.0, 1.5, 2.0)
#: |convexity| below this (a fraction of the error at the paper's amplitude) is "linear".
SPECTRUM_TOLERANCE = 0.1
#: The response whose convexity is measured.
SPECTRUM_METRIC = "rmse_pos_m"
#: Fault kinds whose amplitude the evaluation scales (sweeps, Monte-Carlo).
_SCALABLE = ("flat-tire", "shaft-bump", "slip")
#: ISO 2631-1 multiplying factor of the horizontal axes (health, §7.2; the planner's default).
COMFORT_K_HORIZONTAL = 1.4
#: Monte-Carlo ranges (docs/evaluation.md): relative spreads and absolute offsets.
MC_MASS_SPREAD = 0.2
MC_AMPLITUDE_SPREAD = 0.2
MC_NOISE_RANGE = (0.5, 1.5)
MC_ONSET_SHIFT_S = 2.0
MC_OFFSET_M = 0.05
MC_OFFSET_RAD = math.radians(3.0)
#: The fault settings of a campaign (tools.run.scenario.FAULT_SETTINGS), the first one is
#: the primary: the paper's table, its figures, the spectrum and the exposure runs.
FAULT_SETTINGS: tuple[str, ...] = ("paper", "physical", "diagnosed")
#: Monte-Carlo of the cascaded run (the paper's text: faults "at random moments ... and with
#: different magnitudes"): onsets sorted uniform in this window (s), each fault lasting to
#: the next one's onset and the last for a uniform draw in MC_CASCADE_LAST_S, every fault's
#: amplitude times a uniform draw in MC_CASCADE_FACTOR.
MC_CASCADE_WINDOW_S = (5.0, 60.0)
MC_CASCADE_LAST_S = (8.0, 18.0)
MC_CASCADE_FACTOR = (0.5, 1.5)
#: The tuned gains `make run` uses (written by `wheelchair-hil tune`), relative to the repo.
TUNED_GAINS = "scenarios/tuning/gains.toml"
