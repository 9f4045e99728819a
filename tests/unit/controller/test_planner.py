"""Reference planner: quintic path geometry, jerk-limited profile, limits, comfort, stops."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from controller import comfort
from controller.planner import QuinticPath, RouteParams, load_route, plan
from controller.types import Trajectory
from dbc.runtime.errors import ConfigError

ROOT = Path(__file__).resolve().parents[3]
PAPER = ROOT / "scenarios" / "routes" / "paper.toml"

SMALL = RouteParams(
    waypoints_m=((0.0, 0.0), (3.0, 0.5), (5.0, 3.0), (3.0, 5.0), (0.5, 4.0), (-1.0, 1.5)),
    start_heading_rad=0.3,
    stops=((2, 3.0),),
)


@pytest.fixture(scope="module")
def paper_route() -> RouteParams:
    return load_route(PAPER)


@pytest.fixture(scope="module")
def paper(paper_route: RouteParams):
    return plan(paper_route)


@pytest.fixture(scope="module")
def small():
    return plan(SMALL)


@pytest.fixture(scope="module")
def dense(paper):
    t = np.arange(0.0, paper.duration_s, 1e-3)
    return paper.sample_many(t)


# ----------------------------------------------------------------------------- path


def test_path_passes_through_every_waypoint(paper_route: RouteParams, paper) -> None:
    path = paper.path
    pts = path.point(path.knots)
    np.testing.assert_allclose(pts.T, np.asarray(paper_route.waypoints_m), atol=1e-9)


def test_path_is_c2_across_knots_and_its_polynomials_join(paper) -> None:
    path = paper.path
    for i in range(1, path.n_seg):
        h = path.knots[i] - path.knots[i - 1]
        for c in (path.cx, path.cy):
            left = np.poly1d(c[i - 1])
            right = np.poly1d(c[i])
            for d in range(3):  # value, first and second derivative
                lv = left.deriv(d)(h) if d else left(h)
                rv = right.deriv(d)(0.0) if d else right(0.0)
                assert lv == pytest.approx(rv, abs=1e-8), (i, d)
    # and by finite differences: heading and curvature do not jump at the knots
    eps = 1e-7
    knots = path.knots[1:-1]
    for f in (path.heading, path.curvature):
        jump = np.abs(f(knots + eps) - f(knots - eps))
        assert jump.max() < 1e-5


def test_curvature_and_its_derivative_match_finite_differences(paper) -> None:
    path = paper.path
    s = np.linspace(0.5, path.length_m - 0.5, 400)
    h = 1e-4
    tau, tp, tm = path.tau_of_s(s), path.tau_of_s(s + h), path.tau_of_s(s - h)
    dphi = np.angle(np.exp(1j * (path.heading(tp) - path.heading(tm)))) / (2 * h)
    np.testing.assert_allclose(path.curvature(tau), dphi, atol=2e-6)
    dk = (path.curvature(tp) - path.curvature(tm)) / (2 * h)
    np.testing.assert_allclose(path.curvature_derivative(tau), dk, atol=2e-5)


def test_arc_length_parametrization_is_unit_speed(paper) -> None:
    path = paper.path
    s = np.linspace(0.0, path.length_m - 1e-3, 2000)
    h = 1e-5
    step = np.hypot(*(path.point(path.tau_of_s(s + h)) - path.point(path.tau_of_s(s))))
    np.testing.assert_allclose(step / h, 1.0, atol=1e-5)
    # the fast table the trajectory samples with agrees with the Newton inverse
    np.testing.assert_allclose(path.tau_of_s_fast(s), path.tau_of_s(s), atol=1e-8)


def test_heading_equals_atan2_of_the_path_tangent(dense) -> None:
    x, y, hd = dense["x_m"], dense["y_m"], dense["heading_rad"]
    moving = dense["v_mps"] > 0.05
    dx, dy = np.gradient(x), np.gradient(y)
    tangent = np.arctan2(dy, dx)
    err = np.angle(np.exp(1j * (tangent - hd)))[moving]
    assert np.abs(err).max() < 1e-4


def test_start_heading_is_respected(small) -> None:
    assert small.sample(0.0).heading_rad == pytest.approx(0.3, abs=1e-12)


# ----------------------------------------------------------------------------- profile


def test_profile_starts_and_ends_at_exactly_zero_speed_and_acceleration(paper) -> None:
    for t in (0.0, paper.duration_s):
        r = paper.sample(t)
        assert r.v_mps == 0.0 and r.a_mps2 == 0.0 and r.omega_radps == 0.0
    assert paper.sample(paper.duration_s).done
    assert not paper.sample(paper.duration_s - 1e-3).done
    # and it gets there continuously
    assert paper.sample(1e-4).v_mps < 1e-6
    assert abs(paper.sample(paper.duration_s - 1e-4).v_mps) < 1e-6
    assert abs(paper.sample(paper.duration_s - 1e-4).a_mps2) < 1e-3


def test_profile_respects_every_limit(paper_route: RouteParams, dense) -> None:
    r, tol = paper_route, 1e-9
    v, a, k, w = dense["v_mps"], dense["a_mps2"], dense["curvature_1pm"], dense["omega_radps"]
    assert v.min() >= -tol
    assert v.max() <= r.v_max_mps + tol
    assert a.max() <= r.a_max_mps2 + tol
    assert a.min() >= -r.d_max_mps2 - tol
    assert (np.abs(k) * v * v).max() <= r.a_lat_max_mps2 + tol
    assert np.abs(w).max() <= r.omega_max_radps + tol
    jerk = np.diff(a) / 1e-3
    assert np.abs(jerk).max() <= r.jerk_max_mps3 * (1 + 1e-6)
    # the limits are actually reached: the profile is not trivially slow
    assert v.max() > 0.99 * r.v_max_mps
    assert a.max() > 0.99 * r.a_max_mps2
    assert (np.abs(k) * v * v).max() > 0.9 * r.a_lat_max_mps2 or np.abs(w).max() > 0.9


def test_acceleration_is_continuous(dense) -> None:
    # 1 ms apart, the acceleration never jumps by more than the jerk limit allows
    assert np.abs(np.diff(dense["a_mps2"])).max() <= 1.0 * 1e-3 * (1 + 1e-6)


def test_omega_is_curvature_times_speed(dense) -> None:
    np.testing.assert_allclose(dense["omega_radps"], dense["curvature_1pm"] * dense["v_mps"])


def test_numeric_derivatives_of_samples_match_the_sampled_rates(paper) -> None:
    rng = np.random.default_rng(4)
    h = 1e-5
    for t in rng.uniform(0.01, paper.duration_s - 0.01, 300):
        r, rp, rm = paper.sample(t), paper.sample(t + h), paper.sample(t - h)
        c, s = math.cos(r.heading_rad), math.sin(r.heading_rad)
        assert (rp.x_m - rm.x_m) / (2 * h) == pytest.approx(r.v_mps * c, abs=1e-6)
        assert (rp.y_m - rm.y_m) / (2 * h) == pytest.approx(r.v_mps * s, abs=1e-6)
        dphi = math.remainder(rp.heading_rad - rm.heading_rad, 2 * math.pi)
        assert dphi / (2 * h) == pytest.approx(r.omega_radps, abs=1e-6)
        assert (rp.v_mps - rm.v_mps) / (2 * h) == pytest.approx(r.a_mps2, abs=1e-5)
        assert (rp.omega_radps - rm.omega_radps) / (2 * h) == pytest.approx(
            r.alpha_radps2, abs=1e-4
        )
        assert (rp.s_m - rm.s_m) / (2 * h) == pytest.approx(r.v_mps, abs=1e-6)


def test_sample_and_sample_many_agree(small) -> None:
    t = np.concatenate(([-1.0, 0.0], np.linspace(0.0, small.duration_s + 2.0, 501)))
    many = small.sample_many(t)
    for i, ti in enumerate(t):
        r = small.sample(float(ti))
        for key in ("x_m", "y_m", "heading_rad", "v_mps", "omega_radps", "a_mps2", "s_m"):
            assert getattr(r, key) == pytest.approx(many[key][i], abs=1e-9), (ti, key)
        assert r.done == bool(many["done"][i])


def test_samples_outside_the_route_hold_a_pose_at_rest(paper, paper_route) -> None:
    end_x, end_y = paper_route.waypoints_m[-1]
    for t in (paper.duration_s, paper.duration_s + 0.01, paper.duration_s + 1e6):
        r = paper.sample(t)
        assert r.done and r.t_s == t
        assert (r.v_mps, r.omega_radps, r.a_mps2, r.alpha_radps2) == (0.0, 0.0, 0.0, 0.0)
        assert (r.x_m, r.y_m) == pytest.approx((end_x, end_y), abs=1e-9)
        assert r.s_m == paper.length_m
    for t in (-5.0, -1e-9, float("nan")):
        r = paper.sample(t)
        assert not r.done and r.v_mps == 0.0 and r.a_mps2 == 0.0
        assert (r.x_m, r.y_m, r.heading_rad) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


def test_trajectory_implements_the_protocol(paper) -> None:
    assert isinstance(paper, Trajectory)
    assert paper.duration_s > 0 and paper.length_m > 0


# ----------------------------------------------------------------------------- stops


def test_a_stop_pauses_the_reference_at_its_waypoint_for_the_dwell_time(small) -> None:
    dt = 1e-3
    t = np.arange(0.0, small.duration_s, dt)
    m = small.sample_many(t)
    s_stop = small.path.knot_s[2]
    at_stop = (np.abs(m["s_m"] - s_stop) < 1e-9) & (m["v_mps"] == 0.0)
    assert at_stop.sum() * dt == pytest.approx(3.0, abs=2 * dt)
    idx = np.flatnonzero(at_stop)
    assert np.all(np.diff(idx) == 1)  # one contiguous pause
    assert not m["done"][idx].any()
    np.testing.assert_allclose(m["x_m"][idx], 5.0, atol=1e-9)
    np.testing.assert_allclose(m["y_m"][idx], 3.0, atol=1e-9)
    # moving before and after
    assert m["v_mps"][idx[0] - 200] > 0 and m["v_mps"][idx[-1] + 200] > 0


# ----------------------------------------------------------------------------- comfort


def test_comfort_bound_holds_and_report_matches_an_independent_computation(paper) -> None:
    rep = paper.comfort_report()
    assert rep.a_v_mps2 <= rep.bound_mps2
    assert rep.limit_scale == 1.0
    fs = 100.0
    m = paper.sample_many(np.arange(0.0, paper.duration_s + 1 / fs, 1 / fs))
    awx = comfort.weighted_rms(m["a_mps2"], fs, "x")
    awy = comfort.weighted_rms(m["curvature_1pm"] * m["v_mps"] ** 2, fs, "y")
    assert rep.awx_rms_mps2 == pytest.approx(awx, rel=1e-9)
    assert rep.awy_rms_mps2 == pytest.approx(awy, rel=1e-9)
    assert rep.a_v_mps2 == pytest.approx(1.4 * math.hypot(awx, awy), rel=1e-9)
    assert rep.peak_v_mps <= 1.1 + 1e-9 and rep.peak_omega_radps <= 1.0 + 1e-9


def test_a_strict_comfort_bound_replans_with_lower_limits(paper_route: RouteParams) -> None:
    from dataclasses import replace

    route = replace(paper_route, comfort_rms_max_mps2=0.05)
    traj = plan(route)
    rep = traj.comfort_report()
    assert rep.a_v_mps2 <= 0.05
    assert rep.limit_scale < 1.0
    assert rep.peak_accel_mps2 < route.a_max_mps2
    assert traj.duration_s > plan(paper_route).duration_s


def test_an_unreachable_comfort_bound_is_a_config_error(paper_route: RouteParams) -> None:
    from dataclasses import replace

    with pytest.raises(ConfigError, match="comfort_rms_max_mps2"):
        plan(replace(paper_route, comfort_rms_max_mps2=1e-5))


# ----------------------------------------------------------------------------- route file


def _segments_cross(p: np.ndarray) -> int:
    """Number of proper self-intersections of a polyline (non-adjacent segments)."""
    a, b = p[:-1], p[1:]
    count = 0
    for i in range(len(a)):
        j = np.arange(i + 2, len(a))
        if j.size == 0:
            continue
        d1 = b[i] - a[i]
        c, d = a[j], b[j]
        d2 = d - c
        den = d1[0] * d2[:, 1] - d1[1] * d2[:, 0]
        ok = np.abs(den) > 1e-12
        w = c - a[i]
        u = (w[:, 0] * d2[:, 1] - w[:, 1] * d2[:, 0]) / np.where(ok, den, 1)
        v = (w[:, 0] * d1[1] - w[:, 1] * d1[0]) / np.where(ok, den, 1)
        count += int(np.sum(ok & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)))
    return count


def test_paper_route_has_loops_gentle_and_tight_sections_and_lasts_about_80_s(paper) -> None:
    assert 70.0 <= paper.duration_s <= 90.0
    path = paper.path
    s = np.arange(0.0, path.length_m, 0.05)
    tau = path.tau_of_s(s)
    assert _segments_cross(path.point(tau).T) >= 2  # at least two loops crossing themselves
    k = np.abs(path.curvature(tau))
    assert k.max() > 1.0  # tight turns (radius below 1 m)
    gentle = k < 0.1
    # a long gentle section: at least 8 m in a row with a radius above 10 m
    run = best = 0
    for g in gentle:
        run = run + 1 if g else 0
        best = max(best, run)
    assert best * 0.05 >= 8.0
    # ends at the STOP waypoint at rest
    r = paper.sample(paper.duration_s)
    assert (r.x_m, r.y_m) == pytest.approx((-6.0, -7.0))


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "route.toml"
    p.write_text(text)
    return p


def test_route_with_unknown_key_names_file_and_key(tmp_path: Path) -> None:
    p = _write(tmp_path, "waypoints_m = [[0, 0], [1, 0]]\nv_max = 1.0\n")
    with pytest.raises(ConfigError, match=r"route\.toml.*'v_max'"):
        load_route(p)


def test_route_with_out_of_range_value_names_file_key_and_bound(tmp_path: Path) -> None:
    p = _write(tmp_path, "waypoints_m = [[0, 0], [1, 0]]\nv_max_mps = 9.0\n")
    with pytest.raises(ConfigError, match=r"route\.toml.*v_max_mps = 9\.0 is above its maximum 3"):
        load_route(p)


@pytest.mark.parametrize(
    ("body", "pattern"),
    [
        ("waypoints_m = [[0, 0]]", "at least 2"),
        ("waypoints_m = [[0, 0], [0, 0.01], [2, 0]]", r"waypoints_m\[1\].*apart"),
        ("waypoints_m = [[0, 0], [1, 0, 3]]", r"waypoints_m\[1\] must be \[x, y\]"),
        ("waypoints_m = [[0, 0], [1, 0], [2, 0]]\nstops = [[2, 1.0]]", r"stops\[0\].*interior"),
        ("waypoints_m = [[0, 0], [1, 0], [2, 0]]\nstops = [[1.5, 1.0]]", r"stops\[0\].*integer"),
        ("waypoints_m = [[0, 0], [1, 0], [2, 0]]\nstops = [[1, 0.0]]", r"stops\[0\].*dwell"),
        ("waypoints_m = [[0, 0], [1, 0]]\nstart_heading_rad = 4.0", "start_heading_rad"),
        (
            "waypoints_m = [[0, 0], [1, 0]]\njerk_max_mps3 = 0.0",
            "jerk_max_mps3 = 0.0 must be above",
        ),
    ],
)
def test_bad_route_files_are_config_errors(tmp_path: Path, body: str, pattern: str) -> None:
    with pytest.raises(ConfigError, match=pattern):
        load_route(_write(tmp_path, body + "\n"))


def test_a_straight_two_point_route_plans(tmp_path: Path) -> None:
    traj = plan(RouteParams(waypoints_m=((0.0, 0.0), (5.0, 0.0))))
    r = traj.sample(traj.duration_s / 2)
    assert r.y_m == pytest.approx(0.0, abs=1e-12) and r.curvature_1pm == pytest.approx(0.0)
    assert traj.length_m == pytest.approx(5.0, abs=1e-9)


def test_quintic_path_without_start_heading_is_natural() -> None:
    path = QuinticPath(((0.0, 0.0), (2.0, 1.0), (4.0, 0.0)))
    assert abs(path.curvature(np.array([0.0, path.knots[-1]]))).max() < 1e-9


@pytest.mark.parametrize(
    "waypoints",
    [
        ((0.0, 0.0), (2.0, 0.0), (0.5, 0.0)),  # drives out and straight back: a cusp
        ((0.0, 0.0), (2.0, 0.0), (2.06, 0.0), (0.0, 0.1)),  # needle-sharp hairpin
    ],
)
def test_a_path_that_reverses_on_itself_is_a_config_error(waypoints) -> None:
    with pytest.raises(ConfigError, match=r"my\.toml: waypoints_m\[\d\]\.\.\[\d\].*cusp"):
        plan(RouteParams(waypoints_m=waypoints), source="my.toml")
