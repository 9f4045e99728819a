"""The controller's float kernels (controller/kernels.py) give the same bits compiled as from
source: the fault bank's wheel models for every hypothesis, over intervals that take both of
the arc's branches, and the angle wrap, non-finite input included."""

from __future__ import annotations

import importlib.util
import math
import random
import struct
from pathlib import Path
from types import ModuleType

import pytest

import controller
from controller import kernels
from controller.types import wrap_angle
from dbc.runtime.compiled import compiled


def _source() -> ModuleType:
    path = Path(kernels.__file__).with_name("kernels.py")
    spec = importlib.util.spec_from_file_location("kernels_from_source", path)
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert not compiled(mod)
    return mod


def _bits(values: list[float]) -> list[bytes]:
    return [struct.pack("<d", v) for v in values]


def _intervals(rng: random.Random, n: int, r0: float) -> list[tuple[float, ...]]:
    out = []
    th_l, th_r = rng.uniform(-50, 50), rng.uniform(-50, 50)
    for i in range(n):
        dth_l = rng.uniform(-0.6, 0.6)
        # every other interval nearly straight: the arc's series branch (|dphi / 2| < 1e-4)
        dth_r = dth_l * (1 + 1e-6) if i % 2 else rng.uniform(-0.6, 0.6)
        out.append((th_l, dth_l, th_r, dth_r, r0 * dth_l, r0 * dth_r))
        th_l, th_r = th_l + dth_l, th_r + dth_r
    return out


def test_the_kernels_are_compiled_where_the_package_was_built_with_mypyc() -> None:
    if not any(Path(kernels.__file__).parent.glob("kernels.*.so")):
        pytest.skip("this install has no compiled bench (no mypyc or C compiler at install)")
    assert compiled(kernels), controller.SOURCES_BECAUSE


@pytest.mark.parametrize("kind", range(6))
def test_bank_step_gives_the_same_bits_compiled_as_from_source(kind: int) -> None:
    src = _source()
    rng = random.Random(kind)
    n_par = {kernels.NOMINAL: 0, kernels.BUMP_LEFT: 2, kernels.BUMP_RIGHT: 2}.get(kind, 1)
    r0, b = 0.17, 0.28
    straight = 0
    for trial in range(200):
        par = [rng.uniform(0.001, 0.16) for _ in range(n_par)]
        start = [rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-4, 4), *par]
        iv = _intervals(rng, rng.randint(0, 12), r0)
        straight += sum(1 for t in iv if abs(0.5 * (t[5] - t[4]) / (2 * b)) < 1e-4)
        args = (kind, n_par, r0, b, 1e-4, 2e-5, start, iv)
        got_f, got_x = kernels.bank_step(*args)
        want_f, want_x = src.bank_step(*args)
        assert len(got_f) == 20 and len(got_x) == 3 + n_par
        assert _bits(got_f) == _bits(want_f), (kind, trial)
        assert _bits(got_x) == _bits(want_x), (kind, trial)
    assert straight > 100  # the series branch was taken


def test_a_non_finite_travel_gives_non_finite_results_not_an_exception() -> None:
    iv = [(0.0, math.nan, 0.0, 0.1, math.nan, 0.017)]
    f, x = kernels.bank_step(
        kernels.FLAT_LEFT, 1, 0.17, 0.28, 1e-4, 2e-5, [0.0, 0.0, 0.0, 0.16], iv
    )
    assert not all(map(math.isfinite, f + x))


def test_the_kernels_angle_wrap_is_the_controllers() -> None:
    src = _source()
    rng = random.Random(7)
    angles = [rng.uniform(-100, 100) for _ in range(2000)]
    angles += [math.pi, -math.pi, 0.0, -0.0, 3 * math.pi, 1e300, math.inf, -math.inf, math.nan]
    for a in angles:
        want = wrap_angle(a)
        for f in (kernels.wrap_angle, src.wrap_angle):
            got = f(a)
            assert (math.isnan(got) and math.isnan(want)) or _bits([got]) == _bits([want]), a


def _arc_step_from_the_formula(
    x: float, y: float, phi: float, dl: float, dr: float, b: float
) -> tuple[float, float, float, float, float]:
    """The exact arc written out here, independently of the module (the same operations)."""
    ds, dphi = 0.5 * (dr + dl), (dr - dl) / (2.0 * b)
    half = 0.5 * dphi
    h2 = half * half
    chord = (
        ds * (1.0 - h2 / 6.0 + h2 * h2 / 120.0) if abs(half) < 1e-4 else ds * math.sin(half) / half
    )
    mid = phi + half
    return (
        x + chord * math.cos(mid),
        y + chord * math.sin(mid),
        wrap_angle(phi + dphi),
        chord,
        dphi,
    )


def test_the_arc_step_gives_the_same_bits_compiled_as_from_source() -> None:
    src = _source()
    rng = random.Random(11)
    series = 0
    for trial in range(3000):
        dl = rng.uniform(-0.05, 0.05)
        dr = dl * (1 + rng.uniform(-1e-4, 1e-4)) if trial % 2 else rng.uniform(-0.05, 0.05)
        args = (rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-4, 4), dl, dr, 0.28)
        series += abs(0.5 * (dr - dl) / 0.56) < 1e-4
        want = _arc_step_from_the_formula(*args)
        assert _bits(list(kernels.arc_step(*args))) == _bits(list(want)), args
        assert _bits(list(src.arc_step(*args))) == _bits(list(want)), args
    assert series > 1000  # the series branch was taken
    # a non-finite travel: NaN out, no exception (nothing may raise at tick time)
    assert not all(map(math.isfinite, kernels.arc_step(0.0, 0.0, 0.0, math.nan, 0.1, 0.28)))


def _spd(rng: random.Random, n: int) -> list[float]:
    """A random symmetric positive definite n x n matrix, row by row (A A' + n I, scaled)."""
    a = [[rng.uniform(-1, 1) for _ in range(n)] for _ in range(n)]
    s = rng.choice((1e-6, 1e-3, 1.0))
    return [
        s * (sum(a[i][k] * a[j][k] for k in range(n)) + (n if i == j else 0.0))
        for i in range(n)
        for j in range(n)
    ]


def _flat(out: object) -> list[float]:
    """Every float in a kernel's (nested) result, in order; None as NaN."""
    if out is None:
        return [math.nan]
    if isinstance(out, float | int):
        return [float(out)]
    assert isinstance(out, list | tuple)
    return [v for item in out for v in _flat(item)]


def _same_bits(a: object, b: object) -> bool:
    fa, fb = _flat(a), _flat(b)
    return len(fa) == len(fb) and all(
        (math.isnan(x) and math.isnan(y)) or _bits([x]) == _bits([y])
        for x, y in zip(fa, fb, strict=True)
    )


def test_the_fault_banks_algebra_gives_the_same_bits_compiled_as_from_source() -> None:
    """Covariance step, innovation, Joseph update, IMM mixing and the probabilities, for
    filters of 3, 4 and 5 states, over random states (non-finite ones included)."""
    src = _source()
    rng = random.Random(5)
    R = [6.25e-4, 0.0, 0.0, 0.0, 6.25e-4, 0.0, 0.0, 0.0, 1.5625e-4]
    mixed = 0
    for trial in range(300):
        n = 3 + trial % 3
        x = [rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-3, 3)]
        x += [rng.uniform(0.0, 0.2) for _ in range(n - 3)]
        P = _spd(rng, n)
        if trial % 50 == 7:
            P[n + 1] = math.inf
        entries = [rng.uniform(-0.1, 0.1) for _ in range(20)]
        entries[6] = 1.0
        for mod in (kernels, src):
            assert isinstance(mod.bank_covariance_step(P, n, entries), tuple)
        assert _same_bits(
            kernels.bank_covariance_step(P, n, entries), src.bank_covariance_step(P, n, entries)
        )
        assert _same_bits(kernels.step_matrices(n, entries), src.step_matrices(n, entries))
        z = [x[0] + rng.gauss(0, 0.05), x[1] + rng.gauss(0, 0.05), x[2] + rng.gauss(0, 0.02)]
        inn = kernels.bank_innovation(x, P, n, z, R)
        assert _same_bits(inn, src.bank_innovation(x, P, n, z, R))
        if inn is not None:
            ysi = inn[2]
            assert _same_bits(
                kernels.bank_update(x, P, n, ysi, R), src.bank_update(x, P, n, ysi, R)
            )
        assert kernels.positive_definite(P, n) == src.positive_definite(P, n)
        # a bank of six filters: mixing and probabilities
        dims = [3, 4, 4, 5, 5, 4]
        xs = [[*x[:3], *[rng.uniform(0.0, 0.2) for _ in range(d - 3)]] for d in dims]
        for k in range(1, 6):
            xs[k][0] += rng.gauss(0, 0.05)
            xs[k][2] += rng.gauss(0, 0.05)
        Ps = [_spd(rng, d) for d in dims]
        prob = [rng.uniform(0.01, 1.0) for _ in dims]
        prob = [p / sum(prob) for p in prob]
        prior = [0.8] + [0.04] * 5
        var = [[4e-4] * (d - 3) for d in dims]
        eps = rng.choice((0.0, 1e-5, 1e-3, 0.1))
        got = ([list(v) for v in xs], [list(v) for v in Ps])
        want = ([list(v) for v in xs], [list(v) for v in Ps])
        c1, m1 = kernels.imm_mix(prob, prior, eps, *got, dims, var)
        c2, m2 = src.imm_mix(prob, prior, eps, *want, dims, var)
        assert m1 == m2 and _same_bits(c1, c2) and _same_bits(got, want)
        mixed += len(m1)
        ll = [rng.uniform(-50, 5) for _ in dims]
        assert _same_bits(kernels.posterior(prob, ll), src.posterior(prob, ll))
        # the whole bank's prediction and fix update
        kinds = list(range(6))
        los, his = [0.0, 0.15, 0.15, 0.005, 0.005, 0.03], [0.0, 0.16, 0.16, 0.05, 0.05, 0.9]
        walks = [0.0, 2e-5, 2e-5, 2e-6, 2e-6, 2e-4]
        iv = _intervals(rng, rng.randint(0, 12), 0.17)
        states = [([list(v) for v in xs], [list(v) for v in Ps]) for _ in (0, 1)]
        flushed = [
            mod.bank_flush(kinds, 0.17, 0.28, 1e-6, walks, los, his, *st, iv)
            for mod, st in zip((kernels, src), states, strict=True)
        ]
        assert _same_bits(flushed[0][0], flushed[1][0]) and flushed[0][1] == flushed[1][1]
        assert _same_bits(states[0], states[1])
        fixed = [
            mod.bank_fix(kinds, los, his, *st, z, R, 25.0)
            for mod, st in zip((kernels, src), states, strict=True)
        ]
        assert fixed[0][0] == fixed[1][0] and fixed[0][4] == fixed[1][4]
        assert _same_bits(fixed[0][1:4], fixed[1][1:4]) and _same_bits(states[0], states[1])
        for kind, lo, hi in zip(kinds, los, his, strict=True):
            par = [rng.uniform(-0.2, 0.3) for _ in range({0: 0, 3: 2, 4: 2}.get(kind, 1))]
            assert _same_bits(kernels.project(kind, lo, hi, par), src.project(kind, lo, hi, par))
    assert mixed > 100


def test_the_pose_ekfs_prediction_gives_the_same_bits_compiled_as_from_source() -> None:
    src = _source()
    rng = random.Random(9)
    for trial in range(2000):
        x = [rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-3, 3), rng.gauss(0, 0.02)]
        p = _spd(rng, 4)
        P = (p[0], p[1], p[2], p[3], p[5], p[6], p[7], p[10], p[11], p[15])
        dl = rng.uniform(-0.02, 0.02)
        dr = dl * (1 + rng.uniform(-1e-4, 1e-4)) if trial % 2 else rng.uniform(-0.02, 0.02)
        if trial % 400 == 3:
            dl = 1e200  # finite (the caller refuses others), its variance not: None
        args = (x, P, dl, dr, 0.28, 1e-5, 0.01, 0.002)
        got = kernels.pose_predict(*args)
        assert _same_bits(got, src.pose_predict(*args)), args
        assert (got is None) == (dl == 1e200)


def test_the_limiters_step_gives_the_same_bits_compiled_as_from_source() -> None:
    """Targets in and beyond every limit, signed zeros included (the builtins' min and max
    keep their first argument on a tie, and so must the kernel)."""
    src = _source()
    rng = random.Random(13)
    limits = (1.3, 0.6, 1.2, 9.0, 4.0, 1.0, 1.5, 2.0)
    state = (0.0, 0.0, 0.0, 0.0)
    for trial in range(5000):
        v_t = rng.choice((0.0, -0.0, 1.3, -0.6, rng.uniform(-3, 3)))
        w_t = rng.choice((0.0, -0.0, 1.2, rng.uniform(-4, 4)))
        h = rng.choice((0.01, 0.01, 0.0, 0.02))
        got = kernels.limit_step(v_t, w_t, h, state, limits, 0.28, 0.17)
        want = src.limit_step(v_t, w_t, h, state, limits, 0.28, 0.17)
        assert _same_bits(got, want), (trial, v_t, w_t, h, state)
        assert all(_bits([x]) == _bits([y]) for x, y in zip(got[:6], want[:6], strict=True))
        state = got[:4] if trial % 50 else (0.0, -0.0, 0.0, -0.0)


def test_the_reference_gives_the_same_bits_compiled_as_from_source() -> None:
    """The paper route's reference (controller.planner): the spline's samples over the whole
    route, at random times and at the segments' joints."""
    from controller.planner import load_route, plan

    src = _source()
    traj = plan(load_route(Path(controller.__file__).parents[1] / "scenarios/routes/paper.toml"))
    args = (traj._profile, traj._length, *traj._geo)
    rng = random.Random(17)
    times = [rng.uniform(0.0, traj.duration_s) for _ in range(3000)]
    times += [t for t in traj._pt if 0.0 < t < traj.duration_s]
    for t in times:
        got = kernels.spline_sample(t, *args)
        assert _same_bits(got, src.spline_sample(t, *args)), t
        r = traj.sample(t)
        assert (r.x_m, r.y_m, r.heading_rad, r.v_mps, r.s_m) == (
            got[0],
            got[1],
            got[2],
            got[3],
            got[8],
        )


def test_mixing_leaves_a_filter_nobody_can_switch_to_as_it_is() -> None:
    """A fault hypothesis with a prior of 0 whose probability underflowed (c_j = 0) has no
    mixture: it keeps its state, and nothing divides by zero at tick time."""
    for mod in (kernels, _source()):
        xs = [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0, 0.16]]
        Ps = [[1e-4 if i % 4 == 0 else 0.0 for i in range(9)], [0.0] * 16]
        for i in range(4):
            Ps[1][i * 5] = 1e-4
        before = [list(v) for v in xs], [list(v) for v in Ps]
        c, mixed = mod.imm_mix([1.0, 0.0], [1.0, 0.0], 0.01, xs, Ps, [3, 4], [[], [4e-4]])
        assert c[1] == 0.0 and 1 not in mixed
        assert (xs[1], Ps[1]) == (before[0][1], before[1][1])
