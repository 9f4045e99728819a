"""The OSQP calls of the MPC (ADAPTIVE): the set-up, and the calls of each tick.

``osqp.OSQP.update()`` looks ``OSQP_INFTY`` up through importlib twice per call and clips the
bounds (about 30 us a tick), and ``OSQP.solve()`` copies every info field into a new
namespace (about 17 us).  Our bounds are clipped already and the step reads four info
fields, so :class:`TickSolver` goes straight to the extension calls that those two methods
make themselves, and falls back to them if the extension does not have them.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import osqp
import scipy.sparse as sp

from dbc.runtime.errors import ConfigError

SOLVED = 1  # osqp SolverStatus.OSQP_SOLVED
MAX_ITER = int(osqp.SolverStatus.OSQP_MAX_ITER_REACHED)  # stopped at max_iter
INF = float(osqp.constant("OSQP_INFTY"))  # OSQP clips infinite bounds to this anyway


class QPData(NamedTuple):
    """One MPC problem in OSQP's form: min 1/2 z'Pz + q'z  s.t.  l <= Az <= u.

    ``P`` holds the upper triangle only (OSQP's convention; it is diagonal here).
    """

    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    l: np.ndarray  # noqa: E741 (OSQP's name)
    u: np.ndarray


def setup_solver(
    P: sp.csc_matrix,
    q: np.ndarray,
    A: sp.csc_matrix,
    l: np.ndarray,  # noqa: E741 (OSQP's name)
    u: np.ndarray,
    p: Any,
    who: str,
) -> osqp.OSQP:
    """An ``osqp.OSQP`` set up on the problem with the settings in ``p`` (an MPC's Params).

    Warm-started, unpolished, quiet.  ConfigError naming ``who`` if OSQP refuses the problem
    or a setting.
    """
    solver = osqp.OSQP()
    try:
        solver.setup(
            P,
            q,
            A,
            l,
            u,
            verbose=False,
            warm_starting=True,
            polishing=False,
            max_iter=p.max_iter,
            eps_abs=p.eps_abs,
            eps_rel=p.eps_rel,
            rho=p.rho,
            adaptive_rho_interval=p.adaptive_rho_interval,
            check_termination=p.check_termination,
            scaling=p.scaling,
        )
    except Exception as err:  # OSQPException / ValueError from the extension
        raise ConfigError(f"{who}: OSQP set-up failed: {err}") from err
    return solver


class TickSolver:
    """A set-up ``osqp.OSQP`` whose data keep their sparsity pattern from tick to tick."""

    __slots__ = ("_ext", "solver")

    def __init__(self, solver: osqp.OSQP) -> None:
        self.solver = solver
        ext = getattr(solver, "_solver", None)
        needed = ("update_data_vec", "update_data_mat", "solve", "info", "solution")
        self._ext = ext if all(hasattr(ext, a) for a in needed) else None

    def push(self, Px: np.ndarray, Ax: np.ndarray, l: np.ndarray, u: np.ndarray) -> int:  # noqa: E741
        """Hand this tick's values (same pattern) to OSQP; non-zero: OSQP's error code."""
        ext = self._ext
        if ext is None:
            self.solver.update(Px=Px, Ax=Ax, l=l, u=u)
            return 0
        err = ext.update_data_vec(q=None, l=l, u=u)
        return int(err) or int(ext.update_data_mat(P_x=Px, P_i=None, A_x=Ax, A_i=None))

    def solve(self) -> tuple[Any, np.ndarray | None]:
        """Solve (warm-started); ``(info, x)``, ``info`` with OSQP's field names."""
        ext = self._ext
        if ext is None:
            res = self.solver.solve(raise_error=False)
            return res.info, res.x
        ext.solve()
        return ext.info, ext.solution.x
