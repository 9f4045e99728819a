"""controller.ekf: filterpy's EKF without scipy.stats, scipy.ndimage and scipy.linalg at
start-up."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def _child(code: str) -> dict[str, object]:
    res = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
        cwd=ROOT,
    )
    out: dict[str, object] = json.loads(res.stdout.splitlines()[-1])
    return out


def test_a_controller_process_loads_neither_scipy_stats_nor_scipy_ndimage() -> None:
    got = _child(
        """
        import json, sys
        import controller.node
        heavy = ("scipy.stats", "scipy.ndimage", "scipy.linalg", "filterpy.stats",
                 "filterpy.discrete_bayes")
        print(json.dumps({"loaded": [m for m in heavy if m in sys.modules]}))
        """
    )
    assert got == {"loaded": []}


def test_the_filters_likelihood_is_filterpys_and_filterpy_stats_is_the_real_module() -> None:
    got = _child(
        """
        import json
        import numpy as np
        from controller.ekf import ExtendedKalmanFilter
        ekf = ExtendedKalmanFilter(dim_x=2, dim_z=1)
        ekf.x = np.array([0.5, -0.2]); ekf.P = np.diag([0.3, 0.1]); ekf.R = np.array([[0.04]])
        ekf.update(np.array([0.9]), HJacobian=lambda x: np.array([[1.0, 0.0]]),
                   Hx=lambda x: np.array([x[0]]))
        ours = float(ekf.log_likelihood)
        import filterpy.stats
        from scipy.stats import multivariate_normal
        real = float(filterpy.stats.logpdf(x=ekf.y, cov=ekf.S))
        ref = float(multivariate_normal.logpdf(ekf.y, cov=ekf.S))
        print(json.dumps({"ours": ours, "real": real, "ref": ref,
                          "has_norm": hasattr(filterpy.stats, "norm")}))
        """
    )
    assert got["ours"] == got["real"] == got["ref"]
    assert got["has_norm"] is True  # the whole module, not the stand-in


def test_filterpys_scipy_linalg_functions_are_scipys_at_first_use_the_module_the_real_one() -> None:
    got = _child(
        """
        import json, sys
        import numpy as np
        from controller.ekf import ExtendedKalmanFilter
        before = "scipy.linalg" in sys.modules
        # filterpy's own update inverts S with the scipy.linalg it took at import
        ekf = ExtendedKalmanFilter(dim_x=2, dim_z=2)
        ekf.x = np.array([0.5, -0.2]); ekf.P = np.array([[0.3, 0.05], [0.05, 0.1]])
        ekf.R = np.diag([0.04, 0.09])
        ekf.update(np.array([0.9, 0.1]), HJacobian=lambda x: np.eye(2), Hx=lambda x: x)
        from filterpy.common import Q_discrete_white_noise
        from filterpy.common.discretization import block_diag as fp_block_diag
        import scipy, scipy.linalg
        print(json.dumps({
            "before": before,
            "SI": ekf.SI.tolist(), "ref_SI": scipy.linalg.inv(ekf.S).tolist(),
            "block": fp_block_diag(np.eye(2), 2 * np.eye(1)).tolist(),
            "ref_block": scipy.linalg.block_diag(np.eye(2), 2 * np.eye(1)).tolist(),
            "real": hasattr(scipy.linalg, "lu_factor") and scipy.linalg is sys.modules["scipy.linalg"]
                    and scipy.linalg.__file__ is not None,
            "q": Q_discrete_white_noise(2, 0.1, 1.0, block_size=2).shape[0],
        }))
        """
    )
    assert got["before"] is False  # not loaded by the import of the EKF
    assert got["SI"] == got["ref_SI"]
    assert got["block"] == got["ref_block"]
    assert got["real"] is True  # ``import scipy.linalg`` after it: the whole module
    assert got["q"] == 4  # filterpy.common's block_diag, through the stand-in
