"""Pose EKF: the published estimate moves at most the declared step per tick beyond odometry,
however far a fix the filter accepts is; the filter's own belief is not delayed."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import pytest

from controller.odometry import OdometryIncrement, arc_step
from controller.pose_ekf import EstimatorParams, PoseEstimator
from controller.types import Pose, StateEstimate, wrap_angle
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import load

B = 0.3
DT = 0.01
#: The steps alone (a correction within them published at once): the bound these tests hold
#: is the same with the default first-order release, which only releases less per tick.
P = EstimatorParams(correction_time_constant_s=0.0)
STEP_M, STEP_RAD = P.max_correction_step_m, P.max_correction_step_rad
EPS = 1e-12


def _inc(dl: float, dr: float) -> OdometryIncrement:
    ds, dphi = 0.5 * (dl + dr), (dr - dl) / (2 * B)
    return OdometryIncrement(dl, dr, ds, dphi, ds, 0.0, ds, 0.0, DT)


def _xyh(p: Pose) -> tuple[float, float, float]:
    return (p.x_m, p.y_m, p.heading_rad)


def _step(prev: StateEstimate, est: StateEstimate, dl: float, dr: float) -> tuple[float, float]:
    """How far ``est`` is from where the tick's odometry moves ``prev`` (m, rad)."""
    x, y, h, _, _ = arc_step(prev.x_m, prev.y_m, prev.heading_rad, dl, dr, B)
    return math.hypot(est.x_m - x, est.y_m - y), abs(wrap_angle(est.heading_rad - h))


class Tick(NamedTuple):
    step_m: float  # beyond the tick's odometry
    step_rad: float
    accepted: bool  # a fix was fused at this tick
    est: StateEstimate
    truth: tuple[float, float, float]


def _drive(
    ekf: PoseEstimator,
    ticks: int,
    dl: float,
    dr: float,
    localizer: Callable[[float, float, float], Pose],
    truth: list[float],
    t0: int = 0,
) -> list[Tick]:
    """``ticks`` loop ticks: predict with the same travel as the truth, then every 10th tick
    the fix ``localizer`` makes of the truth, then the estimate the controllers would get.
    """
    out = []
    prev = ekf.estimate(t0 * DT)
    for k in range(t0 + 1, t0 + ticks + 1):
        t = k * DT
        x, y, h, _, _ = arc_step(truth[0], truth[1], truth[2], dl, dr, B)
        truth[:] = [x, y, h]
        assert ekf.predict(_inc(dl, dr), t)
        accepted = False
        if k % 10 == 0:
            accepted = ekf.correct(localizer(x, y, h))
        est = ekf.estimate(t)
        assert est.valid
        sm, sr = _step(prev, est, *ekf.travel_m)  # beyond the arc the filter believes
        out.append(Tick(sm, sr, accepted, est, (x, y, h)))
        prev = est
    return out


def _exact(x: float, y: float, h: float) -> Pose:
    return Pose(x, y, h)


def _jumped(cx: float, cy: float) -> Callable[[float, float, float], Pose]:
    """A localizer whose map jumped: turned 0.3 rad about (cx, cy) and shifted 0.3 m."""
    c, s = math.cos(0.3), math.sin(0.3)

    def fix(x: float, y: float, h: float) -> Pose:
        dx, dy = x - cx, y - cy
        return Pose(cx + c * dx - s * dy - 0.3, cy + s * dx + c * dy, wrap_angle(h + 0.3))

    return fix


def test_a_far_fix_accepted_by_the_recovery_is_released_at_most_a_step_per_tick() -> None:
    # the chair drives a gentle arc; then the localizer's map jumps by 0.3 m and 0.3 rad:
    # the gate rejects its fixes, then the recovery accepts them
    ekf = PoseEstimator(B, params=P, pose=Pose(1.0, 2.0, 0.4))
    truth = [1.0, 2.0, 0.4]
    dl, dr = 0.005, 0.0055
    ticks = _drive(ekf, 100, dl, dr, _exact, truth)
    jumped = _jumped(truth[0], truth[1])
    ticks += _drive(ekf, 400, dl, dr, jumped, truth, t0=100)
    assert ekf.gate_recoveries == 1
    steps_m = [t.step_m for t in ticks]
    steps_rad = [t.step_rad for t in ticks]
    assert max(steps_m) <= STEP_M + EPS
    assert max(steps_rad) <= STEP_RAD + EPS
    # ... and the bound was what held the estimate: the correction took several ticks
    assert sum(s > STEP_M - EPS for s in steps_m) >= 10
    assert sum(s > STEP_RAD - EPS for s in steps_rad) >= 10
    # converged: the published estimate is the filter's again, at the fixes, within the
    # ticks the step allows for a 0.3 m / 0.3 rad correction (and a few more fixes)
    k_rec = next(i for i, t in enumerate(ticks) if t.accepted and i >= 100)
    n = math.ceil(max(0.3 / STEP_M, 0.3 / STEP_RAD)) + 20
    for t in ticks[k_rec + n :]:
        est, f = t.est, jumped(*t.truth)
        assert math.hypot(est.x_m - f.x_m, est.y_m - f.y_m) < 0.05
        assert abs(wrap_angle(est.heading_rad - f.heading_rad)) < 0.05
    assert ekf.pending_correction == (0.0, 0.0, 0.0)
    assert ekf.published_pose == ekf.pose


def test_the_recovery_correction_converges_within_the_ticks_the_step_allows() -> None:
    # standing still, the filter confidently 0.3 m and 0.3 rad from where the fixes are
    ekf = PoseEstimator(B, params=P, pose=Pose(0.3, 0.0, 0.3))
    ekf.predict(_inc(0.0, 0.0), 0.0)
    prev = ekf.estimate(0.0)
    n = ekf.params.max_consecutive_rejections
    assert [ekf.correct(Pose(0.0, 0.0, 0.0)) for _ in range(n)] == [False] * (n - 1) + [True]
    dx, dy, dh = ekf.pending_correction
    assert math.hypot(dx, dy) > 0.25 and abs(dh) > 0.25  # the filter moved, not the estimate
    # the fix's tick released one step already
    need = math.ceil(max(math.hypot(dx, dy) / STEP_M, abs(dh) / STEP_RAD)) + 1
    sm, sr = _step(prev, ekf.estimate(0.0), 0.0, 0.0)
    assert sm == pytest.approx(STEP_M) and sr == pytest.approx(STEP_RAD)
    prev = ekf.estimate(0.0)
    for k in range(1, need + 1):
        assert ekf.predict(_inc(0.0, 0.0), k * DT)
        est = ekf.estimate(k * DT)
        sm, sr = _step(prev, est, 0.0, 0.0)
        assert sm <= STEP_M + EPS and sr <= STEP_RAD + EPS
        prev = est
    assert ekf.pending_correction == (0.0, 0.0, 0.0)
    assert (prev.x_m, prev.y_m, prev.heading_rad) == _xyh(ekf.pose)


def test_a_released_heading_correction_turns_the_short_way_across_pi() -> None:
    # the filter believes pi - 0.1; the fixes say -pi + 0.2, 0.3 rad further counter-clockwise
    ekf = PoseEstimator(B, params=P, pose=Pose(0.0, 0.0, math.pi - 0.1))
    ekf.predict(_inc(0.0, 0.0), 0.0)
    for _ in range(ekf.params.max_consecutive_rejections):
        ekf.correct(Pose(0.0, 0.0, -math.pi + 0.2))
    assert ekf.gate_recoveries == 1
    prev = ekf.estimate(0.0)
    headings = []
    for k in range(1, 40):
        ekf.predict(_inc(0.0, 0.0), k * DT)
        est = ekf.estimate(k * DT)
        assert -math.pi < est.heading_rad <= math.pi
        sm, sr = _step(prev, est, 0.0, 0.0)
        assert sm <= STEP_M + EPS and sr <= STEP_RAD + EPS
        # counter-clockwise: each step turns left, never back through 0
        assert wrap_angle(est.heading_rad - prev.heading_rad) >= 0.0
        assert abs(est.heading_rad) > math.pi - 0.25
        headings.append(est.heading_rad)
        prev = est
    assert any(h > 0 for h in headings) and any(h < 0 for h in headings)  # crossed ±pi
    assert ekf.pending_correction == (0.0, 0.0, 0.0)
    assert abs(wrap_angle(prev.heading_rad - (-math.pi + 0.2))) < 0.05


def test_a_correction_within_the_step_is_published_at_once() -> None:
    ekf = PoseEstimator(B, params=P, pose=Pose(0.0, 0.0, 0.0))
    ekf.predict(_inc(0.01, 0.01), DT)
    assert ekf.correct(Pose(0.015, 0.005, 0.01))
    est = ekf.estimate(DT)
    assert ekf.pending_correction == (0.0, 0.0, 0.0)
    assert (est.x_m, est.y_m, est.heading_rad) == _xyh(ekf.pose)


def test_fixes_within_one_tick_share_its_step() -> None:
    # two far fixes in one tick (bunched in real time) may not release two steps
    params = EstimatorParams(max_consecutive_rejections=1, correction_time_constant_s=0.0)
    ekf = PoseEstimator(B, params=params, pose=Pose(0.0, 0.0, 0.0))
    ekf.predict(_inc(0.0, 0.0), DT)
    prev = ekf.estimate(DT)
    assert ekf.correct(Pose(1.0, 0.0, 0.5))
    assert ekf.correct(Pose(1.0, 0.0, 0.5))
    sm, sr = _step(prev, ekf.estimate(DT), 0.0, 0.0)
    assert sm <= STEP_M + EPS and sr <= STEP_RAD + EPS
    # the next tick has its own step
    ekf.predict(_inc(0.0, 0.0), 2 * DT)
    est = ekf.estimate(2 * DT)
    assert est.x_m == pytest.approx(2 * STEP_M, abs=1e-9)
    assert est.heading_rad == pytest.approx(2 * STEP_RAD, abs=1e-9)


def test_nonfinite_input_during_a_release_is_ignored_and_nothing_raises() -> None:
    ekf = PoseEstimator(
        B, params=EstimatorParams(max_consecutive_rejections=1, correction_time_constant_s=0.0)
    )
    ekf.predict(_inc(0.0, 0.0), DT)
    assert ekf.correct(Pose(0.5, 0.0, 0.3))
    pending, published = ekf.pending_correction, ekf.published_pose
    for bad in (math.nan, math.inf, -math.inf):
        assert not ekf.correct(Pose(bad, 0.0, 0.0))
        assert not ekf.correct(Pose(0.0, 0.0, bad))
        assert not ekf.predict(_inc(bad, 0.0), 2 * DT)
        assert not ekf.predict(_inc(0.0, 0.0), bad)
    assert ekf.nonfinite_count == 12
    assert ekf.pending_correction == pending and ekf.published_pose == published
    assert not ekf.estimate(math.nan).valid  # no exception either
    ekf.predict(_inc(0.0, 0.0), 2 * DT)
    est = ekf.estimate(2 * DT)
    assert est.valid and all(math.isfinite(v) for v in (est.x_m, est.y_m, est.heading_rad))
    assert est.x_m == pytest.approx(2 * STEP_M, abs=1e-9)


def test_a_reset_publishes_the_new_pose_at_once() -> None:
    ekf = PoseEstimator(
        B, params=EstimatorParams(max_consecutive_rejections=1, correction_time_constant_s=0.0)
    )
    ekf.predict(_inc(0.0, 0.0), DT)
    assert ekf.correct(Pose(0.5, 0.0, 0.3))
    assert ekf.pending_correction != (0.0, 0.0, 0.0)
    ekf.reset(Pose(3.0, 4.0, -1.0), 0.02)  # arming on a localizer fix: before tracking
    assert ekf.pending_correction == (0.0, 0.0, 0.0)
    assert ekf.published_pose == Pose(3.0, 4.0, -1.0)


def test_the_correction_steps_load_with_units_and_bounds() -> None:
    p = load(
        EstimatorParams,
        {"max_correction_step_m": 0.005, "max_correction_step_rad": 0.01},
        source="est.toml",
    )
    assert (p.max_correction_step_m, p.max_correction_step_rad) == (0.005, 0.01)
    with pytest.raises(ConfigError, match=r"est\.toml.*max_correction_step_m = 0\.0"):
        load(EstimatorParams, {"max_correction_step_m": 0.0}, source="est.toml")
    with pytest.raises(ConfigError, match=r"est\.toml.*max_correction_step_rad = 4\.0"):
        load(EstimatorParams, {"max_correction_step_rad": 4.0}, source="est.toml")


def test_by_default_a_fix_is_released_as_a_first_order_ramp_never_faster_than_the_steps() -> None:
    """The default release: each tick takes dt / tau of what is left (within the steps), so
    a fix's few-centimetre correction reaches the controllers over about the fix period, not
    in one tick; the filter's own pose has it at once; the rest is published at once below
    0.1 mm."""
    params = EstimatorParams()
    tau = params.correction_time_constant_s
    assert tau > 0.0
    ekf = PoseEstimator(B, params=params, pose=Pose(0.0, 0.0, 0.0))
    ekf.predict(_inc(0.01, 0.01), DT)
    assert ekf.correct(Pose(0.03, 0.02, 0.0))
    filt = ekf.pose
    gap0 = math.hypot(filt.x_m - 0.01, filt.y_m)
    assert gap0 > 0.003  # the filter took a good part of the fix
    est0 = ekf.estimate(DT)
    assert (est0.x_m, est0.y_m) == pytest.approx((0.01, 0.0), abs=1e-12)  # not yet published
    gaps, steps = [], []
    prev = est0
    for k in range(2, 40):
        ekf.predict(_inc(0.0, 0.0), k * DT)
        est = ekf.estimate(k * DT)
        steps.append(math.hypot(est.x_m - prev.x_m, est.y_m - prev.y_m))
        f = ekf.pose
        gaps.append(math.hypot(f.x_m - est.x_m, f.y_m - est.y_m))
        prev = est
    assert steps[0] == pytest.approx(gap0 * DT / tau, rel=1e-6)  # a share, not all of it
    assert max(steps) <= min(STEP_M, gap0 * DT / tau) + EPS
    assert gaps[9] < gap0 * (1 - DT / tau) ** 10 * 1.01  # first order over about the fix period
    assert gaps[-1] == 0.0  # published whole once below 0.1 mm
