"""Every registered controller, through the whole stack on the virtual bus, in lock-step.

Same gains for every scenario.  Each must: track the paper route fault-free and stop at
its end (the earlier laws kept as alternatives: the short route); keep every command finite
and inside the limits; start from rest; and the main job's five must recover from a start
right of the path (y_e < 0 at low speed) and from a 90 degree heading error, and follow a
reference that pauses.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from controller.config import load_config
from controller.tracking import registry
from tests.integration.conftest import run_stack, setpoints

CONTROLLERS = registry.names()
#: The paper's four and BASELINE: the main job's controllers, on the paper route.  The
#: project's earlier laws, kept as named alternatives, are held to the same checks on the
#: short route (a paper-route run costs about 15 s of CPU each).
MAIN = ("baseline", "antifragile", "robust", "adaptive", "resilient")
ALTERNATIVES = tuple(c for c in CONTROLLERS if c not in MAIN)
CFG = load_config()


def _check_commands(run_dir: Path) -> None:
    sp = setpoints(run_dir)
    limit_revps = CFG.limits.wheel_max_radps / (2 * math.pi) + 1e-6
    for side in ("Left", "Right"):
        w = sp[side]
        assert w.size > 100
        assert np.all(np.isfinite(w))
        assert np.max(np.abs(w)) <= limit_revps, side
        assert w[0] == 0.0  # starts from rest (neutral command while arming)


@pytest.mark.parametrize(
    ("name", "scenario"),
    [*((c, "fault-free") for c in MAIN), *((c, "short") for c in ALTERNATIVES)],
)
def test_controller_tracks_the_paper_route_and_stops_at_its_end(
    tmp_path: Path, name: str, scenario: str
) -> None:
    s = run_stack(tmp_path, scenario, name)
    assert s["stop_reason"] == "ROUTE_DONE", s
    assert s["max_pos_err_m"] < 0.5
    assert s["deadline_misses"] == 0
    _check_commands(tmp_path)
    if name == "antifragile":  # the envelope the paper reports in its Fig. 11
        assert s["max_pos_err_m"] <= 0.05
        assert math.degrees(s["max_phie_rad"]) <= 4.0


@pytest.mark.parametrize("name", MAIN)
@pytest.mark.parametrize("scenario", ["start-right-of-path", "start-heading-90", "short-pause"])
def test_controller_handles_hard_starts_and_pauses(
    tmp_path: Path, name: str, scenario: str
) -> None:
    s = run_stack(tmp_path, scenario, name)
    assert s["stop_reason"] == "ROUTE_DONE", s
    assert s["final_pos_err_m"] < 0.15, s["final_pos_err_m"]
    _check_commands(tmp_path)
