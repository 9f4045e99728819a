"""A run's summary gives the controller's counts as shares of its tracking ticks: at each limit
of the envelope (``rate_limit_share``) and in each of the law's own events
(``law_activity_share``)."""

from __future__ import annotations

import math

from controller.limits import RATE_LIMITS
from tools.logs.runlog import law_activity_share, rate_limit_share


def test_each_limit_is_a_share_of_the_counted_ticks() -> None:
    counts = {"ticks": 200, "accel": 50, "turn_accel": 2, "speed": 0, "turn_rate": 200}
    shares = rate_limit_share(counts)
    assert list(shares) == list(RATE_LIMITS)
    assert shares == {
        "accel": 0.25,
        "turn_accel": 0.01,
        "speed": 0.0,
        "turn_rate": 1.0,
        "jerk": 0.0,
    }


def test_a_run_that_never_tracked_has_no_share_rather_than_zero() -> None:
    for counts in (None, {}, {"ticks": 0, "accel": 0}):
        shares = rate_limit_share(counts)
        assert list(shares) == list(RATE_LIMITS)
        assert all(math.isnan(v) for v in shares.values())


def test_the_laws_events_are_shares_of_its_own_steps_and_ticks_is_not_an_event() -> None:
    counts = {"ticks": 400, "outside_boundary1": 100, "regime_fragile": 0}
    assert law_activity_share(counts, tracking_ticks=500) == {
        "outside_boundary1": 0.25,
        "regime_fragile": 0.0,
    }
    # a law that does not count its steps: the controller's tracking ticks
    assert law_activity_share({"qp_fallback": 5}, tracking_ticks=500) == {"qp_fallback": 0.01}
    assert law_activity_share({"ticks": 12}) == {}  # nothing but steps: no event
    assert law_activity_share(None) == {}
    assert math.isnan(law_activity_share({"ticks": 0, "x": 0})["x"])
