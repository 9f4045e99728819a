"""The controller's float loops, compiled with mypyc where the package is built with it.

Plain, fully typed Python on floats, lists and tuples only: no numpy, no project import.
``setup.py`` compiles this module beside its source, as it does the bench's inner loops
(:mod:`dbc.runtime.compiled` says which, and how a stale or unwanted compiled module is not
used); where nothing is compiled the chair runs it from source,
with the same numbers: a compiled float operation is the same IEEE operation, in the same order,
and ``math``'s functions are the same C library's (``tests/unit/controller/test_kernels.py``
compares both, bit for bit).

:func:`bank_step` is the fault bank's wheel-model integration (:mod:`controller.diagnosis`,
``_Filter.step``): over a fix period it runs 6 hypotheses times 10 odometry intervals, the
bank's largest single cost from source.  :func:`arc_step` (the exact arc of a differential
drive) and :func:`wrap_angle` are called several times every tick; ``controller.odometry`` and
``controller.types`` give them under their usual names.
"""

from __future__ import annotations

import math
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
