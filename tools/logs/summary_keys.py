"""The keys of a run's summary (summary.json, tools.logs.runlog) that are not figures of the
run: those the wall clock and the machine set, and the counts of what came late.  Declared
once here for the evaluation's timing section and for the checks that two runs agree."""

from __future__ import annotations

#: Summary keys measured on the wall clock or the machine: two runs of one scenario differ
#: in these alone (and in the name of their own bus, ``bus``).
WALL_CLOCK_KEYS: tuple[str, ...] = (
    "wall_s",
    "wall_total_s",
    "real_time_factor",
    "controller_step_us_p50",
    "controller_step_us_p99",
    "tick_us_p50",
    "tick_us_p99",
    "lockstep_budget_us",
    "controller_peak_rss_mb",
)
#: Summary counts of what came late in a real-time run (none in lock-step).
LATE_COUNT_KEYS: tuple[str, ...] = ("deadline_misses", "missed_acks", "recorder_missed_steps")
