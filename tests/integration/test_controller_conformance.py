"""Every registered controller, through the whole stack on the virtual bus, in lock-step.

Same gains for every scenario.  Each must track the paper route fault-free and stop at its
end (a named variant of one of them: the short route), keep every command finite and inside
the limits, and start from rest.  The hard starts and the pause are in
test_controller_hard_starts.py (a file of its own: make test gives each file to one worker).
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from controller.tracking import registry
from tests.integration.conftest import check_commands, run_unlogged

# make test starts the heaviest files first (tests/conftest.py)
pytestmark = pytest.mark.heavy(seconds=52)

CONTROLLERS = registry.names()
#: The paper's four and BASELINE: the main job's controllers, on the paper route.  Any other
#: registered name (a variant of one of them) is held to the same checks on the short route
#: (a paper-route run costs about 15 s of CPU each).
MAIN = ("baseline", "antifragile", "robust", "adaptive", "resilient")
ALTERNATIVES = tuple(c for c in CONTROLLERS if c not in MAIN)


@pytest.mark.parametrize(
    ("name", "scenario"),
    [*((c, "fault-free") for c in MAIN), *((c, "short") for c in ALTERNATIVES)],
)
def test_controller_tracks_the_paper_route_and_stops_at_its_end(
    tmp_path: Path, name: str, scenario: str
) -> None:
    s, bus = run_unlogged(tmp_path, scenario, name)
    assert s["stop_reason"] == "ROUTE_DONE", s
    assert s["max_pos_err_m"] < 0.5
    assert s["deadline_misses"] == 0
    check_commands(bus)
    if name == "antifragile":  # the envelope the paper reports in its Fig. 11
        assert s["max_pos_err_m"] <= 0.05
        assert math.degrees(s["max_phie_rad"]) <= 4.0
