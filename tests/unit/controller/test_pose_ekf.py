"""Pose EKF: dead reckoning without fixes, bounded error with fixes, gating, wrap, covariance."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from controller.odometry import Odometry, OdometryIncrement, arc_step
from controller.planner import load_route, plan
from controller.pose_ekf import EstimatorParams, PoseEstimator
from controller.types import Pose, wrap_angle
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import load

B = 0.3
R = 0.3
REV = 2 * math.pi * R
PAPER = Path(__file__).resolve().parents[3] / "scenarios" / "routes" / "paper.toml"


def _inc(dl: float, dr: float, dt: float = 0.01) -> OdometryIncrement:
    ds, dphi = 0.5 * (dl + dr), (dr - dl) / (2 * B)
    return OdometryIncrement(dl, dr, ds, dphi, ds, 0.0, ds, 0.0, dt)


def _assert_spd(P: np.ndarray) -> None:
    assert np.array_equal(P, P.T)
    assert np.linalg.eigvalsh(P).min() > 0.0


def test_without_fixes_the_filter_is_dead_reckoning() -> None:
    rng = np.random.default_rng(1)
    od = Odometry(B, R, R, pose=Pose(1.0, -2.0, 3.0))
    ekf = PoseEstimator(B, pose=Pose(1.0, -2.0, 3.0))
    left = right = 0.0
    od.update(left, right, 0.0)
    for k in range(1, 3001):
        left += rng.uniform(-0.002, 0.008)
        right += rng.uniform(-0.002, 0.008)
        inc = od.update(left, right, 0.01 * k)
        assert inc is not None
        assert ekf.predict(inc, 0.01 * k)
    a, b = od.pose, ekf.pose
    assert (b.x_m, b.y_m) == pytest.approx((a.x_m, a.y_m), abs=1e-9)
    assert wrap_angle(b.heading_rad - a.heading_rad) == pytest.approx(0.0, abs=1e-12)
    _assert_spd(ekf.covariance)


def _drive_paper_route(with_fixes: bool, seed: int = 7):
    """Truth from the paper route's reference; the left tire is 4 % smaller than believed."""
    traj = plan(load_route(PAPER))
    dt = 0.01
    t = np.arange(0.0, traj.duration_s, dt)
    ref = traj.sample_many(t)
    rng = np.random.default_rng(seed)
    r_true_left = 0.96 * R
    truth = (0.0, 0.0, 0.0)
    rev_l = rev_r = 0.0
    od = Odometry(B, R, R)
    ekf = PoseEstimator(B, pose=Pose(*truth))
    od.update(rev_l, rev_r, 0.0)
    dr_err, ekf_err = [], []
    for k in range(1, t.size):
        v, w = ref["v_mps"][k], ref["omega_radps"][k]
        dl, dr = (v - B * w) * dt, (v + B * w) * dt
        x, y, phi, _, _ = arc_step(*truth, dl, dr, B)
        truth = (x, y, phi)
        rev_l += dl / (2 * math.pi * r_true_left)
        rev_r += dr / REV
        inc = od.update(rev_l, rev_r, t[k])
        assert inc is not None
        ekf.predict(inc, t[k])
        if with_fixes and k % 20 == 0:  # 5 Hz fixes, 5 cm / 0.03 rad noise
            ekf.correct(
                Pose(
                    x + rng.normal(0, 0.05),
                    y + rng.normal(0, 0.05),
                    wrap_angle(phi + rng.normal(0, 0.03)),
                )
            )
        dr_err.append(math.hypot(od.pose.x_m - x, od.pose.y_m - y))
        e = ekf.pose
        ekf_err.append(math.hypot(e.x_m - x, e.y_m - y))
    return np.array(dr_err), np.array(ekf_err), ekf


def test_with_a_biased_radius_and_noisy_fixes_the_error_stays_bounded() -> None:
    dr_err, ekf_err, ekf = _drive_paper_route(with_fixes=True)
    assert dr_err[-1] > 2.0  # dead reckoning drifts by metres over the route
    assert ekf_err.max() < 0.2  # the EKF stays within a few fix sigmas all along
    assert ekf_err[-1000:].mean() < 0.1
    assert ekf.fixes_accepted > 0.95 * (ekf.fixes_accepted + ekf.fixes_rejected)
    _assert_spd(ekf.covariance)


def test_an_outlier_fix_is_rejected_and_good_ones_are_not() -> None:
    ekf = PoseEstimator(B)
    for _ in range(5):
        assert ekf.correct(Pose(0.0, 0.0, 0.0))
    before = ekf.pose
    assert not ekf.correct(Pose(3.0, -2.0, 0.0))  # 3.6 m away
    assert not ekf.correct(Pose(0.0, 0.0, 1.5))  # heading 1.5 rad off
    assert ekf.fixes_rejected == 2
    assert ekf.pose == before
    assert ekf.last_mahalanobis2 > ekf.params.gate_chi2
    assert ekf.correct(Pose(0.02, -0.01, 0.01))


def test_persistent_disagreement_is_recovered_after_consecutive_rejections() -> None:
    # the filter is confidently wrong by 2 m; consistent fixes eventually win
    ekf = PoseEstimator(B, pose=Pose(2.0, 0.0, 0.0))
    n = ekf.params.max_consecutive_rejections
    results = [ekf.correct(Pose(0.0, 0.0, 0.0)) for _ in range(n)]
    assert results == [False] * (n - 1) + [True]
    assert ekf.gate_recoveries == 1
    assert abs(ekf.pose.x_m) < 0.1
    assert ekf.correct(Pose(0.0, 0.0, 0.0))  # normal operation afterwards
    _assert_spd(ekf.covariance)


def test_heading_residual_wraps_across_pi() -> None:
    ekf = PoseEstimator(B, pose=Pose(0.0, 0.0, math.pi - 0.01))
    # the fix is 0.02 rad further counter-clockwise, i.e. just below -pi + 0.01
    assert ekf.correct(Pose(0.0, 0.0, -math.pi + 0.01))
    h = ekf.pose.heading_rad
    assert -math.pi < h <= math.pi
    assert abs(wrap_angle(h - math.pi)) < 0.02  # near ±pi, not pulled through 0
    # prediction across ±pi too: turn left in place by 0.1 rad
    ekf.predict(_inc(-0.1 * B, 0.1 * B), 0.01)
    h2 = ekf.pose.heading_rad
    assert -math.pi < h2 <= math.pi
    assert wrap_angle(h2 - h) == pytest.approx(0.1, abs=1e-12)


def test_covariance_stays_symmetric_positive_definite() -> None:
    rng = np.random.default_rng(3)
    ekf = PoseEstimator(B)
    for k in range(1, 5001):
        ekf.predict(_inc(*rng.uniform(-0.005, 0.015, 2)), 0.01 * k)
        if k % 7 == 0:
            p = ekf.pose
            off = 5.0 if rng.random() < 0.05 else 0.0  # some outliers
            ekf.correct(
                Pose(
                    p.x_m + rng.normal(0, 0.05) + off,
                    p.y_m + rng.normal(0, 0.05),
                    wrap_angle(p.heading_rad + rng.normal(0, 0.03)),
                )
            )
        if k % 50 == 0:
            _assert_spd(ekf.covariance)
    assert ekf.fixes_rejected > 0


NO_SCALE = EstimatorParams(scale_initial_std=0.0, scale_drift_std_per_sqrt_m=0.0)


def test_process_noise_grows_with_distance_travelled_not_with_time() -> None:
    # the wheels' own noise alone (no differential-scale state): linear in distance
    still, short, long_ = (PoseEstimator(B, NO_SCALE) for _ in range(3))
    p0 = np.trace(still.covariance)
    for k in range(1, 101):
        still.predict(_inc(0.0, 0.0), 0.01 * k)
        short.predict(_inc(0.001, 0.001), 0.01 * k)
        long_.predict(_inc(0.01, 0.01), 0.01 * k)
    assert np.trace(still.covariance) == pytest.approx(p0)
    assert p0 < np.trace(short.covariance) < np.trace(long_.covariance)
    # heading variance grows roughly linearly in distance: 10x the travel, ~10x the growth
    g_short = short.covariance[2, 2] - still.covariance[2, 2]
    g_long = long_.covariance[2, 2] - still.covariance[2, 2]
    assert 8.0 < g_long / g_short < 12.0


def test_nonfinite_inputs_are_counted_and_ignored() -> None:
    ekf = PoseEstimator(B)
    ekf.predict(_inc(0.01, 0.01), 0.01)
    before, cov = ekf.pose, ekf.covariance
    assert not ekf.predict(_inc(math.nan, 0.01), 0.02)
    assert not ekf.predict(_inc(0.01, 0.01), math.inf)
    assert not ekf.correct(Pose(math.nan, 0.0, 0.0))
    assert not ekf.correct(Pose(0.0, 0.0, math.inf))
    assert ekf.nonfinite_count == 4
    assert ekf.pose == before
    assert np.array_equal(ekf.covariance, cov)


def test_estimate_carries_latest_interval_velocity_and_staleness() -> None:
    ekf = PoseEstimator(B, params=EstimatorParams(odometry_timeout_s=0.1))
    assert not ekf.estimate(0.0).valid  # no odometry yet
    ekf.predict(_inc(0.004, 0.006, dt=0.01), 1.00)
    est = ekf.estimate(1.00)
    assert est.valid and est.t_s == 1.00
    assert est.v_mps == pytest.approx(0.5)
    assert est.omega_radps == pytest.approx(0.002 / (2 * B) / 0.01)
    assert ekf.estimate(1.09).valid
    assert not ekf.estimate(1.11).valid
    # an increment without dt uses the time since the previous prediction
    ekf.predict(_inc(0.01, 0.01, dt=math.nan), 1.02)
    assert ekf.estimate(1.02).v_mps == pytest.approx(0.5)


def test_estimator_params_load_with_units_and_bounds() -> None:
    p = load(EstimatorParams, {"fix_pos_std_m": 0.1}, source="est.toml")
    assert p.fix_pos_std_m == 0.1
    with pytest.raises(ConfigError, match=r"est\.toml.*fix_pos_std_m = -1\.0"):
        load(EstimatorParams, {"fix_pos_std_m": -1.0}, source="est.toml")
    with pytest.raises(ConfigError, match="unknown key 'pos_std'"):
        load(EstimatorParams, {"pos_std": 1.0}, source="est.toml")


def test_the_written_out_prediction_is_filterpys_predict() -> None:
    """P' = F P F' + Q and x' = f(x, u), with filterpy's F, Q and priors, for any motion."""
    from filterpy.kalman import ExtendedKalmanFilter

    rng = np.random.default_rng(7)
    ekf = PoseEstimator(B, pose=Pose(0.5, -1.0, 3.1))
    ekf.rebase_scale(1.0, 0.9)  # a differential scale of about 0.1, so that delta acts
    ref = ExtendedKalmanFilter(dim_x=4, dim_z=3)
    for k in range(1, 400):
        inner = ekf.filter
        ref.x, ref.P = inner.x.copy(), inner.P.copy()
        d = float(ref.x[3])
        dl, dr = rng.uniform(-0.02, 0.03, 2)
        assert ekf.predict(_inc(dl, dr), 0.01 * k)
        inner = ekf.filter  # its arrays, filled from the prediction's floats
        ref.F, ref.Q = inner.F, inner.Q
        ref.predict_x = lambda u=0: None  # the state step is the arc, checked below
        ref.predict()
        x0, y0, phi0, _ = ref.x.tolist()
        x, y, phi, _, _ = arc_step(x0, y0, phi0, dl * (1 - d / 2), dr * (1 + d / 2), B)
        np.testing.assert_allclose(inner.x, [x, y, phi, d], rtol=0, atol=1e-12)
        np.testing.assert_allclose(inner.P, ref.P, rtol=1e-12, atol=1e-18)
        assert np.array_equal(inner.x_prior, inner.x) and np.array_equal(inner.P_prior, inner.P)
        _assert_spd(inner.P)


def test_fixes_between_predictions_see_the_predicted_state_and_are_seen_after() -> None:
    """The per-tick prediction works on floats: a fix must be fused into the predicted
    state (not the one of the last fix), and pose, estimate, covariance and the filterpy
    filter must all show the corrected state afterwards.  ``seen`` is read before each
    fix (its filter is the reference for the hand-written update); ``blind`` is not."""
    rng = np.random.default_rng(3)
    # the correction published at once (no first-order release): estimate() shows it too
    at_once = EstimatorParams(correction_time_constant_s=0.0)
    seen = PoseEstimator(B, params=at_once, pose=Pose(1.0, 2.0, 0.5))
    blind = PoseEstimator(B, params=at_once, pose=Pose(1.0, 2.0, 0.5))
    R = np.diag([seen.params.fix_pos_std_m**2] * 2 + [seen.params.fix_heading_std_rad**2])
    t = 0.0
    for _ in range(30):
        for _ in range(int(rng.integers(1, 12))):
            t += 0.01
            inc = _inc(*rng.uniform(0.0, 0.02, 2))
            assert seen.predict(inc, t) and blind.predict(inc, t)
        f = seen.filter
        x, P = f.x.copy(), f.P.copy()
        assert seen.pose == Pose(*x.tolist()[:3])
        z = x[:3] + rng.normal(0.0, [0.03, 0.03, 0.02])
        y = z - x[:3]
        y[2] = wrap_angle(float(y[2]))
        H = np.hstack([np.eye(3), np.zeros((3, 1))])
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        I_KH = np.eye(4) - K @ H
        x_new = x + K @ y
        P_new = I_KH @ P @ I_KH.T + K @ R @ K.T
        assert seen.correct(Pose(*z.tolist())) and blind.correct(Pose(*z.tolist()))
        for est in (blind, seen):
            pose = est.pose
            assert (pose.x_m, pose.y_m) == pytest.approx((x_new[0], x_new[1]), abs=1e-12)
            e = est.estimate(t)
            assert (e.x_m, e.y_m, e.heading_rad) == (pose.x_m, pose.y_m, pose.heading_rad)
            np.testing.assert_allclose(est.covariance, P_new[:3, :3], rtol=1e-9, atol=1e-15)
            np.testing.assert_allclose(est.filter.P, P_new, rtol=1e-9, atol=1e-15)
            np.testing.assert_allclose(est.filter.x, x_new, rtol=0, atol=1e-12)


def _worst_error_with_flat_tire(params: EstimatorParams, seed: int) -> tuple[float, float]:
    """15 s straight ahead at 1.1 m/s believed, while the left tire, 16 % smaller than the
    odometry believes (a physical flat tire), makes the chair circle; fixes at 10 Hz with the
    assumed noise.  The filter's worst position and heading error after the first second."""
    b, v, dt = 0.28, 1.1, 0.01
    rng = np.random.default_rng(seed)
    ekf = PoseEstimator(b, params)
    truth = (0.0, 0.0, 0.0)
    worst_m = worst_rad = 0.0
    for k in range(1, 1501):
        truth = arc_step(*truth, 0.84 * v * dt, v * dt, b)[:3]
        ds = v * dt
        ekf.predict(OdometryIncrement(ds, ds, ds, 0.0, ds, 0.0, ds, 0.0, dt), k * dt)
        if k % 10 == 0:
            x, y, h = truth
            ekf.correct(
                Pose(x + rng.normal(0, 0.05), y + rng.normal(0, 0.05), h + rng.normal(0, 0.03))
            )
        if k > 100:
            p = ekf.pose
            worst_m = max(worst_m, math.hypot(p.x_m - truth[0], p.y_m - truth[1]))
            worst_rad = max(worst_rad, abs(wrap_angle(p.heading_rad - truth[2])))
    return worst_m, worst_rad


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_flat_tire_drifts_the_belief_at_most_three_fixes_long(seed: int) -> None:
    # The gate cannot tell the odometry's systematic error from a localizer outlier; the
    # recovery after 3 fixes (0.3 s) bounds how far the belief drifts before it follows the
    # fixes again.  The former 10 fixes (1 s) let it drift 0.34-0.40 m and 0.42-0.44 rad.
    # That is the pose-only filter's bound; learning the differential scale does better.
    worst_m, worst_rad = _worst_error_with_flat_tire(NO_SCALE, seed)
    assert worst_m < 0.25 and worst_rad < 0.26
    slow_m, slow_rad = _worst_error_with_flat_tire(
        dataclasses.replace(NO_SCALE, max_consecutive_rejections=10), seed
    )
    assert slow_m > 0.3 and slow_rad > 0.38
    learnt_m, learnt_rad = _worst_error_with_flat_tire(EstimatorParams(), seed)
    assert learnt_m < 0.2 and learnt_rad < 0.5 * worst_rad


def test_scale_uncertainty_makes_heading_variance_grow_faster_than_distance() -> None:
    # an unknown differential scale turns the heading by delta ds / (2 b): its variance
    # adds (ds / 2b)^2 var(delta), quadratic in distance
    short, long_ = PoseEstimator(B), PoseEstimator(B)
    base_s, base_l = PoseEstimator(B, NO_SCALE), PoseEstimator(B, NO_SCALE)
    for k in range(1, 101):
        for e, d in ((short, 0.001), (long_, 0.01), (base_s, 0.001), (base_l, 0.01)):
            e.predict(_inc(d, d), 0.01 * k)
    extra_s = short.covariance[2, 2] - base_s.covariance[2, 2]
    extra_l = long_.covariance[2, 2] - base_l.covariance[2, 2]
    assert extra_s > 0.0
    assert extra_l / extra_s > 50.0  # ~100 for a fixed delta, less its random walk's part


def test_without_scale_state_the_filter_is_the_three_state_one() -> None:
    # delta held at 0 with zero variance: the pose and its covariance are the pose-only EKF's
    rng = np.random.default_rng(3)
    a = PoseEstimator(B, NO_SCALE, pose=Pose(0.0, 0.0, 0.2))
    assert a.scale == 0.0
    for k in range(1, 400):
        dl, dr = 0.011 + rng.normal(0, 1e-4), 0.01 + rng.normal(0, 1e-4)
        a.predict(_inc(dl, dr), 0.01 * k)
        if k % 10 == 0:
            q, e = a.pose, rng.normal(0, 0.02, 3)
            a.correct(Pose(q.x_m + e[0], q.y_m + e[1], q.heading_rad + e[2]))
    P = a.filter.P
    assert a.scale == 0.0
    assert np.all(P[3, :] == 0.0) and np.all(P[:, 3] == 0.0)


def test_the_filter_learns_a_soft_tire_and_stops_drifting_between_fixes() -> None:
    """A right wheel 16 % smaller than believed (the evaluation's largest flat): the odometry
    turns the heading 0.29 rad/s too little at 1 m/s.  With fixes every 0.1 s the filter
    learns delta = -0.16 within a few metres; then the heading it predicts between two fixes
    stays within the fixes' noise of the truth instead of drifting 29 mrad per fix."""
    rng = np.random.default_rng(4)
    ekf = PoseEstimator(B, pose=Pose(0.0, 0.0, 0.0))
    true_scale = 0.84  # the right wheel travels 0.84 of what the encoder says
    x = y = phi = 0.0
    dt, v = 0.01, 1.0
    gaps = []
    for k in range(1, 1501):
        dl = dr = v * dt
        x, y, phi, _, _ = arc_step(x, y, phi, dl, dr * true_scale, B)
        ekf.predict(_inc(dl, dr), k * dt)
        if k % 10 == 0:
            if k > 1000:  # the heading the filter predicted, just before the fix
                gaps.append(abs(wrap_angle(ekf.pose.heading_rad - phi)))
            ekf.correct(
                Pose(x + rng.normal(0, 0.02), y + rng.normal(0, 0.02), phi + rng.normal(0, 0.01))
            )
    assert ekf.scale == pytest.approx(-0.16, abs=0.02)
    assert np.percentile(gaps, 90) < 0.02
    # the pose-only filter in the same ride: the drift between fixes stays
    base = PoseEstimator(B, NO_SCALE, pose=Pose(0.0, 0.0, 0.0))
    x = y = phi = 0.0
    base_gaps = []
    for k in range(1, 1501):
        x, y, phi, _, _ = arc_step(x, y, phi, v * dt, v * dt * true_scale, B)
        base.predict(_inc(v * dt, v * dt), k * dt)
        if k % 10 == 0:
            if k > 1000:
                base_gaps.append(abs(wrap_angle(base.pose.heading_rad - phi)))
            base.correct(Pose(x, y, phi))
    assert np.median(base_gaps) > 0.02


def test_rebasing_the_scale_keeps_the_travels_the_filter_believes() -> None:
    # the odometry starts to report 0.95 and 1.05 of what it did (new radii): delta is
    # rebased so that the same wheel turns still move the filter by the same travels
    ekf = PoseEstimator(B)
    ekf.rebase_scale(1.0, 0.9)  # delta = 1 / 0.9 - 1 = 0.111
    assert ekf.scale == pytest.approx(1.0 / 0.9 - 1.0)
    ekf.predict(_inc(0.01, 0.01), 0.01)
    before = ekf.travel_m
    ekf.rebase_scale(0.95, 1.05)
    ekf.predict(_inc(0.01 * 0.95, 0.01 * 1.05), 0.02)
    assert ekf.travel_m == pytest.approx(before, rel=1e-3)  # without the rebase: 5 % off
    ekf.rebase_scale(math.nan, 1.0)  # refused, counted
    assert ekf.nonfinite_count == 1


def test_a_scale_held_at_its_bound_is_counted_not_silent() -> None:
    # a right wheel that travels half of what its encoder says, for a metre of fixes: the
    # heading the fixes show asks for a differential scale of about -0.67, beyond scale_max
    # (0.1 here); it is held there, and each correction or rebase that hit the bound counts
    params = EstimatorParams(scale_max=0.1, scale_drift_std_per_sqrt_m=0.2)
    ekf = PoseEstimator(B, params)
    truth = Pose(0.0, 0.0, 0.0)
    for k in range(200):
        ekf.predict(_inc(0.01, 0.01), 0.01 * (k + 1))
        x, y, h, _, _ = arc_step(truth.x_m, truth.y_m, truth.heading_rad, 0.01, 0.005, B)
        truth = Pose(x, y, h)
        if k % 10 == 9:
            ekf.correct(truth)
    assert ekf.scale == pytest.approx(-0.1)
    assert ekf.scale_held > 0
    held = ekf.scale_held
    ekf.rebase_scale(1.0, 2.0)  # asks for delta = 1.1 / 2 - 1.05 / 1: far beyond -0.1
    assert ekf.scale == pytest.approx(-0.1)
    assert ekf.scale_held == held + 1


def test_after_a_fix_the_filters_priors_are_still_the_predictions() -> None:
    """filterpy's update() leaves x_prior and P_prior as the prediction set them; so do the
    floats behind PoseEstimator.filter, whether or not the filter was read in between."""
    seen = PoseEstimator(B, pose=Pose(0.0, 0.0, 0.0))  # read after the prediction
    blind = PoseEstimator(B, pose=Pose(0.0, 0.0, 0.0))  # read only after the fix
    for est in (seen, blind):
        assert est.predict(_inc(0.010, 0.012), 0.01)
    x_pred, P_pred = seen.filter.x.copy(), seen.filter.P.copy()
    for est in (seen, blind):
        assert est.correct(Pose(0.03, -0.02, 0.01))
        f = est.filter
        assert not np.array_equal(f.x, x_pred)  # the fix moved the state
        assert np.array_equal(f.x_prior, x_pred) and np.array_equal(f.P_prior, P_pred)
        assert f.K.shape == (4, 3) and np.isfinite(f.y).all()
