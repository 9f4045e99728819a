"""Differential-drive kinematics: the one path between body twist and wheel speeds."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.kinematics import (
    TWO_PI,
    forward,
    inverse,
    radps_to_revps,
    revps_to_radps,
    rim_speeds,
    twist_from_rim,
)
from controller.tracking.parking import RouteEndLatch

B, R = 0.27, 0.30
finite = st.floats(-3.0, 3.0, allow_nan=False)


def test_turning_on_the_spot_spins_the_wheels_in_opposite_directions() -> None:
    w = inverse(0.0, 1.0, B, R, R)
    assert w.left_radps == pytest.approx(-B / R)
    assert w.right_radps == pytest.approx(B / R)


def test_the_left_wheel_is_the_slower_one_in_a_left_turn() -> None:
    left, right = rim_speeds(1.0, 0.5, B)
    assert left == pytest.approx(1.0 - B * 0.5) and right == pytest.approx(1.0 + B * 0.5)
    assert left < right


def test_a_smaller_left_radius_needs_a_faster_left_wheel_for_the_same_twist() -> None:
    nominal = inverse(1.0, 0.0, B, R, R)
    flat = inverse(1.0, 0.0, B, 0.9 * R, R)
    assert flat.left_radps == pytest.approx(nominal.left_radps / 0.9)
    assert flat.right_radps == nominal.right_radps


@given(v=finite, omega=finite)
def test_forward_undoes_inverse(v: float, omega: float) -> None:
    w = inverse(v, omega, B, R, 0.29)
    v2, omega2 = forward(w.left_radps, w.right_radps, B, R, 0.29)
    assert v2 == pytest.approx(v, abs=1e-12)
    assert omega2 == pytest.approx(omega, abs=1e-12)


@given(v=finite, omega=finite)
def test_twist_from_rim_undoes_rim_speeds(v: float, omega: float) -> None:
    v2, omega2 = twist_from_rim(*rim_speeds(v, omega, B), B)
    assert v2 == pytest.approx(v, abs=1e-12) and omega2 == pytest.approx(omega, abs=1e-12)


def test_revolutions_and_radians_convert_both_ways() -> None:
    assert 2.0 * math.pi == TWO_PI
    assert radps_to_revps(TWO_PI) == 1.0
    assert revps_to_radps(0.5) == math.pi


def test_a_parked_law_stays_parked_until_reset() -> None:
    latch = RouteEndLatch()
    assert not latch.check(route_done=False, distance_m=0.0, stop_radius_m=0.1)
    assert not latch.check(route_done=True, distance_m=0.2, stop_radius_m=0.1)
    assert latch.check(route_done=True, distance_m=0.05, stop_radius_m=0.1)
    assert latch.check(route_done=True, distance_m=5.0, stop_radius_m=0.1)  # latched
    assert not RouteEndLatch().parked
