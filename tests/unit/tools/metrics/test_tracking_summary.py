"""Run metrics of a run that tracked for less than one truth sample."""

from __future__ import annotations

import math

import numpy as np

from controller.types import ReferenceSample
from tools.metrics.tracking import TRACKING, BusSeries, summarize_bus

SAFE_STOP = 4  # any state but TRACKING ends the tracked window


class _Line:
    """1 m/s along x for 10 s."""

    duration_s = 10.0

    def sample(self, t_s: float) -> ReferenceSample:
        return ReferenceSample(t_s, t_s, 0.0, 0.0, 1.0, 0.0)


def _bus(truth_s: list[float], states: list[tuple[float, int]]) -> BusSeries:
    hb = np.array(states, dtype=float).reshape(-1, 2)
    t = np.array(truth_s, dtype=float)
    return BusSeries(
        {
            "Host_Heartbeat": {
                "t": (hb[:, 0] * 1e9).astype(np.int64),
                "Host_State": hb[:, 1].astype(int),
                "Route_Time": np.maximum(hb[:, 0] - 1.0, 0.0),
            },
            "Bench_Truth_Pose": {
                "t": (t * 1e9).astype(np.int64),
                "X": np.maximum(t - 1.0, 0.0),
                "Y": np.full(t.size, 0.02),
                "Heading": np.zeros(t.size),
            },
        },
        {},
        {},
    )


def _summary(bus: BusSeries) -> dict[str, object]:
    return summarize_bus(bus, _Line(), half_track_m=0.3, wheel_radius_m=0.17, period_s=0.01)


def test_a_safe_stop_before_the_first_truth_sample_gives_no_figure_and_no_error() -> None:
    # tracking from 1.0 s, safe stop at the next heartbeat; truth only before and after
    bus = _bus([0.5, 0.9, 1.5, 2.0], [(1.0, TRACKING), (1.0 + 1e-3, SAFE_STOP)])
    s = _summary(bus)
    assert s["tracking_started"] is True
    assert s["samples"] == 0
    assert math.isnan(s["rmse_pos_m"]) and math.isnan(s["max_pos_err_m"])  # type: ignore[arg-type]
    assert s["tracking_ended_early_s"] > 9.9  # type: ignore[operator]


def test_the_same_log_tracked_longer_gives_its_figures() -> None:
    truth = [1.0 + 0.01 * k for k in range(200)]
    bus = _bus(truth, [(1.0, TRACKING), (3.0, SAFE_STOP)])
    s = _summary(bus)
    assert s["samples"] == 200
    assert abs(s["rmse_pos_m"] - 0.02) < 1e-9  # type: ignore[operator]
    assert abs(s["max_pos_err_m"] - 0.02) < 1e-9  # type: ignore[operator]
