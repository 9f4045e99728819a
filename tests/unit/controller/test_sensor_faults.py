"""Sensor faults injected into the controller's estimate (the paper's flat tire)."""

from __future__ import annotations

import math

import pytest

from controller.config import PerceivedFlatParams
from controller.sensor_faults import PerceivedEncoders, perceived_radius_m

R0 = 0.30


def test_the_perceived_radius_follows_the_benchs_flat_tire_profile() -> None:
    f = PerceivedFlatParams(side="left", onset_s=10.0, to_radius_m=0.26, time_constant_s=2.0)
    assert perceived_radius_m(f, R0, 9.99) == R0
    assert perceived_radius_m(f, R0, 12.0) == pytest.approx(0.30 - 0.04 * (1 - math.exp(-1)))
    assert perceived_radius_m(f, R0, 1e4) == pytest.approx(0.26)
    step = PerceivedFlatParams(onset_s=1.0, duration_s=2.0, to_radius_m=0.25, time_constant_s=0)
    assert perceived_radius_m(step, R0, 1.5) == 0.25
    assert perceived_radius_m(step, R0, 3.0) == R0  # re-inflated when it ends


def test_perceived_positions_scale_only_the_faulty_wheels_rotation_after_the_onset() -> None:
    f = PerceivedFlatParams(side="right", onset_s=1.0, to_radius_m=0.24, time_constant_s=0.0)
    enc = PerceivedEncoders([f], R0)
    assert enc.positions(0.0, 0.0, 0.0) == (0.0, 0.0)
    assert enc.positions(1.0, 1.0, 0.5) == (1.0, 1.0)  # before the onset: as read
    left, right = enc.positions(2.0, 2.0, 1.5)
    assert left == 2.0 and right == pytest.approx(1.0 + 0.24 / 0.30)
    # a non-finite reading passes through for the odometry to reject; the state is kept
    assert math.isnan(enc.positions(math.nan, 3.0, 1.6)[0])
    left, right = enc.positions(3.0, 3.0, 1.7)
    assert left == 3.0 and right == pytest.approx(1.0 + 2 * 0.8)


def test_without_a_fault_positions_are_untouched() -> None:
    enc = PerceivedEncoders([], R0)
    assert not enc.active
    assert enc.positions(1.25, -3.5, 7.0) == (1.25, -3.5)
