"""Fixtures of the tracking laws' tests: the packaged short route."""

from __future__ import annotations

from pathlib import Path

import pytest

from controller.planner import load_route, plan
from controller.types import Trajectory

ROUTES = Path(__file__).resolve().parents[4] / "scenarios" / "routes"


@pytest.fixture(scope="module")
def short() -> Trajectory:
    return plan(load_route(ROUTES / "short.toml"))
