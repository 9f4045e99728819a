"""The main job's five controllers recover from hard starts and follow a reference that pauses.

Through the whole stack on the virtual bus, in lock-step, with the gains of every other
scenario: a start right of the path (y_e < 0 at low speed), a 90 degree heading error, and a
reference that stops and goes on.  Each run ends at the route's end, near it, with every
command finite, inside the limits and starting from rest.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.integration.conftest import check_commands, run_unlogged
from tests.integration.test_controller_conformance import MAIN

# make test starts the heaviest files first (tests/conftest.py)
pytestmark = pytest.mark.heavy(seconds=60)


@pytest.mark.parametrize("name", MAIN)
@pytest.mark.parametrize("scenario", ["start-right-of-path", "start-heading-90", "short-pause"])
def test_controller_handles_hard_starts_and_pauses(
    tmp_path: Path, name: str, scenario: str
) -> None:
    s, bus = run_unlogged(tmp_path, scenario, name)
    assert s["stop_reason"] == "ROUTE_DONE", s
    assert s["final_pos_err_m"] < 0.15, s["final_pos_err_m"]
    check_commands(bus)
