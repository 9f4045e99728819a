"""Wheel odometry: exact arcs, current radii, robustness to first samples, resets and NaN."""

from __future__ import annotations

import math

import pytest

from controller.odometry import Odometry, arc_step
from controller.types import Pose

B = 0.3  # half track (m)
R = 0.3  # wheel radius (m)
REV = 2 * math.pi * R  # travel per wheel revolution (m)


def test_first_sample_sets_the_baseline_without_moving() -> None:
    od = Odometry(B, R, R, pose=Pose(1.0, 2.0, 0.5))
    assert od.update(1234.5, -987.25) is None
    assert od.pose == Pose(1.0, 2.0, 0.5)
    inc = od.update(1234.5, -987.25)
    assert inc is not None and inc.ds_m == 0.0 and inc.dphi_rad == 0.0
    assert od.pose == Pose(1.0, 2.0, 0.5)


def test_straight_travel_is_revolutions_times_circumference() -> None:
    od = Odometry(B, R, R)
    od.update(0.0, 0.0)
    for k in range(1, 11):
        inc = od.update(0.01 * k, 0.01 * k)
        assert inc is not None
        assert inc.ds_left_m == pytest.approx(0.01 * REV)
    assert od.pose.x_m == pytest.approx(0.1 * REV, abs=1e-12)
    assert od.pose.y_m == pytest.approx(0.0, abs=1e-12)
    assert od.distance_m == pytest.approx(0.1 * REV)


@pytest.mark.parametrize("steps", [7, 1000])
def test_constant_wheel_speeds_integrate_an_exact_circle_at_any_step_size(steps: int) -> None:
    # left 0.5 m, right 1.0 m per unit: radius b (r + l)/(r - l) = 0.9 m, full turn when
    # (r - l) / (2 b) * n = 2 pi
    od = Odometry(B, R, R, max_step_m=10.0)
    od.update(0.0, 0.0)
    total_dphi = 2 * math.pi
    units = total_dphi * 2 * B / 0.5
    radius = B * 1.5 / 0.5
    for k in range(1, steps + 1):
        u = units * k / steps
        od.update(0.5 * u / REV, 1.0 * u / REV)
        # every intermediate pose lies on the circle centred at (0, radius)
        p = od.pose
        assert math.hypot(p.x_m, p.y_m - radius) == pytest.approx(radius, abs=1e-9)
    p = od.pose
    assert (p.x_m, p.y_m) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert abs(p.heading_rad) < 1e-9 or abs(abs(p.heading_rad) - 2 * math.pi) < 1e-9


def test_new_radii_apply_to_travel_from_now_on_and_bad_radii_are_ignored() -> None:
    od = Odometry(B, R, R, max_step_m=10.0)
    od.update(0.0, 0.0)
    od.update(1.0, 1.0)
    x_before = od.pose.x_m
    assert od.set_radii(0.27, 0.3)
    inc = od.update(2.0, 2.0)
    assert inc is not None
    assert inc.ds_left_m == pytest.approx(2 * math.pi * 0.27)
    assert inc.dphi_rad > 0  # the smaller left wheel makes the chair turn left
    assert x_before == pytest.approx(REV)  # earlier travel was not re-scaled
    for bad in ((math.nan, 0.3), (0.3, -0.1), (0.0, 0.3), (math.inf, 0.3)):
        assert not od.set_radii(*bad)
    assert (od.r_left_m, od.r_right_m) == (0.27, 0.3)
    assert od.rejected_radii_count == 4


def test_a_drive_reboot_is_reported_and_not_integrated() -> None:
    od = Odometry(B, R, R)

    def rev(t: float) -> float:  # 0.5 m/s from 57 rev
        return 57.0 + 0.5 * t / REV

    od.update(rev(0.0), rev(0.0), 0.0)
    for k in range(1, 11):
        assert od.update(rev(0.01 * k), rev(0.01 * k), 0.01 * k) is not None
    pose = od.pose
    assert pose.x_m == pytest.approx(0.05)
    assert od.update(0.0, rev(0.11), 0.11) is None  # left drive rebooted: its position is 0
    assert od.jump_count == 1
    assert od.last_rejection is not None and "left" in od.last_rejection
    assert od.pose == pose
    # integration resumes from the new baseline
    inc = od.update(0.005 / REV, rev(0.12), 0.12)
    assert inc is not None
    assert inc.ds_left_m == pytest.approx(0.005) and inc.ds_right_m == pytest.approx(0.005)
    assert od.pose.x_m == pytest.approx(0.055)


def test_jump_limit_scales_with_the_elapsed_time() -> None:
    od = Odometry(B, R, R, max_wheel_speed_mps=4.0, jump_margin_m=0.05)
    od.update(0.0, 0.0, 0.0)
    step = 0.3 / REV  # 0.3 m of wheel travel
    assert od.update(step, step, 0.01) is None  # 30 m/s: impossible
    assert od.jump_count == 1
    inc = od.update(2 * step, 2 * step, 0.11)  # 0.3 m in 0.1 s: 3 m/s, allowed
    assert inc is not None and inc.dt_s == pytest.approx(0.1)
    # without times the fixed max_step_m applies
    od2 = Odometry(B, R, R, max_step_m=0.2)
    od2.update(0.0, 0.0)
    assert od2.update(step, step) is None
    assert od2.update(step + 0.1 / REV, step + 0.1 / REV) is not None


def test_nonfinite_positions_are_counted_and_travel_is_not_lost() -> None:
    od = Odometry(B, R, R)
    od.update(0.0, 0.0, 0.0)
    assert od.update(math.nan, 0.01, 0.01) is None
    assert od.update(0.02, math.inf, 0.02) is None
    assert od.nonfinite_count == 2 and od.last_rejection == "nonfinite"
    inc = od.update(0.03, 0.03, 0.03)
    assert inc is not None
    assert inc.ds_m == pytest.approx(0.03 * REV)  # all travel since the last good sample
    assert inc.dt_s == pytest.approx(0.03)


def test_increment_components_agree_between_body_and_world_frames() -> None:
    od = Odometry(B, R, R, pose=Pose(0.0, 0.0, 1.0))
    od.update(0.0, 0.0)
    inc = od.update(0.05, 0.08)
    assert inc is not None
    c, s = math.cos(1.0), math.sin(1.0)
    assert inc.dx_m == pytest.approx(c * inc.dx_body_m - s * inc.dy_body_m)
    assert inc.dy_m == pytest.approx(s * inc.dx_body_m + c * inc.dy_body_m)
    assert (od.pose.x_m, od.pose.y_m) == pytest.approx((inc.dx_m, inc.dy_m))
    assert od.pose.heading_rad == pytest.approx(1.0 + inc.dphi_rad)


def test_arc_step_is_continuous_across_its_small_angle_series() -> None:
    a = arc_step(0.0, 0.0, 0.2, 1.0, 1.0 + 4 * B * 0.99999e-4, B)
    b = arc_step(0.0, 0.0, 0.2, 1.0, 1.0 + 4 * B * 1.00001e-4, B)
    assert a[0] == pytest.approx(b[0], abs=1e-8) and a[1] == pytest.approx(b[1], abs=1e-8)


def test_heading_wraps_when_turning_in_place_past_pi() -> None:
    od = Odometry(B, R, R, pose=Pose(0.0, 0.0, 3.1))
    od.update(0.0, 0.0)
    od.update(-0.01, 0.01)  # turn left in place by 2 * 0.01 * REV / (2 B)
    h = od.pose.heading_rad
    assert -math.pi < h <= math.pi
    assert h == pytest.approx(3.1 + 0.02 * REV / (2 * B) - 2 * math.pi)
