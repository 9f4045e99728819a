"""The controller's float loops, compiled with mypyc where the package is built with it.

Plain, fully typed Python on floats, lists and tuples only: no numpy, no project import.
``setup.py`` compiles this module beside its source, as it does the bench's inner loops
(:mod:`dbc.runtime.compiled` says which, and how a stale or unwanted compiled module is not
used); where nothing is compiled the chair runs it from source,
with the same numbers: a compiled float operation is the same IEEE operation, in the same order,
and ``math``'s functions are the same C library's (``tests/unit/controller/test_kernels.py``
compares both, bit for bit).

:func:`arc_step` (the exact arc of a differential drive) and :func:`wrap_angle` are called
several times every tick; ``controller.odometry`` and ``controller.types`` give them under their
usual names.  The rest is the arithmetic of the tick's work, each function named after the
method it computes for:

* the fault bank (:mod:`controller.diagnosis`): :func:`bank_step`, one hypothesis' wheel
  model over a fix period's odometry intervals; :func:`bank_flush` (every filter's
  prediction), :func:`bank_fix` (every filter's fix update), :func:`imm_mix` and
  :func:`posterior` (the mixing and the probabilities), on lists of floats per filter;
* the pose EKF (:mod:`controller.pose_ekf`): :func:`pose_predict`, and its fix update through
  the bank's :func:`bank_innovation` and :func:`bank_update`;
* the command limiter's step (:func:`limit_step`) and the reference's spline
  (:func:`spline_sample`, :func:`spline_geometry`).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from math import cos, sin

#: The hypotheses' kinds, as ``int(Hypothesis.X)`` (``dbc.messages.Hypothesis``; checked in
#: controller.diagnosis, which owns the hypotheses).
NOMINAL, FLAT_LEFT, FLAT_RIGHT, BUMP_LEFT, BUMP_RIGHT, SLIP = 0, 1, 2, 3, 4, 5

_PI = math.pi
_TWO_PI = 2.0 * math.pi


def wrap_angle(a: float) -> float:
    """:func:`controller.types.wrap_angle`, the same operations (NaN for a non-finite angle)."""
    if not math.isfinite(a):
        return math.nan
    a = math.fmod(a + _PI, _TWO_PI)
    if a <= 0.0:
        a += _TWO_PI
    return a - _PI


def arc_step(
    x: float, y: float, phi: float, ds_left_m: float, ds_right_m: float, half_track_m: float
) -> tuple[float, float, float, float, float]:
    """Exact pose increment of a differential drive moving on a circular arc.

    Returns ``(x', y', phi', chord_m, dphi_rad)``; ``phi'`` is wrapped to (-π, π].  The chord
    ``ds · sin(dφ/2)/(dφ/2)`` is taken along ``phi + dφ/2`` (series for small dφ).  Called
    several times a tick (the odometry, the pose EKF, the node's estimate-step meter), as
    ``controller.odometry.arc_step``.
    """
    ds = 0.5 * (ds_right_m + ds_left_m)
    dphi = (ds_right_m - ds_left_m) / (2.0 * half_track_m)
    half = 0.5 * dphi
    if abs(half) < 1e-4:
        h2 = half * half
        chord = ds * (1.0 - h2 / 6.0 + h2 * h2 / 120.0)
    else:
        chord = ds * math.sin(half) / half
    mid = phi + half
    return (
        x + chord * math.cos(mid),
        y + chord * math.sin(mid),
        wrap_angle(phi + dphi),
        chord,
        dphi,
    )


def bank_step(
    kind: int,
    n_par: int,
    r0: float,
    half_track_m: float,
    noise: float,
    walk_per_m: float,
    start: list[float],
    intervals: list[tuple[float, float, float, float, float, float]],
) -> tuple[list[float], list[float]]:
    """Integrate one hypothesis' wheel model over ``intervals`` from the state ``start``.

    ``intervals``: ``(th_l, dth_l, th_r, dth_r, ds_l, ds_r)`` each (previous wheel angles and
    their increments, rad; nominal ground travels, m).  Returns the 20 entries of the covariance
    step's ``F`` and ``Q`` that are not those of the identity and zero (the order of
    ``controller.diagnosis._STEP_ENTRIES``), and the new mean ``[x, y, phi, params...]``.
    """
    x0 = px = start[0]
    y0 = py = start[1]
    pphi = start[2]
    par = start[3:]
    a = par[0] if n_par else 0.0
    b = par[1] if n_par == 2 else 0.0
    rk = r0 * (1.0 - a)  # slip: the effective radius
    two_b = 2.0 * half_track_m
    four_b = 4.0 * half_track_m
    gp = 1.0 / (2.0 * half_track_m)
    gp2 = gp * gp
    q0 = q1 = q2 = q3 = q4 = q5 = dist = 0.0
    d00 = d01 = d10 = d11 = d20 = d21 = 0.0  # d(pose)/d(params)
    jl0 = jl1 = jr0 = jr1 = 0.0  # d(ground travel of each wheel)/d(params)
    for th_l, dth_l, th_r, dth_r, ds_l, ds_r in intervals:
        # this hypothesis' ground travel of each wheel (ds_l, ds_r: nominal)
        if kind == NOMINAL:
            pass
        elif kind == FLAT_LEFT:
            ds_l = a * dth_l
            jl0 = dth_l
        elif kind == FLAT_RIGHT:
            ds_r = a * dth_r
            jr0 = dth_r
        elif kind == SLIP:
            jl0 = -ds_l
            jr0 = -ds_r
            ds_l = rk * dth_l
            ds_r = rk * dth_r
        elif kind == BUMP_LEFT:
            th1 = th_l + dth_l
            jl0 = sin(th1) - sin(th_l)
            jl1 = cos(th_l) - cos(th1)
            ds_l = ds_l + a * jl0 + b * jl1
        else:
            th1 = th_r + dth_r
            jr0 = sin(th1) - sin(th_r)
            jr1 = cos(th_r) - cos(th1)
            ds_r = ds_r + a * jr0 + b * jr1
        # the exact arc (as controller.odometry.arc_step) and its derivatives
        ds = 0.5 * (ds_l + ds_r)
        dphi = (ds_r - ds_l) / two_b
        half = 0.5 * dphi
        chord = ds * (1.0 - half * half / 6.0) if -1e-4 < half < 1e-4 else ds * sin(half) / half
        m = pphi + half
        cm = cos(m)
        sm = sin(m)
        dx = chord * cm
        dy = chord * sm
        k = chord / four_b
        hc = 0.5 * cm
        hs = 0.5 * sm
        kc = k * cm
        ks = k * sm
        lx = hc + ks
        ly = hs - kc
        rx = hc - ks
        ry = hs + kc
        if n_par:
            d00 += -dy * d20 + lx * jl0 + rx * jr0
            d10 += dx * d20 + ly * jl0 + ry * jr0
            d20 += gp * (jr0 - jl0)
            if n_par == 2:
                d01 += -dy * d21 + lx * jl1 + rx * jr1
                d11 += dx * d21 + ly * jl1 + ry * jr1
                d21 += gp * (jr1 - jl1)
        al = abs(ds_l)
        ar = abs(ds_r)
        vl = noise * al
        vr = noise * ar
        q0 += lx * lx * vl + rx * rx * vr
        q1 += lx * ly * vl + rx * ry * vr
        q2 += ly * ly * vl + ry * ry * vr
        q3 += gp * (rx * vr - lx * vl)
        q4 += gp * (ry * vr - ly * vl)
        q5 += gp2 * (vl + vr)
        px += dx
        py += dy
        pphi += dphi
        dist += 0.5 * (al + ar)
    w = walk_per_m * dist
    entries = [
        -(py - y0),
        d00,
        d01,
        px - x0,
        d10,
        d11,
        1.0,
        d20,
        d21,
        q0,
        q1,
        q3,
        q1,
        q2,
        q4,
        q3,
        q4,
        q5,
        w if n_par else 0.0,
        w if n_par == 2 else 0.0,
    ]
    mean = [px, py, wrap_angle(pphi)]
    mean.extend(par)
    return entries, mean


# -- the fault bank's covariance algebra (controller.diagnosis), on one filter at a time ----
#
# A filter of n states (3 pose, 0-2 parameters) keeps its mean as a list of n floats and its
# covariance as a list of n * n floats, row by row.  Every product is summed in index order,
# one rounding per operation: the same bits compiled and from source, on every machine (a
# BLAS product's order and fused multiply-adds depend on the CPU it picks a kernel for).


def inv_sym3(
    a: float, b: float, c: float, d: float, e: float, f: float
) -> tuple[list[list[float]], float] | None:
    """Inverse and determinant of the symmetric positive matrix [[a, b, c], [b, d, e], [c, e, f]]
    by its adjugate (plain floats: ~4x faster than LAPACK); None if singular.

    The pose EKF's and the fault bank's filters' innovation covariances are inverted here.
    """
    A = d * f - e * e
    B = c * e - b * f
    C = b * e - c * d
    det = a * A + b * B + c * C
    if not (det > 0.0 and math.isfinite(det)):
        return None
    D = a * f - c * c
    E = b * c - a * e
    F = a * d - b * b
    r = 1.0 / det
    return [[A * r, B * r, C * r], [B * r, D * r, E * r], [C * r, E * r, F * r]], det


def _symmetrised(M: list[float], n: int) -> list[float]:
    """``0.5 (M + M')``."""
    out = list(M)
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (M[i * n + j] + M[j * n + i])
            out[i * n + j] = v
            out[j * n + i] = v
    return out


def all_finite(values: list[float]) -> bool:
    """Whether every value is finite (False for NaN and infinities)."""
    for v in values:  # noqa: SIM110 (a compiled loop, no generator)
        if not math.isfinite(v):
            return False
    return True


def bank_covariance_step(
    P: list[float], n: int, entries: list[float]
) -> tuple[list[float], list[float]]:
    """One covariance step ``P' = F P F' + Q`` of a filter of ``n`` states.

    ``entries``: :func:`bank_step`'s 20 values, ``F[:3, 2:5]`` then ``Q[:3, :3]``, ``Q[3, 3]``,
    ``Q[4, 4]`` (``F`` is the identity elsewhere, ``Q`` zero; the entries beyond ``n`` unused).
    Returns ``(P', 0.5 (P' + P''))``, each ``n * n`` row by row.  ``F`` differs from the
    identity only in the columns 2 and up of its first three rows, so each product takes
    only those terms (``F[2, 2]`` included), summed in column order.
    """
    # FP = F P: rows 3 and up are P's
    FP = list(P)
    for i in range(3):
        for j in range(n):
            s = P[i * n + j] if i < 2 else 0.0
            for c in range(2, n):
                s += entries[i * 3 + c - 2] * P[c * n + j]
            FP[i * n + j] = s
    # (F P) F' + Q: columns 3 and up are F P's
    out = list(FP)
    for i in range(n):
        for j in range(3):
            s = FP[i * n + j] if j < 2 else 0.0
            for c in range(2, n):
                s += FP[i * n + c] * entries[j * 3 + c - 2]
            out[i * n + j] = s
    for i in range(3):
        for j in range(3):
            out[i * n + j] += entries[9 + i * 3 + j]
    if n > 3:
        out[3 * n + 3] += entries[18]
    if n > 4:
        out[4 * n + 4] += entries[19]
    return out, _symmetrised(out, n)


def step_matrices(n: int, entries: list[float]) -> tuple[list[float], list[float]]:
    """The ``F`` and ``Q`` (``n * n`` each, row by row) of :func:`bank_covariance_step`."""
    F = [0.0] * (n * n)
    Q = [0.0] * (n * n)
    for i in range(n):
        F[i * n + i] = 1.0
    for i in range(3):
        for j in range(2, n):
            F[i * n + j] = entries[i * 3 + j - 2]
        for j in range(3):
            Q[i * n + j] = entries[9 + i * 3 + j]
    if n > 3:
        Q[3 * n + 3] = entries[18]
    if n > 4:
        Q[4 * n + 4] = entries[19]
    return F, Q


def bank_innovation(
    x: list[float], P: list[float], n: int, z: list[float], R: list[float]
) -> tuple[float, float, list[float]] | None:
    """A pose fix ``z`` = [x, y, phi] against a filter (``H = [I3 0]``, heading wrapped).

    Returns the Mahalanobis distance squared ``y' S^-1 y``, the Gaussian log-likelihood, and
    ``y`` (3), ``S`` (9) and ``S^-1`` (9) side by side; None if ``S`` is not invertible.
    ``R``: the fix's covariance, 9 values row by row.
    """
    y0 = z[0] - x[0]
    y1 = z[1] - x[1]
    y2 = wrap_angle(z[2] - x[2])
    S = [0.0] * 9
    for i in range(3):
        for j in range(3):
            S[i * 3 + j] = P[i * n + j] + R[i * 3 + j]
    inv = inv_sym3(S[0], S[1], S[2], S[4], S[5], S[8])
    if inv is None:
        return None
    SI, det = inv
    v0 = y0 * SI[0][0] + y1 * SI[1][0] + y2 * SI[2][0]
    v1 = y0 * SI[0][1] + y1 * SI[1][1] + y2 * SI[2][1]
    v2 = y0 * SI[0][2] + y1 * SI[1][2] + y2 * SI[2][2]
    d2 = v0 * y0 + v1 * y1 + v2 * y2
    ll = -0.5 * (d2 + math.log(det) + 3.0 * math.log(_TWO_PI))
    out = [y0, y1, y2]
    out.extend(S)
    for row in SI:
        out.extend(row)
    return d2, ll, out


def bank_update(
    x: list[float], P: list[float], n: int, ysi: list[float], R: list[float]
) -> tuple[list[float], list[float], list[float]]:
    """The Joseph-form update of a filter with :func:`bank_innovation`'s ``ysi``.

    ``K = P H' S^-1``, ``x + K y``, ``(I - K H) P (I - K H)' + K R K'`` symmetrised, with
    ``H = [I3 0]``: ``(I - K H) P = P - K P[:3, :]`` and likewise on the right.  Returns
    ``(x', P', K)``: ``n``, ``n * n`` and ``n * 3`` values (not checked for finiteness).
    """
    y0 = ysi[0]
    y1 = ysi[1]
    y2 = ysi[2]
    K = [0.0] * (n * 3)
    X = [0.0] * n
    for i in range(n):
        p0 = P[i * n]
        p1 = P[i * n + 1]
        p2 = P[i * n + 2]
        k0 = p0 * ysi[12] + p1 * ysi[15] + p2 * ysi[18]
        k1 = p0 * ysi[13] + p1 * ysi[16] + p2 * ysi[19]
        k2 = p0 * ysi[14] + p1 * ysi[17] + p2 * ysi[20]
        K[i * 3] = k0
        K[i * 3 + 1] = k1
        K[i * 3 + 2] = k2
        X[i] = x[i] + (k0 * y0 + k1 * y1 + k2 * y2)
    out = [0.0] * (n * n)
    for i in range(n):
        k0 = K[i * 3]
        k1 = K[i * 3 + 1]
        k2 = K[i * 3 + 2]
        # row i of (I - K H) P in its first three columns, and of K R
        a0 = P[i * n] - (k0 * P[0] + k1 * P[n] + k2 * P[2 * n])
        a1 = P[i * n + 1] - (k0 * P[1] + k1 * P[n + 1] + k2 * P[2 * n + 1])
        a2 = P[i * n + 2] - (k0 * P[2] + k1 * P[n + 2] + k2 * P[2 * n + 2])
        r0 = k0 * R[0] + k1 * R[3] + k2 * R[6]
        r1 = k0 * R[1] + k1 * R[4] + k2 * R[7]
        r2 = k0 * R[2] + k1 * R[5] + k2 * R[8]
        for j in range(n):
            j0 = K[j * 3]
            j1 = K[j * 3 + 1]
            j2 = K[j * 3 + 2]
            ap = P[i * n + j] - (k0 * P[j] + k1 * P[n + j] + k2 * P[2 * n + j])
            out[i * n + j] = ap - (a0 * j0 + a1 * j1 + a2 * j2) + (r0 * j0 + r1 * j1 + r2 * j2)
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (out[i * n + j] + out[j * n + i])
            out[i * n + j] = v
            out[j * n + i] = v
    return X, out, K


def project(kind: int, lo: float, hi: float, par: list[float]) -> list[float]:
    """A hypothesis' parameters ``par`` brought into its admissible set: a flat tire's radius
    or the slip ratio clamped to ``[lo, hi]``, a bump's amplitude ``|(a, b)|`` scaled into it
    (``(lo, 0)`` from zero); the nominal hypothesis has none."""
    if kind == NOMINAL:
        return par
    if kind != BUMP_LEFT and kind != BUMP_RIGHT:
        return [min(max(par[0], lo), hi)]
    a = par[0]
    b = par[1]
    amp = math.hypot(a, b)
    if amp < 1e-12:
        return [lo, 0.0]
    if amp < lo or amp > hi:
        k = (lo if amp < lo else hi) / amp
        return [a * k, b * k]
    return par


def bank_flush(
    kinds: list[int],
    r0: float,
    half_track_m: float,
    noise: float,
    walks: list[float],
    los: list[float],
    his: list[float],
    xs: list[list[float]],
    Ps: list[list[float]],
    intervals: list[tuple[float, float, float, float, float, float]],
) -> tuple[list[tuple[list[float], list[float], list[float]]], bool]:
    """Every filter's prediction over ``intervals``: :func:`bank_step`, then
    :func:`bank_covariance_step`, the parameters projected (:func:`project`, with the bounds
    ``los``, ``his``).  ``xs`` and ``Ps`` are replaced for the filters whose step is finite;
    the others keep their state.  Returns each filter's ``(F and Q entries, P', x')`` (before
    symmetrising and projecting, as filterpy's priors) and whether every step was finite."""
    records: list[tuple[list[float], list[float], list[float]]] = []
    ok = True
    for i in range(len(kinds)):
        kind = kinds[i]
        n = len(xs[i])
        entries, x = bank_step(kind, n - 3, r0, half_track_m, noise, walks[i], xs[i], intervals)
        P, P_sym = bank_covariance_step(Ps[i], n, entries)
        records.append((entries, P, list(x)))
        if all_finite(P) and all_finite(x):
            par = project(kind, los[i], his[i], x[3:])
            xs[i] = [x[0], x[1], x[2], *par]
            Ps[i] = P_sym
        else:
            ok = False
    return records, ok


def bank_fix(
    kinds: list[int],
    los: list[float],
    his: list[float],
    xs: list[list[float]],
    Ps: list[list[float]],
    z: list[float],
    R: list[float],
    outlier_chi2: float,
) -> tuple[int, list[float], list[list[float]], list[list[float]], int]:
    """A pose fix ``z`` for every filter: :func:`bank_innovation`, then (unless a filter's
    ``S`` is singular, a likelihood is not finite, or every filter's Mahalanobis distance
    squared exceeds ``outlier_chi2``) :func:`bank_update`, the heading wrapped and the
    parameters projected.  ``xs`` and ``Ps`` are replaced for the filters whose update is
    finite; the others keep their state.

    Returns ``(status, log-likelihoods, innovations, gains, failed)``: status 0 (updated), 1
    (a singular ``S``), 2 (a likelihood not finite) or 3 (an outlier), nothing changed
    unless 0; each filter's :func:`bank_innovation` values and gain ``K`` (empty where its
    update was not finite); how many updates were not finite.
    """
    m = len(xs)
    ll: list[float] = []
    d2: list[float] = []
    inns: list[list[float]] = []
    for i in range(m):
        inn = bank_innovation(xs[i], Ps[i], len(xs[i]), z, R)
        if inn is None:
            return 1, ll, inns, [], 0
        d2.append(inn[0])
        ll.append(inn[1])
        inns.append(inn[2])
    if not all_finite(ll):
        return 2, ll, inns, [], 0
    if min(d2) > outlier_chi2:
        return 3, ll, inns, [], 0
    Ks: list[list[float]] = []
    failed = 0
    for i in range(m):
        X, P_sym, K = bank_update(xs[i], Ps[i], len(xs[i]), inns[i], R)
        if not (all_finite(X) and all_finite(P_sym)):
            failed += 1
            Ks.append([])
            continue
        par = project(kinds[i], los[i], his[i], X[3:])
        xs[i] = [X[0], X[1], wrap_angle(X[2]), *par]
        Ps[i] = P_sym
        Ks.append(K)
    return 0, ll, inns, Ks, failed


def positive_definite(P: list[float], n: int) -> bool:
    """Whether the symmetric ``P`` (``n * n``) has a Cholesky factor (every pivot > 0)."""
    L = [0.0] * (n * n)
    for j in range(n):
        s = P[j * n + j]
        for k in range(j):
            s -= L[j * n + k] * L[j * n + k]
        if not s > 0.0:  # NaN included
            return False
        d = math.sqrt(s)
        L[j * n + j] = d
        for i in range(j + 1, n):
            t = P[i * n + j]
            for k in range(j):
                t -= L[i * n + k] * L[j * n + k]
            L[i * n + j] = t / d
    return True


def posterior(c: list[float], ll: list[float]) -> list[float]:
    """Model probabilities: the predicted ``c`` times the likelihoods ``exp(ll)``, normalised
    (in logarithms, the largest taken out first)."""
    logp = [math.log(max(c[i], 1e-300)) + ll[i] for i in range(len(c))]
    top = max(logp)
    post = [math.exp(v - top) for v in logp]
    total = 0.0
    for v in post:
        total += v
    return [v / total for v in post]


def _mix_weight(
    prob: list[float], prior: list[float], eps: float, cj: float, i: int, j: int
) -> float:
    """``mu_i|j = pi_ij mu_i / c_j``."""
    w = eps * (prob[i] * prior[j])
    if i == j:
        w += (1.0 - eps) * prob[i]
    return w / cj


def imm_mix(
    prob: list[float],
    prior: list[float],
    eps: float,
    xs: list[list[float]],
    Ps: list[list[float]],
    dims: list[int],
    prior_var: list[list[float]],
) -> tuple[list[float], list[int]]:
    """IMM mixing of the pose block (``controller.diagnosis.FaultBank``).

    Transition ``pi_ij = (1 - eps) delta_ij + eps prior_j``; each filter ``j`` whose own weight
    ``mu_j|j`` is below 1 takes the mixture's pose mean and covariance over ``mu_i|j = pi_ij
    mu_i / c_j``; its parameters' covariance relaxes toward ``prior_var`` by ``1 - mu_j|j`` and
    their cross-covariance with the pose shrinks by ``sqrt(mu_j|j)`` (dropped where that would
    leave the covariance not positive definite).  ``xs`` and ``Ps`` (the filters' means and
    ``dims[j]``-square symmetric covariances) are replaced for the filters mixed.  Returns the
    predicted probabilities ``c`` and the filters mixed.
    """
    m = len(prob)
    c = [(1.0 - eps) * prob[j] + eps * prior[j] for j in range(m)]
    if eps <= 0.0:
        return c, []
    # (a filter no hypothesis can switch to, c_j = 0 (a prior of 0 and a probability that
    # underflowed), has no mixture: it keeps its state)
    mixed = [
        j
        for j in range(m)
        if c[j] > 0.0 and not _mix_weight(prob, prior, eps, c[j], j, j) > 1.0 - 1e-9
    ]
    new_x: list[list[float]] = []
    new_P: list[list[float]] = []
    for j in mixed:
        xj = xs[j]
        cj = c[j]
        # the weighted mean of d_i = pose_i - pose_j (heading wrapped)
        m0 = m1 = m2 = 0.0
        for i in range(m):
            w = _mix_weight(prob, prior, eps, cj, i, j)
            xi = xs[i]
            m0 += w * (xi[0] - xj[0])
            m1 += w * (xi[1] - xj[1])
            m2 += w * ((xi[2] - xj[2] + _PI) % _TWO_PI - _PI)
        # the pose block: sum_i w_i (P_i + e_i e_i'), e_i = d_i - mean (upper triangle)
        c00 = c01 = c02 = c11 = c12 = c22 = 0.0
        for i in range(m):
            w = _mix_weight(prob, prior, eps, cj, i, j)
            xi = xs[i]
            Pi = Ps[i]
            ni = dims[i]
            e0 = xi[0] - xj[0] - m0
            e1 = xi[1] - xj[1] - m1
            e2 = (xi[2] - xj[2] + _PI) % _TWO_PI - _PI - m2
            c00 += w * (Pi[0] + e0 * e0)
            c01 += w * (Pi[1] + e0 * e1)
            c02 += w * (Pi[2] + e0 * e2)
            c11 += w * (Pi[ni + 1] + e1 * e1)
            c12 += w * (Pi[ni + 2] + e1 * e2)
            c22 += w * (Pi[2 * ni + 2] + e2 * e2)
        n = dims[j]
        keep = _mix_weight(prob, prior, eps, cj, j, j)
        P = list(Ps[j])
        P[0] = c00
        P[1] = P[n] = c01
        P[2] = P[2 * n] = c02
        P[n + 1] = c11
        P[n + 2] = P[2 * n + 1] = c12
        P[2 * n + 2] = c22
        if n > 3:
            var = prior_var[j]
            sk = math.sqrt(keep)
            for k in range(3, n):
                for col in range(3, n):
                    p0 = var[k - 3] if k == col else 0.0
                    P[k * n + col] = keep * P[k * n + col] + (1.0 - keep) * p0
                for col in range(3):
                    P[k * n + col] *= sk
                    P[col * n + k] *= sk
            if not positive_definite(P, n):
                for k in range(3, n):
                    for col in range(3):
                        P[k * n + col] = 0.0
                        P[col * n + k] = 0.0
        x = [xj[0] + m0, xj[1] + m1, wrap_angle(xj[2] + m2)]
        x.extend(xj[3:])
        new_x.append(x)
        new_P.append(P)
    for k in range(len(mixed)):  # every mixture from the states before mixing
        xs[mixed[k]] = new_x[k]
        Ps[mixed[k]] = new_P[k]
    return c, mixed


def pose_predict(
    x: list[float],
    P: tuple[float, ...],
    raw_l: float,
    raw_r: float,
    half_track_m: float,
    wheel_noise: float,
    radius_rel_std: float,
    scale_drift_std: float,
) -> tuple[list[float], tuple[float, ...], tuple[float, ...], float, float, float, float] | None:
    """The pose EKF's prediction (``controller.pose_ekf.PoseEstimator.predict``) with one
    odometry interval's wheel travels ``raw_l``, ``raw_r`` (m) from the state ``x`` = [x, y,
    phi, delta] and ``P``'s upper triangle row by row (10 values).

    Returns the new state, the new ``P`` (10 values), ``F``'s and ``Q``'s entries (``fa, fb,
    c0, c1, c2, qxx, qxy, qxp, qyy, qyp, qpp, qdd``), the travels delta believes ``dl``,
    ``dr``, and the interval's ``ds`` and ``dphi``; None if the step is not finite.
    """
    x0 = x[0]
    y0 = x[1]
    phi = x[2]
    dlt = x[3]
    b = half_track_m
    dl = raw_l * (1.0 - 0.5 * dlt)  # the travels delta believes
    dr = raw_r * (1.0 + 0.5 * dlt)
    ds = 0.5 * (dl + dr)
    dphi = (dr - dl) / (2.0 * b)
    half = 0.5 * dphi
    chord = ds if abs(half) < 1e-4 else ds * math.sin(half) / half
    m = phi + half
    cm = math.cos(m)
    sm = math.sin(m)
    fa = -chord * sm
    fb = chord * cm
    rr = radius_rel_std
    try:
        var_l = wheel_noise * abs(dl) + (rr * dl) ** 2
        var_r = wheel_noise * abs(dr) + (rr * dr) ** 2
    except OverflowError:  # a travel beyond any wheel's (float ** raises): not finite
        return None
    k = chord / (4.0 * b)
    # G = d(x', y', phi')/d(ds_L, ds_R) with dchord/dds ~ 1
    gxl = 0.5 * cm + k * sm
    gxr = 0.5 * cm - k * sm
    gyl = 0.5 * sm - k * cm
    gyr = 0.5 * sm + k * cm
    gp = 1.0 / (2.0 * b)
    qxx = gxl * gxl * var_l + gxr * gxr * var_r
    qxy = gxl * gyl * var_l + gxr * gyr * var_r
    qyy = gyl * gyl * var_l + gyr * gyr * var_r
    qxp = (-gxl * var_l + gxr * var_r) * gp
    qyp = (-gyl * var_l + gyr * var_r) * gp
    qpp = gp * gp * (var_l + var_r)
    sd = scale_drift_std
    qdd = sd * sd * 0.5 * (abs(raw_l) + abs(raw_r))
    # d(x', y', phi')/d(delta) = G (-ds_L / 2, ds_R / 2): F's fourth column (c0, c1, c2)
    hl = -0.5 * raw_l
    hr = 0.5 * raw_r
    c0 = gxl * hl + gxr * hr
    c1 = gyl * hl + gyr * hr
    c2 = gp * (hr - hl)
    # filterpy's predict() (x = f(x, u); P = F P F' + Q) with F and Q written out: F = I + E,
    # E's entries (0,2) fa, (1,2) fb, (0,3) c0, (1,3) c1, (2,3) c2.
    p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = P
    # R = F P (rows 0-2; row 3 is P's)
    r00 = p00 + fa * p02 + c0 * p03
    r01 = p01 + fa * p12 + c0 * p13
    r02 = p02 + fa * p22 + c0 * p23
    r03 = p03 + fa * p23 + c0 * p33
    r11 = p11 + fb * p12 + c1 * p13
    r12 = p12 + fb * p22 + c1 * p23
    r13 = p13 + fb * p23 + c1 * p33
    r22 = p22 + c2 * p23
    r23 = p23 + c2 * p33
    # N = R F' + Q (upper triangle)
    n00 = r00 + fa * r02 + c0 * r03 + qxx
    n01 = r01 + fb * r02 + c1 * r03 + qxy
    n02 = r02 + c2 * r03 + qxp
    n03 = r03
    n11 = r11 + fb * r12 + c1 * r13 + qyy
    n12 = r12 + c2 * r13 + qyp
    n13 = r13
    n22 = r22 + c2 * r23 + qpp
    n23 = r23
    n33 = p33 + qdd
    if not math.isfinite(n00 + n01 + n02 + n03 + n11 + n12 + n13 + n22 + n23 + n33):
        return None
    x1, y1, phi1, _, _ = arc_step(x0, y0, phi, dl, dr, b)  # x = f(x, u): the exact arc
    if not (math.isfinite(x1) and math.isfinite(y1) and math.isfinite(phi1)):
        return None
    return (
        [x1, y1, phi1, dlt],
        (n00, n01, n02, n03, n11, n12, n13, n22, n23, n33),
        (fa, fb, c0, c1, c2, qxx, qxy, qxp, qyy, qyp, qpp, qdd),
        dl,
        dr,
        ds,
        dphi,
    )


def _max(a: float, b: float) -> float:
    """``max(a, b)`` as Python's builtin gives it (the first unless the second is greater)."""
    return b if b > a else a


def _min(a: float, b: float) -> float:
    """``min(a, b)`` as Python's builtin gives it (the first unless the second is less)."""
    return b if b < a else a


def limit_step(
    v_t: float,
    w_t: float,
    h: float,
    state: tuple[float, float, float, float],
    limits: tuple[float, float, float, float, float, float, float, float],
    half_track_m: float,
    wheel_radius_m: float,
) -> tuple[float, float, float, float, float, float, int, int, int]:
    """The command limiter's step (``controller.limits.CommandLimiter.apply``, whose docstring
    and comments say why each line is there) on the twist ``(v_t, w_t)`` over ``h`` seconds.

    ``state``: the previous output ``(v, a, omega)`` and target ``vb``; ``limits``: ``(v_max,
    v_reverse_max, omega_max, wheel_max, jerk_max, accel_max, decel_max, alpha_max)``.
    Returns the new ``(v, a, omega, vb)``, the wheel speeds to send (rad/s, left and right),
    and how many times the box, wheel and rate limits changed the command (0, 1 or 2).
    """
    v_max, v_rev, w_max, wheel_max, j, accel_max, decel_max, alpha_max = limits
    v0, a0, w0, vb_prev = state
    b = half_track_m
    r = wheel_radius_m
    box = wheel = rate = 0
    # 1. box limits
    vb = _min(_max(v_t, -v_rev), v_max)
    wb = _min(_max(w_t, -w_max), w_max)
    if vb != v_t or wb != w_t:
        box = 1
    # 2. wheel saturation of the target
    left_mps = vb - b * wb
    right_mps = vb + b * wb
    peak = _max(abs(left_mps), abs(right_mps)) / r
    k = wheel_max / peak if peak > wheel_max else 1.0
    if k < 1.0:
        vb = vb * k
        wb = wb * k
        wheel += 1
    # 3. rate limits on v
    dv = vb - v0
    a_des = dv / h if h > 0.0 else 0.0
    a_target = (vb - vb_prev) / h if h > 0.0 else 0.0
    brake = -0.5 * j * h + math.sqrt(0.25 * (j * h) ** 2 + 2.0 * j * abs(dv))
    a_des = _min(_max(a_des, a_target - brake), a_target + brake)
    speeding_up = (v0 >= 0.0 and a_des > 0.0) or (v0 <= 0.0 and a_des < 0.0)
    a_lim = accel_max if speeding_up else decel_max
    a = _min(_max(a_des, -a_lim), a_lim)
    da = j * h
    a = _min(_max(a, a0 - da), a0 + da)
    v = v0 + a * h
    if (dv > 0.0 and v > vb) or (dv < 0.0 and v < vb) or dv == 0.0:
        v = vb
        a = (v - v0) / h if h > 0.0 else 0.0
    elif v > v_max or v < -v_rev:
        v = _min(_max(v, -v_rev), v_max)
        a = (v - v0) / h if h > 0.0 else 0.0
    dw_max = alpha_max * h
    w = _min(_max(wb, w0 - dw_max), w0 + dw_max)
    if abs(v - vb) > 1e-12 or w != wb:
        rate = 1
    # 4. the rate-limited mix may still exceed a wheel limit
    left_mps = v - b * w
    right_mps = v + b * w
    peak = _max(abs(left_mps), abs(right_mps)) / r
    if peak > wheel_max:
        k = wheel_max / peak
        v = v * k
        w = w * k
        a = (v - v0) / h if h > 0.0 else 0.0
        wheel += 1
        left_mps = v - b * w
        right_mps = v + b * w
    return v, a, w, vb, left_mps / r, right_mps / r, box, wheel, rate


def spline_geometry(
    s: float,
    tab: list[tuple[float, float, float, float, int]],
    tab_h: float,
    tab_inv_h: float,
    tab_last: int,
    knots: list[float],
    coef: list[tuple[float, ...]],
) -> tuple[float, float, float, float, float]:
    """x, y, heading, curvature and its derivative along the path at arc length ``s``
    (``controller.planner.SplineTrajectory``: its arc-length table ``tab`` of cubic pieces
    giving the spline parameter, the segments' ``knots`` and each segment's 32 polynomial
    coefficients ``coef``, in Horner form)."""
    k = int(s * tab_inv_h)
    if k > tab_last:
        k = tab_last
    w = s - k * tab_h
    t0, m0, c2, c3, seg = tab[k]
    tau = t0 + w * (m0 + w * (c2 + w * c3))
    last = len(coef) - 1
    while seg < last and tau >= knots[seg + 1]:
        seg += 1
    u = tau - knots[seg]
    c = coef[seg]
    x1 = c[4]
    x2 = c[3]
    y1 = c[10]
    y2 = c[9]
    x = ((((c[0] * u + c[1]) * u + c[2]) * u + x2) * u + x1) * u + c[5]
    y = ((((c[6] * u + c[7]) * u + c[8]) * u + y2) * u + y1) * u + c[11]
    xd = (((c[12] * u + c[13]) * u + c[14]) * u + c[15]) * u + x1
    yd = (((c[16] * u + c[17]) * u + c[18]) * u + c[19]) * u + y1
    xdd = ((c[20] * u + c[21]) * u + c[22]) * u + 2.0 * x2
    ydd = ((c[23] * u + c[24]) * u + c[25]) * u + 2.0 * y2
    xddd = (c[26] * u + c[27]) * u + c[28]
    yddd = (c[29] * u + c[30]) * u + c[31]
    sp2 = xd * xd + yd * yd
    sp = math.sqrt(sp2)
    sp3 = sp2 * sp
    cross = xd * ydd - xdd * yd
    curv = cross / sp3
    dk = ((xd * yddd - xddd * yd) / sp3 - 3.0 * cross * (xd * xdd + yd * ydd) / (sp3 * sp2)) / sp
    return x, y, math.atan2(yd, xd), curv, dk


def spline_sample(
    t_s: float,
    profile: tuple[list[float], list[float], list[float], list[float], list[float], list[float]],
    length: float,
    tab: list[tuple[float, float, float, float, int]],
    tab_h: float,
    tab_inv_h: float,
    tab_last: int,
    knots: list[float],
    coef: list[tuple[float, ...]],
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """The reference at ``0 < t_s <`` the route's duration: the speed profile's piece
    ``(t, s, v, a, j, j / 6)`` around ``t_s`` gives the arc length, speed and acceleration,
    :func:`spline_geometry` the pose and curvature.  Returns ``(x, y, heading, v, omega, a,
    alpha, curvature, s)``."""
    pt, ps, pv, pa, pj, pj6 = profile
    i = bisect_right(pt, t_s) - 1
    u = t_s - pt[i]
    a0 = pa[i]
    j = pj[i]
    v0 = pv[i]
    s = ps[i] + u * (v0 + u * (0.5 * a0 + u * pj6[i]))
    v = v0 + u * (a0 + 0.5 * j * u)
    a = a0 + j * u
    if s > length:
        s = length
    elif s < 0.0:
        s = 0.0
    x, y, hd, k, dk = spline_geometry(s, tab, tab_h, tab_inv_h, tab_last, knots, coef)
    return x, y, hd, v, k * v, a, dk * v * v + k * a, k, s
