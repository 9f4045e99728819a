"""controller.ekf: filterpy's EKF without scipy.stats and scipy.ndimage at start-up."""

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
        heavy = ("scipy.stats", "scipy.ndimage", "filterpy.stats", "filterpy.discrete_bayes")
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
