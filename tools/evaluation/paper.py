"""What the paper claims: its published Table "Performance evaluation ..." (the RMSE of each
error component per controller and scenario) and its Rank column.  The results layer judges
our campaign against the rank (tools.evaluation.assemble); the report sets our table beside
the paper's (tools.evaluation.report)."""

from __future__ import annotations

#: The paper's Table (x_e, y_e RMSE as printed, phi_e RMSE as printed; the paper gives no units).
PAPER_TABLE: dict[str, dict[str, dict[str, float]]] = {
    "rmse_xe_m": {
        "robust": {"fault-free": 0.0156, "bump-left": 1.3897, "bump-right": 1.7950, "flat-left": 0.1430, "flat-right": 0.1434},
        "adaptive": {"fault-free": 0.0036, "bump-left": 1.3777, "bump-right": 1.7830, "flat-left": 0.1310, "flat-right": 0.1314},
        "resilient": {"fault-free": 0.6948, "bump-left": 5.5747, "bump-right": 5.1694, "flat-left": 6.8214, "flat-right": 6.8219},
        "antifragile": {"fault-free": 0.0025, "bump-left": 1.3766, "bump-right": 1.7819, "flat-left": 0.1299, "flat-right": 0.1300},
    },
    "rmse_ye_m": {
        "robust": {"fault-free": 0.0005, "bump-left": 0.3538, "bump-right": 1.2162, "flat-left": 0.1689, "flat-right": 0.6052},
        "adaptive": {"fault-free": 0.0007, "bump-left": 0.3540, "bump-right": 1.2159, "flat-left": 0.1691, "flat-right": 0.6053},
        "resilient": {"fault-free": 0.0316, "bump-left": 0.3848, "bump-right": 1.2851, "flat-left": 0.1999, "flat-right": 0.6362},
        "antifragile": {"fault-free": 0.0002, "bump-left": 0.3529, "bump-right": 1.2170, "flat-left": 0.1681, "flat-right": 0.6043},
    },
    "rmse_phie_rad": {
        "robust": {"fault-free": 0.05521, "bump-left": 0.2573, "bump-right": 0.3441, "flat-left": 0.2332, "flat-right": 0.8642},
        "adaptive": {"fault-free": 0.0917, "bump-left": 0.7628, "bump-right": 0.0807, "flat-left": 0.6785, "flat-right": 1.3898},
        "resilient": {"fault-free": 0.5569, "bump-left": 0.2976, "bump-right": 0.3844, "flat-left": 0.2133, "flat-right": 0.8945},
        "antifragile": {"fault-free": 0.0707, "bump-left": 0.1838, "bump-right": 0.1016, "flat-left": 0.6195, "flat-right": 1.3807},
    },
}  # fmt: skip
#: The paper's Rank column.
PAPER_RANK: dict[str, dict[str, int]] = {
    "rmse_xe_m": {"robust": 3, "adaptive": 2, "resilient": 4, "antifragile": 1},
    "rmse_ye_m": {"robust": 2, "adaptive": 3, "resilient": 4, "antifragile": 1},
    "rmse_phie_rad": {"robust": 1, "adaptive": 4, "resilient": 2, "antifragile": 3},
}
