"""The MPC machinery apart from its model (controller/tracking/mpc.py, qp.py): pattern, preview, tabulation, set-up."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.sparse as sp

from controller.tracking.adaptive import AdaptiveMPC
from controller.tracking.mpc import Pattern, Preview, diagonal, reference_columns
from controller.tracking.qp import SOLVED, TickSolver, setup_solver
from controller.types import ReferenceSample
from dbc.runtime.errors import ConfigError


def test_the_pattern_keeps_zero_entries_structural_and_knows_their_positions() -> None:
    pat = Pattern()
    entries = [(2, 1, 0.0), (0, 0, 1.0), (1, 2, -3.0), (2, 0, 0.0), (0, 2, 5.0)]
    for r, c, v in entries:
        pat.add(r, c, v)
    A, pos = pat.csc((3, 3))
    assert A.nnz == len(entries)  # the zeros were not dropped
    for k, (r, c, v) in enumerate(entries):
        assert A.data[pos[k]] == v
        A.data[pos[k]] = 10.0 + k  # written in place through the position
        assert A[r, c] == 10.0 + k
    P = diagonal(4)
    assert P.nnz == 4 and not P.data.any()


def _linear_table(n: int) -> np.ndarray:
    t = np.arange(n, dtype=float)
    return np.stack([t, 2.0 * t + 1.0], axis=1)


def test_the_preview_interpolates_every_stage_on_both_paths() -> None:
    grid, T, N = 0.01, 0.1, 5
    tab = _linear_table(200)  # column 0 = grid index, column 1 = 2 * index + 1
    strided = Preview(tab, grid, T, N)
    general = Preview(tab, grid, T * 1.05, N)  # T not a multiple of the grid
    out = np.zeros((N, 2))
    strided.rows(0.123, out)
    expect = (0.123 + np.arange(N) * T) / grid
    assert out[:, 0] == pytest.approx(expect)
    assert out[:, 1] == pytest.approx(2.0 * expect + 1.0)
    general.rows(0.123, out)
    assert out[:, 0] == pytest.approx((0.123 + np.arange(N) * T * 1.05) / grid)
    # beyond the table the reference rests at its last row; before it, at its first
    strided.rows(10.0, out)
    assert (out[:, 0] == 199.0).all()
    strided.rows(-1.0, out)
    assert out[0, 0] == 0.0


class _Line:
    def __init__(self, duration: float) -> None:
        self.duration_s = duration

    def sample(self, t: float) -> ReferenceSample:
        return ReferenceSample(t, 0.5 * t, 0.0, 0.0, 0.5, 0.0)


def test_reference_columns_rest_at_the_end_and_refuse_unusable_routes() -> None:
    t, (v, w) = reference_columns(_Line(1.0), 0.1, ("v_mps", "omega_radps"), "law")
    assert t[0] == 0.0 and t[-1] == 1.0 and len(t) == 11
    assert (v[:-1] == 0.5).all() and v[-1] == 0.0 and not w.any()
    with pytest.raises(ConfigError, match="law: trajectory duration nan s is not usable"):
        reference_columns(_Line(math.nan), 0.1, ("v_mps",), "law")
    with pytest.raises(ConfigError, match=r"law: a 1000000\.0 s route needs a coarser"):
        reference_columns(_Line(1e6), 0.1, ("v_mps",), "law")


def test_an_osqp_set_up_failure_is_a_config_error_naming_the_law() -> None:
    p = dataclasses.replace(AdaptiveMPC.Params(), rho=-1.0)  # bypasses load's bounds
    P = diagonal(2)
    P.data[:] = 1.0
    A = diagonal(2)
    A.data[:] = 1.0
    with pytest.raises(ConfigError, match="adaptive: OSQP set-up failed"):
        setup_solver(P, np.zeros(2), A, np.zeros(2), np.ones(2), p, "adaptive")


class _WrapperOnly:
    """An OSQP solver seen without its extension: TickSolver must go through the wrapper."""

    def __init__(self, solver: object) -> None:
        self._inner = solver

    def update(self, **kw: object) -> None:
        self._inner.update(**kw)  # type: ignore[attr-defined]

    def solve(self, raise_error: bool = False) -> object:
        return self._inner.solve(raise_error=raise_error)  # type: ignore[attr-defined]


def test_the_tick_path_solves_the_same_problem_directly_and_through_the_wrapper() -> None:
    p = AdaptiveMPC.Params()
    P = sp.csc_matrix(np.diag([2.0, 4.0]))
    A = sp.csc_matrix(np.array([[1.0, 1.0], [1.0, 0.0]]))
    q, lo, hi = np.array([-1.0, -1.0]), np.array([1.0, -10.0]), np.array([1.0, 10.0])
    direct = TickSolver(setup_solver(P, q, A, lo, hi, p, "test"))
    wrapped = TickSolver(_WrapperOnly(setup_solver(P, q, A, lo, hi, p, "test")))  # type: ignore[arg-type]
    for lo0 in (1.0, 0.5):  # the second tick: new bounds in place, same pattern
        lo[0] = hi[0] = lo0
        assert direct.push(P.data, A.data, lo, hi) == 0
        assert wrapped.push(P.data, A.data, lo, hi) == 0
        (i1, x1), (i2, x2) = direct.solve(), wrapped.solve()
        assert int(i1.status_val) == int(i2.status_val) == SOLVED
        assert x1 is not None and x2 is not None
        assert x1 == pytest.approx(x2, abs=1e-9)
        assert x1.sum() == pytest.approx(lo0, abs=2e-3)
