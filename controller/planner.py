"""The reference planner: route parameters, quintic-spline path, comfort-bounded speed profile.

This module owns the virtual robot the tracking controllers follow (the paper's "trajectory
planner", section *Time scale separation*):

* :class:`RouteParams` / :func:`load_route` -- the route as typed parameters from TOML
  (waypoints, optional start heading, stops with dwell times, profile limits, comfort bound);
* :class:`QuinticPath` -- a piecewise quintic through the waypoints, parametrized by
  cumulative chord length τ.  The derivatives at the waypoints are those of the C⁴ quintic
  interpolating spline with end conditions r'' = 0 (zero curvature) and r''' = 0 at the final
  waypoint and r'' = 0 plus r' = (cos φ0, sin φ0) (or r''' = 0 if no heading is given) at the
  first one.  That spline minimizes ∫|r'''|² dτ among all interpolants, which for a nearly
  unit-speed parametrization is the integrated squared *curvature variation* -- the paper's
  "antifragile" planning goal of limiting curvature changes.  Position, heading, curvature and
  dk/ds are therefore continuous.  Curvature uses the paper's Eq. (curvature) with the
  exponent 3/2, k = (ẋÿ − ẍẏ)/(ẋ² + ẏ²)^{3/2}, and dk/ds is its analytic derivative;
* the speed profile (see :func:`plan`): a time-optimal profile under v_max, a_max, d_max,
  v²|k| ≤ a_lat_max and v|k| ≤ ω_max on a fine arc-length grid, turned jerk-limited by a
  moving average of width T = (a_max + d_max)/j_max in time (computed exactly, so the result
  is piecewise cubic in time with continuous acceleration and |jerk| ≤ j_max), with the
  curvature limits pre-eroded over the distance the average can shift the chair so they still
  hold afterwards.  If the ISO 2631-1 weighted r.m.s. acceleration of the reference exceeds
  the comfort bound, all acceleration limits are scaled by f < 1 (and v_max by √f) and the
  profile is replanned;
* :class:`SplineTrajectory` -- the :class:`~controller.types.Trajectory` the loop samples every
  tick and predictive controllers preview: precomputed tables, ``bisect`` and local
  polynomial evaluation in plain floats.

Pure computation: no bus, no clock, no logging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from controller import comfort
from controller.kernels import spline_geometry, spline_sample
from controller.types import ReferenceSample
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import load, load_toml, param

# ----------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class RouteParams:
    """A route: where to drive, where to pause, and the limits of the reference's motion."""

    waypoints_m: tuple[tuple[float, ...], ...] = param(
        ((0.0, 0.0), (4.0, 0.0), (8.0, 2.0)),
        unit="m",
        doc="(x, y) points the path passes through, in driving order (world frame)",
        lo=-10000.0,
        hi=10000.0,
    )
    start_heading_rad: float | None = param(
        None,
        unit="rad",
        doc="heading at the first waypoint; omitted: free (natural end condition)",
        lo=-math.pi,
        hi=math.pi,
    )
    stops: tuple[tuple[float, ...], ...] = param(
        (),
        unit="(index, s)",
        doc="pauses: [interior waypoint index, dwell time in s] at rest",
        lo=0.0,
        hi=100000.0,
    )
    v_max_mps: float = param(1.1, unit="m/s", doc="speed limit", lo=0.0, lo_open=True, hi=3.0)
    a_max_mps2: float = param(
        0.5, unit="m/s^2", doc="longitudinal acceleration limit", lo=0.0, lo_open=True, hi=3.0
    )
    d_max_mps2: float = param(
        0.5, unit="m/s^2", doc="longitudinal deceleration limit", lo=0.0, lo_open=True, hi=5.0
    )
    a_lat_max_mps2: float = param(
        0.6, unit="m/s^2", doc="lateral (centripetal) acceleration limit v^2|k|", lo=0.0,
        lo_open=True, hi=5.0,
    )  # fmt: skip
    jerk_max_mps3: float = param(
        1.0, unit="m/s^3", doc="longitudinal jerk limit", lo=0.0, lo_open=True, hi=50.0
    )
    omega_max_radps: float = param(
        1.0, unit="rad/s", doc="yaw rate limit v|k|", lo=0.0, lo_open=True, hi=6.0
    )
    comfort_rms_max_mps2: float = param(
        0.315,
        unit="m/s^2",
        doc="bound on the ISO 2631-1 weighted rms vector value of the reference acceleration",
        lo=0.0,
        lo_open=True,
        hi=10.0,
    )
    comfort_k_horizontal: float = param(
        1.4,
        unit="1",
        doc="ISO 2631-1 multiplying factor of the horizontal axes (1.4 health, 1.0 comfort)",
        lo=1.0,
        hi=1.4,
    )


#: Minimum distance between consecutive waypoints.
MIN_WAYPOINT_SPACING_M = 0.05


def validate_route(route: RouteParams, source: str = "RouteParams") -> None:
    """Check what per-key bounds cannot: enough distinct waypoints, stops at interior ones."""
    wps = route.waypoints_m
    for i, wp in enumerate(wps):
        if len(wp) != 2:
            raise ConfigError(f"{source}: waypoints_m[{i}] must be [x, y] (m), got {list(wp)}")
    if len(wps) < 2:
        raise ConfigError(f"{source}: waypoints_m needs at least 2 points, got {len(wps)}")
    for i in range(1, len(wps)):
        d = math.dist(wps[i - 1], wps[i])
        if d < MIN_WAYPOINT_SPACING_M:
            raise ConfigError(
                f"{source}: waypoints_m[{i}] is {d:.3g} m from the previous one; "
                f"consecutive waypoints must be at least {MIN_WAYPOINT_SPACING_M} m apart"
            )
    seen: set[int] = set()
    for j, stop in enumerate(route.stops):
        if len(stop) != 2 or stop[0] != int(stop[0]):
            raise ConfigError(
                f"{source}: stops[{j}] must be [waypoint index (integer), dwell (s)], "
                f"got {list(stop)}"
            )
        idx, dwell = int(stop[0]), stop[1]
        if not 1 <= idx <= len(wps) - 2:
            raise ConfigError(
                f"{source}: stops[{j}] waypoint index {idx} must be an interior waypoint "
                f"(1..{len(wps) - 2}); the route starts and ends at rest anyway"
            )
        if idx in seen:
            raise ConfigError(f"{source}: stops[{j}] repeats waypoint index {idx}")
        if not dwell > 0.0:
            raise ConfigError(f"{source}: stops[{j}] dwell {dwell} s must be above 0 (s)")
        seen.add(idx)


def route_from_table(table: dict[str, Any] | None, *, source: str, prefix: str = "") -> RouteParams:
    """Build and validate a route from a TOML table (e.g. a scenario's ``[route]``)."""
    route = load(RouteParams, table, source=source, prefix=prefix)
    validate_route(route, source)
    return route


def load_route(path: str | Path) -> RouteParams:
    """Load a route file like ``scenarios/routes/paper.toml`` (keys at top level)."""
    return route_from_table(load_toml(path), source=str(path))


# ----------------------------------------------------------------------------- path

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_SUBDIV = 16  # arc-length quadrature sub-intervals per spline segment
_TAB_DS_M = 0.02  # τ(s) table spacing


class QuinticPath:
    """Piecewise quintic r(τ) = (x(τ), y(τ)) through the waypoints, τ = cumulative chord length.

    Vectorized accessors take τ (or s) arrays; see the module doc for the derivative choice.
    """

    def __init__(
        self, waypoints_m: tuple[tuple[float, ...], ...], start_heading_rad: float | None = None
    ) -> None:
        pts = np.asarray(waypoints_m, dtype=float)
        chords = np.hypot(*np.diff(pts, axis=0).T)
        self.knots = np.concatenate(([0.0], np.cumsum(chords)))
        n_seg = len(chords)
        right = [(2, 0.0), (3, 0.0)]
        coeffs = []
        # scipy.interpolate and scipy.ndimage here and in plan(): 0.5-0.9 s of import that
        # the processes which never plan a route (the recorder) would pay at every start
        from scipy.interpolate import PPoly, make_interp_spline  # lazy: see above

        for axis in (0, 1):
            if start_heading_rad is None:
                left = [(2, 0.0), (3, 0.0)]
            else:
                d1 = math.cos(start_heading_rad) if axis == 0 else math.sin(start_heading_rad)
                left = [(1, d1), (2, 0.0)]
            spl = make_interp_spline(self.knots, pts[:, axis], k=5, bc_type=(left, right))
            pp = PPoly.from_spline(spl)
            keep = np.diff(pp.x) > 0.0
            coeffs.append(pp.c[:, keep].T.copy())  # (n_seg, 6), highest power first
        #: per-segment coefficients in u = τ - knots[i], highest power first
        self.cx, self.cy = coeffs
        assert self.cx.shape == (n_seg, 6)
        self.n_seg = n_seg
        self.waypoints = pts
        self._build_arclength()
        self._build_tau_table()

    # -- evaluation in τ --------------------------------------------------------------------

    def _seg(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        i = np.clip(np.searchsorted(self.knots, tau, side="right") - 1, 0, self.n_seg - 1)
        return i, tau - self.knots[i]

    def derivatives(self, tau: np.ndarray | float, order: int = 3) -> np.ndarray:
        """Array (order+1, 2, n) of r, r', r'', r''' ... with respect to τ."""
        tau = np.atleast_1d(np.asarray(tau, dtype=float))
        i, u = self._seg(tau)
        out = np.empty((order + 1, 2, tau.size))
        for axis, c in enumerate((self.cx, self.cy)):
            cc = c[i].T  # (6, n)
            for d in range(order + 1):
                # coefficients of the d-th derivative, highest power first
                deg = 5 - d
                acc = np.zeros(tau.size)
                for p in range(deg, -1, -1):
                    factor = math.perm(p + d, d)
                    acc = acc * u + factor * cc[5 - (p + d)]
                out[d, axis] = acc
        return out

    def point(self, tau: np.ndarray | float) -> np.ndarray:
        """(2, n) positions."""
        return self.derivatives(tau, 0)[0]

    def heading(self, tau: np.ndarray | float) -> np.ndarray:
        """Heading (rad) of the path's tangent at ``tau``, shape (n,)."""
        d = self.derivatives(tau, 1)[1]
        return np.arctan2(d[1], d[0])

    def curvature(self, tau: np.ndarray | float) -> np.ndarray:
        """k = (ẋÿ − ẍẏ)/(ẋ² + ẏ²)^{3/2} (1/m), analytic from the spline derivatives."""
        _, d1, d2 = self.derivatives(tau, 2)
        sp2 = d1[0] ** 2 + d1[1] ** 2
        return (d1[0] * d2[1] - d2[0] * d1[1]) / sp2**1.5

    def curvature_derivative(self, tau: np.ndarray | float) -> np.ndarray:
        """dk/ds (1/m²), analytic: (dk/dτ)/|r'|."""
        _, d1, d2, d3 = self.derivatives(tau, 3)
        return _dk_ds(d1[0], d1[1], d2[0], d2[1], d3[0], d3[1])

    # -- arc length ---------------------------------------------------------------------------

    def _speed(self, tau: np.ndarray) -> np.ndarray:
        d1 = self.derivatives(tau, 1)[1]
        return np.hypot(d1[0], d1[1])

    def _build_arclength(self) -> None:
        sub = np.concatenate(
            [
                np.linspace(self.knots[i], self.knots[i + 1], _SUBDIV + 1)[:-1]
                for i in range(self.n_seg)
            ]
            + [self.knots[-1:]]
        )
        a, b = sub[:-1], sub[1:]
        inc = self._gauss(a, b)
        self._sub_tau = sub
        self._sub_s = np.concatenate(([0.0], np.cumsum(inc)))
        self.length_m = float(self._sub_s[-1])
        self.knot_s = self.s_of_tau(self.knots)

    def _gauss(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """∫_a^b |r'(τ)| dτ by 8-point Gauss-Legendre (vectorized over intervals)."""
        mid, half = 0.5 * (a + b), 0.5 * (b - a)
        taus = mid[None, :] + half[None, :] * _GL_X[:, None]
        sp = self._speed(taus.ravel()).reshape(taus.shape)
        return half * (_GL_W[:, None] * sp).sum(axis=0)

    def s_of_tau(self, tau: np.ndarray | float) -> np.ndarray:
        """Arc length (m) from the start to parameter τ, accurate to ~1e-12 m."""
        t = np.clip(np.atleast_1d(np.asarray(tau, dtype=float)), 0.0, self.knots[-1])
        j = np.clip(np.searchsorted(self._sub_tau, t, side="right") - 1, 0, len(self._sub_tau) - 2)
        return self._sub_s[j] + self._gauss(self._sub_tau[j], t)

    def tau_of_s(self, s: np.ndarray | float) -> np.ndarray:
        """Inverse of :meth:`s_of_tau` by Newton iteration (accurate, vectorized)."""
        s = np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, self.length_m)
        tau = np.interp(s, self._sub_s, self._sub_tau)
        for _ in range(4):
            tau = np.clip(tau - (self.s_of_tau(tau) - s) / self._speed(tau), 0.0, self.knots[-1])
        return tau

    def _build_tau_table(self) -> None:
        """Uniform-in-s table of τ with cubic Hermite cells, for fast scalar lookups."""
        n = max(1, math.ceil(self.length_m / _TAB_DS_M))
        h = self.length_m / n
        s = np.linspace(0.0, self.length_m, n + 1)
        tau = self.tau_of_s(s)
        m = 1.0 / self._speed(tau)  # dτ/ds
        t0, t1, m0, m1 = tau[:-1], tau[1:], m[:-1], m[1:]
        c2 = (3.0 * (t1 - t0) / h - 2.0 * m0 - m1) / h
        c3 = (m0 + m1 - 2.0 * (t1 - t0) / h) / (h * h)
        seg = np.clip(np.searchsorted(self.knots, t0, side="right") - 1, 0, self.n_seg - 1)
        self.tab_h = h
        self.tab_n = n
        self.tab = (t0, m0, c2, c3, seg)

    def tau_of_s_fast(self, s: np.ndarray) -> np.ndarray:
        """Table lookup of τ(s) (the one :class:`SplineTrajectory` uses), vectorized."""
        s = np.clip(np.asarray(s, dtype=float), 0.0, self.length_m)
        k = np.minimum((s / self.tab_h).astype(np.int64), self.tab_n - 1)
        w = s - k * self.tab_h
        t0, m0, c2, c3, _ = self.tab
        return t0[k] + w * (m0[k] + w * (c2[k] + w * c3[k]))


def _dk_ds(dx, dy, ddx, ddy, dddx, dddy):
    sp2 = dx * dx + dy * dy
    sp = sp2**0.5
    cross = dx * ddy - ddx * dy
    dk_dtau = (dx * dddy - dddx * dy) / (sp2 * sp) - 3.0 * cross * (dx * ddx + dy * ddy) / (
        sp2 * sp2 * sp
    )
    return dk_dtau / sp


# ----------------------------------------------------------------------------- profile

_PROFILE_DS_M = 0.01  # arc-length grid of the time-optimal pass
_LIMIT_MARGIN = 0.995  # keep the curvature limits strictly inside after the smoothing
_COMFORT_FS_HZ = 100.0
_MIN_SCALE = 0.02


@dataclass(frozen=True, slots=True)
class ComfortReport:
    """Figures of a planned reference (what docs/planner.md and the evaluation print)."""

    length_m: float
    duration_s: float
    awx_rms_mps2: float  # Wd-weighted rms of the longitudinal acceleration dv/dt
    awy_rms_mps2: float  # Wd-weighted rms of the lateral acceleration k v^2
    a_v_mps2: float  # k_h * sqrt(awx^2 + awy^2)
    k_horizontal: float
    bound_mps2: float
    mtvv_x_mps2: float  # peak 1 s running rms, longitudinal
    mtvv_y_mps2: float  # peak 1 s running rms, lateral
    peak_v_mps: float
    peak_accel_mps2: float
    peak_decel_mps2: float
    peak_lat_accel_mps2: float
    peak_jerk_mps3: float
    peak_omega_radps: float
    peak_alpha_radps2: float
    peak_curvature_1pm: float
    limit_scale: float  # factor applied to the acceleration limits to meet the bound (1 = none)

    def as_dict(self) -> dict[str, float]:
        """The figures by field name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _time_optimal_leg(v_lim: np.ndarray, ds: float, a_max: float, d_max: float) -> np.ndarray:
    """Speeds on a uniform s grid, zero at both ends, under v_lim and accel/decel limits."""
    vl2 = (v_lim * v_lim).tolist()
    n = len(vl2)
    v2 = [0.0] * n
    da, dd = 2.0 * a_max * ds, 2.0 * d_max * ds
    for i in range(1, n - 1):
        v2[i] = min(vl2[i], v2[i - 1] + da)
    v2[n - 1] = 0.0
    for i in range(n - 2, 0, -1):
        v2[i] = min(v2[i], v2[i + 1] + dd)
    return np.sqrt(np.asarray(v2))


class _RawProfile:
    """Piecewise constant-acceleration profile (breakpoints t, s, v, a) plus Q = ∫ s dt."""

    def __init__(self, t: np.ndarray, s: np.ndarray, v: np.ndarray, a: np.ndarray, length: float):
        dt = np.diff(t)
        q_inc = s[:-1] * dt + v[:-1] * dt**2 / 2 + a[:-1] * dt**3 / 6
        self.t, self.s, self.v, self.a = t, s, v, a
        self.q = np.concatenate(([0.0], np.cumsum(q_inc)))
        self.length = length
        self.t_end = float(t[-1])

    def eval(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """s, v, a (right limit) and Q at times t, extended at rest before 0 and after the end."""
        i = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 1)
        u = t - self.t[i]
        s0, v0, a0 = self.s[i], self.v[i], self.a[i]
        s = s0 + u * (v0 + 0.5 * a0 * u)
        v = v0 + a0 * u
        q = self.q[i] + u * (s0 + u * (0.5 * v0 + a0 * u / 6.0))
        a = a0.copy()
        before = t < 0.0
        for arr in (s, v, a, q):
            arr[before] = 0.0
        return s, v, a, q


def _raw_profile(
    path: QuinticPath, route: RouteParams, scale: float, t_smooth: float
) -> _RawProfile:
    """Time-optimal (jerk-unlimited) profile with stops, on the arc-length grid."""
    v_max = route.v_max_mps * math.sqrt(scale)
    a_max, d_max = route.a_max_mps2 * scale, route.d_max_mps2 * scale
    a_lat, w_max = (
        route.a_lat_max_mps2 * scale * _LIMIT_MARGIN,
        route.omega_max_radps * _LIMIT_MARGIN,
    )
    dwell = {int(i): d for i, d in route.stops}
    bounds = [0.0] + [float(path.knot_s[i]) for i in sorted(dwell)] + [path.length_m]
    dwells = [dwell[i] for i in sorted(dwell)]
    ts, ss, vs, as_ = [], [], [], []
    from scipy.ndimage import minimum_filter1d  # lazy: see QuinticPath

    t0 = 0.0
    for leg, (sa, sb) in enumerate(pairwise(bounds)):
        n = max(2, math.ceil((sb - sa) / _PROFILE_DS_M))
        s = np.linspace(sa, sb, n + 1)
        ds = (sb - sa) / n
        k = np.abs(path.curvature(path.tau_of_s(s)))
        with np.errstate(divide="ignore"):
            v_lim = np.minimum(v_max, np.minimum(np.sqrt(a_lat / k), w_max / k))
        radius = v_max * t_smooth + 2.0 * ds
        v_lim = minimum_filter1d(v_lim, size=2 * math.ceil(radius / ds) + 1, mode="nearest")
        v = _time_optimal_leg(v_lim, ds, a_max, d_max)
        dt = 2.0 * ds / (v[:-1] + v[1:])
        a = (v[1:] ** 2 - v[:-1] ** 2) / (2.0 * ds)
        t = t0 + np.concatenate(([0.0], np.cumsum(dt)))
        ts.append(t[:-1])
        ss.append(s[:-1])
        vs.append(v[:-1])
        as_.append(a)
        t0 = float(t[-1])
        if leg < len(dwells):  # at rest at the stop for dwell + T, so dwell survives smoothing
            ts.append(np.array([t0]))
            ss.append(np.array([sb]))
            vs.append(np.array([0.0]))
            as_.append(np.array([0.0]))
            t0 += dwells[leg] + t_smooth
    # final rest piece
    ts.append(np.array([t0]))
    ss.append(np.array([path.length_m]))
    vs.append(np.array([0.0]))
    as_.append(np.array([0.0]))
    return _RawProfile(
        np.concatenate(ts), np.concatenate(ss), np.concatenate(vs), np.concatenate(as_),
        path.length_m,
    )  # fmt: skip


def _smooth(raw: _RawProfile, t_smooth: float) -> tuple[np.ndarray, ...]:
    """Exact moving average of width T of the raw profile: piecewise cubic s(t), shifted by T/2.

    Returns breakpoints and per-piece (s0, v0, a0, jerk), the first piece starting at t = 0.
    """
    h = 0.5 * t_smooth
    b = np.concatenate((raw.t - h, raw.t + h))
    b.sort()
    keep = np.concatenate(([True], np.diff(b) > 1e-9))
    b = b[keep]
    sp, vp, _, qp = raw.eval(b + h)
    sm, vm, _, qm = raw.eval(b - h)
    s0 = (qp - qm) / t_smooth
    v0 = (sp - sm) / t_smooth
    a0 = (vp - vm) / t_smooth
    mid = np.append(0.5 * (b[:-1] + b[1:]), b[-1] + 1.0)
    _, _, a_hi, _ = raw.eval(mid + h)
    _, _, a_lo, _ = raw.eval(mid - h)
    jerk = (a_hi - a_lo) / t_smooth
    s0 = np.clip(s0, 0.0, raw.length)
    # the last breakpoint (raw end + h) starts the final rest
    s0[-1], v0[-1], a0[-1], jerk[-1] = raw.length, 0.0, 0.0, 0.0
    return b + h, s0, v0, a0, jerk


# ----------------------------------------------------------------------------- trajectory


class SplineTrajectory:
    """A planned route as a time-parametrized reference (implements ``Trajectory``).

    Before t = 0 it holds the start pose at rest; from ``duration_s`` on the final pose at rest
    with ``done=True``.  A non-finite t gives the start pose (nothing raises at tick time).
    """

    def __init__(
        self,
        route: RouteParams,
        path: QuinticPath,
        profile: tuple[np.ndarray, ...],
        limit_scale: float,
        t_smooth_s: float,
    ) -> None:
        self.route = route
        self.path = path
        self.limit_scale = limit_scale
        self.t_smooth_s = t_smooth_s
        pt, ps, pv, pa, pj = profile
        self._pt_arr, self._ps_arr, self._pv_arr, self._pa_arr, self._pj_arr = profile
        self._duration = float(pt[-1])
        self._length = path.length_m
        # plain-float tables for the scalar fast path
        self._pt: list[float] = pt.tolist()
        self._ps: list[float] = ps.tolist()
        self._pv: list[float] = pv.tolist()
        self._pa: list[float] = pa.tolist()
        self._pj6: list[float] = (pj / 6.0).tolist()
        self._pj: list[float] = pj.tolist()
        t0, m0, c2, c3, seg = path.tab
        self._tab = list(
            zip(t0.tolist(), m0.tolist(), c2.tolist(), c3.tolist(), seg.tolist(), strict=True)
        )
        self._tab_inv_h = 1.0 / path.tab_h
        self._tab_h = path.tab_h
        self._tab_last = path.tab_n - 1
        self._knots: list[float] = path.knots.tolist()
        self._seg_coef = [_segment_tuple(path.cx[i], path.cy[i]) for i in range(path.n_seg)]
        # the kernels' arguments (controller.kernels.spline_sample, spline_geometry)
        self._profile = (self._pt, self._ps, self._pv, self._pa, self._pj, self._pj6)
        self._geo = (
            self._tab,
            self._tab_h,
            self._tab_inv_h,
            self._tab_last,
            self._knots,
            self._seg_coef,
        )
        self._start = self._at_rest(0.0, 0.0, False)
        self._comfort: ComfortReport | None = None

    # -- protocol --------------------------------------------------------------------------

    @property
    def duration_s(self) -> float:
        """Time from the start to the route's end, in s."""
        return self._duration

    @property
    def length_m(self) -> float:
        """Arc length of the path, in m."""
        return self._length

    def _at_rest(self, t_s: float, s: float, done: bool) -> ReferenceSample:
        g = self._geometry(s)
        return ReferenceSample(t_s, g[0], g[1], g[2], 0.0, 0.0, 0.0, 0.0, g[3], s, done)

    def _geometry(self, s: float) -> tuple[float, float, float, float, float]:
        """x, y, heading, k, dk/ds at arc length s (scalar, plain floats;
        :func:`controller.kernels.spline_geometry`)."""
        return spline_geometry(s, *self._geo)

    def sample(self, t_s: float) -> ReferenceSample:
        """The virtual robot at ``t_s`` (s since the route started)."""
        t_s = float(t_s)  # numpy scalars would make every operation below several times slower
        if not t_s > 0.0:
            if t_s == 0.0 or t_s != t_s:
                return self._start
            return ReferenceSample(t_s, *_rest_fields(self._start))
        if t_s >= self._duration:
            return self._at_rest(t_s, self._length, True)
        x, y, hd, v, w, a, alpha, k, s = spline_sample(t_s, self._profile, self._length, *self._geo)
        return ReferenceSample(t_s, x, y, hd, v, w, a, alpha, k, s, False)

    def sample_many(self, t_s: np.ndarray) -> dict[str, np.ndarray]:
        """Vectorized :meth:`sample`: one array per :class:`ReferenceSample` field."""
        t = np.asarray(t_s, dtype=float).ravel()
        t_c = np.where(np.isfinite(t), t, 0.0)
        i = np.clip(np.searchsorted(self._pt_arr, t_c, side="right") - 1, 0, len(self._pt) - 1)
        u = t_c - self._pt_arr[i]
        a0, j, v0 = self._pa_arr[i], self._pj_arr[i], self._pv_arr[i]
        s = self._ps_arr[i] + u * (v0 + u * (0.5 * a0 + u * j / 6.0))
        v = v0 + u * (a0 + 0.5 * j * u)
        a = a0 + j * u
        before = ~(t_c > 0.0)
        done = t_c >= self._duration
        rest = before | done
        s = np.where(before, 0.0, np.where(done, self._length, np.clip(s, 0.0, self._length)))
        v = np.where(rest, 0.0, v)
        a = np.where(rest, 0.0, a)
        tau = self.path.tau_of_s_fast(s)
        _, d1, d2, d3 = self.path.derivatives(tau, 3)
        r = self.path.point(tau)
        sp2 = d1[0] ** 2 + d1[1] ** 2
        k = (d1[0] * d2[1] - d2[0] * d1[1]) / sp2**1.5
        dk = _dk_ds(d1[0], d1[1], d2[0], d2[1], d3[0], d3[1])
        return {
            "t_s": t,
            "x_m": r[0],
            "y_m": r[1],
            "heading_rad": np.arctan2(d1[1], d1[0]),
            "v_mps": v,
            "omega_radps": k * v,
            "a_mps2": a,
            "alpha_radps2": dk * v * v + k * a,
            "curvature_1pm": k,
            "s_m": s,
            "done": done,
        }

    # -- figures ---------------------------------------------------------------------------

    def comfort_report(self) -> ComfortReport:
        """Weighted rms, MTVV and peak figures of the reference (computed once, cached)."""
        if self._comfort is None:
            self._comfort = _comfort_of(self)
        return self._comfort


def _rest_fields(r: ReferenceSample) -> tuple[Any, ...]:
    return (r.x_m, r.y_m, r.heading_rad, 0.0, 0.0, 0.0, 0.0, r.curvature_1pm, r.s_m, r.done)


def _segment_tuple(cx: np.ndarray, cy: np.ndarray) -> tuple[float, ...]:
    """Flat coefficient tuple of one segment: r, r' (less the constant), r'', r''' per axis."""
    x5, x4, x3, x2, x1, x0 = (float(c) for c in cx)
    y5, y4, y3, y2, y1, y0 = (float(c) for c in cy)
    return (
        x5, x4, x3, x2, x1, x0, y5, y4, y3, y2, y1, y0,
        5 * x5, 4 * x4, 3 * x3, 2 * x2, 5 * y5, 4 * y4, 3 * y3, 2 * y2,
        20 * x5, 12 * x4, 6 * x3, 20 * y5, 12 * y4, 6 * y3,
        60 * x5, 24 * x4, 6 * x3, 60 * y5, 24 * y4, 6 * y3,
    )  # fmt: skip


def _comfort_of(traj: SplineTrajectory) -> ComfortReport:
    fs = _COMFORT_FS_HZ
    t = np.arange(0.0, traj.duration_s + 1.0 / fs, 1.0 / fs)
    r = traj.sample_many(t)
    a_lon = r["a_mps2"]
    a_lat = r["curvature_1pm"] * r["v_mps"] ** 2
    awx = comfort.weight(a_lon, fs, "x")
    awy = comfort.weight(a_lat, fs, "y")
    rx, ry = float(np.sqrt(np.mean(awx**2))), float(np.sqrt(np.mean(awy**2)))
    kh = traj.route.comfort_k_horizontal
    return ComfortReport(
        length_m=traj.length_m,
        duration_s=traj.duration_s,
        awx_rms_mps2=rx,
        awy_rms_mps2=ry,
        a_v_mps2=comfort.vector_value(rx, ry, kx=kh, ky=kh),
        k_horizontal=kh,
        bound_mps2=traj.route.comfort_rms_max_mps2,
        mtvv_x_mps2=comfort.mtvv(awx, fs),
        mtvv_y_mps2=comfort.mtvv(awy, fs),
        peak_v_mps=float(np.max(r["v_mps"])),
        peak_accel_mps2=float(max(0.0, np.max(a_lon))),
        peak_decel_mps2=float(max(0.0, -np.min(a_lon))),
        peak_lat_accel_mps2=float(np.max(np.abs(a_lat))),
        peak_jerk_mps3=float(np.max(np.abs(traj._pj_arr))),
        peak_omega_radps=float(np.max(np.abs(r["omega_radps"]))),
        peak_alpha_radps2=float(np.max(np.abs(r["alpha_radps2"]))),
        peak_curvature_1pm=float(np.max(np.abs(traj.path.curvature(traj.path._sub_tau)))),
        limit_scale=traj.limit_scale,
    )


#: Path geometry a wheelchair reference can follow: |r'| must stay near the chord-length speed
#: (a slower parametrization means the spline nearly stops, i.e. a cusp) and turns must be
#: wider than this radius.
MIN_PARAM_SPEED = 0.1
MIN_TURN_RADIUS_M = 0.05


def _check_geometry(path: QuinticPath, source: str = "route") -> None:
    """Reject cusps and needle-sharp turns, which no speed profile can make drivable."""
    tau = np.concatenate(
        [np.linspace(path.knots[i], path.knots[i + 1], 200) for i in range(path.n_seg)]
    )
    seg = np.repeat(np.arange(path.n_seg), 200)
    speed = path._speed(tau)
    k = np.abs(path.curvature(tau))
    bad = (speed < MIN_PARAM_SPEED) | ~np.isfinite(k) | (k > 1.0 / MIN_TURN_RADIUS_M)
    if bad.any():
        i = int(seg[np.argmax(bad)])
        raise ConfigError(
            f"{source}: waypoints_m[{i}]..[{i + 1}]: the spline through them has a cusp or a "
            f"turn tighter than {MIN_TURN_RADIUS_M} m radius (path reverses on itself); "
            "add or spread waypoints there"
        )


def _plan_scaled(route: RouteParams, path: QuinticPath, scale: float) -> SplineTrajectory:
    t_smooth = (route.a_max_mps2 + route.d_max_mps2) / route.jerk_max_mps3  # scale-invariant
    raw = _raw_profile(path, route, scale, t_smooth)
    return SplineTrajectory(route, path, _smooth(raw, t_smooth), scale, t_smooth)


def plan(route: RouteParams, source: str = "route") -> SplineTrajectory:
    """Plan the reference for ``route``: path, jerk-limited profile, comfort bound.

    Raises :class:`ConfigError` (naming ``source``, e.g. the route file) if the route is
    invalid, its spline has a cusp, or the comfort bound cannot be met even with the limits
    scaled down to 2 %.
    """
    validate_route(route, source)
    path = QuinticPath(route.waypoints_m, route.start_heading_rad)
    _check_geometry(path, source)
    scale = 1.0
    bound = route.comfort_rms_max_mps2
    for _ in range(30):
        traj = _plan_scaled(route, path, scale)
        a_v = traj.comfort_report().a_v_mps2
        if a_v <= bound:
            return traj
        # accelerations scale ~linearly with the factor; aim a little below the bound
        scale *= max(0.1, min(0.97, 0.98 * bound / a_v))
        if scale < _MIN_SCALE:
            break
    raise ConfigError(
        f"{source}: comfort bound comfort_rms_max_mps2 = {bound} m/s^2 cannot be met "
        f"(weighted rms {a_v:.3f} m/s^2 with the limits scaled to {scale:.3g})"
    )


# ----------------------------------------------------------------------------- saved plans

#: The ``format`` entry of a saved plan (:func:`save_plan`); a file without it is refused.  A
#: change of what a plan holds (a new table of :class:`QuinticPath`, a new comfort figure)
#: changes it, so that a part never loads a plan written by another version.
PLAN_FORMAT = "wheelchair-hil planned route 1"
#: The arrays of a :class:`QuinticPath` a saved plan holds (everything its methods read).
_PATH_ARRAYS = ("knots", "cx", "cy", "waypoints", "_sub_tau", "_sub_s", "knot_s")
_PROFILE_ARRAYS = ("pt", "ps", "pv", "pa", "pj")
#: The τ(s) table's arrays (:attr:`QuinticPath.tab`), in its order.
_TAB_ARRAYS = ("t0", "m0", "c2", "c3", "seg")


def save_plan(traj: SplineTrajectory, file: str | Path) -> None:
    """Write ``traj`` to ``file`` (numpy's ``.npz``, no pickles): its route, path, speed
    profile and comfort figures, every float as its 64 bits.

    ``run`` plans a route once and hands the file to the bench and controller it starts
    (``--plan``), which load it (:func:`load_plan`) instead of planning the same route again:
    the same trajectory, bit for bit, without scipy.interpolate, scipy.ndimage and
    scipy.signal (about 0.55 s of a part's start on a 2-core machine, 5.4-6.5 s in the
    user-mode Linux guest of the socketcan lane; docs/planner.md "A saved plan").
    """
    path = traj.path
    arrays: dict[str, Any] = {
        "format": np.array(PLAN_FORMAT),
        "route": np.array(repr(traj.route)),
        "comfort": np.array([getattr(traj.comfort_report(), f.name) for f in _COMFORT_FIELDS]),
        "scalars": np.array([traj.limit_scale, traj.t_smooth_s, path.tab_h]),
        "tab_n": np.array(path.tab_n),
    }
    for name, a in zip(_TAB_ARRAYS, path.tab, strict=True):
        arrays[f"tab_{name}"] = a
    for name in _PATH_ARRAYS:
        arrays[f"path{name}"] = getattr(path, name)
    for name, a in zip(
        _PROFILE_ARRAYS,
        (traj._pt_arr, traj._ps_arr, traj._pv_arr, traj._pa_arr, traj._pj_arr),
        strict=True,
    ):
        arrays[f"profile_{name}"] = a
    with open(file, "wb") as f:
        np.savez(f, **arrays)


def load_plan(file: str | Path, route: RouteParams, source: str = "route") -> SplineTrajectory:
    """The trajectory :func:`save_plan` wrote to ``file``, which must be the plan of
    ``route`` (``source`` names the route in an error).

    Raises :class:`ConfigError` naming the file if it is missing or unreadable, is not a
    saved plan, lacks an entry, or holds the plan of another route.
    """
    try:
        with np.load(file, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError) as err:
        raise ConfigError(f"{file}: not a readable saved plan (--plan): {err}") from None
    if data.get("format") is None or str(data["format"]) != PLAN_FORMAT:
        raise ConfigError(f"{file}: not a saved plan (--plan): no format {PLAN_FORMAT!r}")
    try:
        if str(data["route"]) != repr(route):
            raise ConfigError(
                f"{file}: the saved plan is of another route than {source}'s (--plan): "
                "plan it again"
            )
        path = QuinticPath.__new__(QuinticPath)
        for name in _PATH_ARRAYS:
            setattr(path, name, data[f"path{name}"])
        path.n_seg = len(path.cx)
        path.length_m = float(path._sub_s[-1])
        limit_scale, t_smooth, path.tab_h = (float(v) for v in data["scalars"])
        path.tab_n = int(data["tab_n"])
        path.tab = tuple(data[f"tab_{k}"] for k in _TAB_ARRAYS)
        profile = tuple(data[f"profile_{k}"] for k in _PROFILE_ARRAYS)
        comfort_values = data["comfort"].tolist()
    except KeyError as err:
        raise ConfigError(f"{file}: the saved plan lacks {err.args[0]!r} (--plan)") from None
    if len(comfort_values) != len(_COMFORT_FIELDS):
        raise ConfigError(f"{file}: the saved plan's comfort figures are not this version's")
    traj = SplineTrajectory(route, path, profile, limit_scale, t_smooth)
    traj._comfort = ComfortReport(*comfort_values)
    return traj


_COMFORT_FIELDS = fields(ComfortReport)
