"""A saved plan (``run`` hands it to the bench and controller it starts): the same trajectory,
bit for bit, and a file that is not the plan of the part's route refused naming the file."""

from __future__ import annotations

import dataclasses
import json
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from controller.planner import RouteParams, load_plan, load_route, plan, save_plan
from dbc.runtime.errors import ConfigError

ROOT = Path(__file__).resolve().parents[3]
PAUSE = RouteParams(
    waypoints_m=((0.0, 0.0), (3.0, 0.5), (5.0, 3.0), (3.0, 5.0)),
    start_heading_rad=0.3,
    stops=((1, 2.0),),
)


def _bits(x: object) -> object:
    return struct.pack("<d", x) if isinstance(x, float) else x


@pytest.mark.parametrize("route", [load_route(ROOT / "scenarios/routes/paper.toml"), PAUSE])
def test_a_loaded_plan_samples_every_instant_as_the_planned_one(
    tmp_path: Path, route: RouteParams
) -> None:
    planned = plan(route)
    save_plan(planned, tmp_path / "plan.npz")
    loaded = load_plan(tmp_path / "plan.npz", route)
    t = np.concatenate(([-1.0, 0.0, float("nan")], np.linspace(0, planned.duration_s + 2, 9001)))
    for ti in t:
        a, b = planned.sample(float(ti)), loaded.sample(float(ti))
        assert [_bits(v) for v in dataclasses.astuple(a)] == [
            _bits(v) for v in dataclasses.astuple(b)
        ], ti
    many_a, many_b = planned.sample_many(t), loaded.sample_many(t)
    for key, value in many_a.items():
        assert np.array_equal(value, many_b[key], equal_nan=True), key
    assert loaded.comfort_report() == planned.comfort_report()
    assert (loaded.duration_s, loaded.length_m) == (planned.duration_s, planned.length_m)


def test_the_plan_of_another_route_is_refused_naming_the_file(tmp_path: Path) -> None:
    save_plan(plan(PAUSE), tmp_path / "plan.npz")
    other = dataclasses.replace(PAUSE, v_max_mps=0.9)
    with pytest.raises(ConfigError, match=r"plan\.npz: the saved plan is of another route"):
        load_plan(tmp_path / "plan.npz", other, "route.toml")


@pytest.mark.parametrize("content", [b"", b"not a plan", None])
def test_a_file_that_is_no_plan_is_refused_naming_it(tmp_path: Path, content: bytes | None) -> None:
    f = tmp_path / "plan.npz"
    if content is None:  # an npz, but not of a plan
        np.savez(f, x=np.zeros(3))
    else:
        f.write_bytes(content)
    with pytest.raises(ConfigError, match=r"plan\.npz: not a (readable )?saved plan"):
        load_plan(f, PAUSE)
    with pytest.raises(ConfigError, match=r"missing\.npz: not a readable saved plan"):
        load_plan(tmp_path / "missing.npz", PAUSE)


def test_a_saved_plan_without_an_entry_is_refused_naming_it(tmp_path: Path) -> None:
    save_plan(plan(PAUSE), tmp_path / "full.npz")
    with np.load(tmp_path / "full.npz") as z:
        kept = {k: z[k] for k in z.files if k != "profile_pv"}
    np.savez(tmp_path / "cut.npz", **kept)
    with pytest.raises(ConfigError, match=r"cut\.npz: the saved plan lacks 'profile_pv'"):
        load_plan(tmp_path / "cut.npz", PAUSE)


_PART = """
import argparse, json, sys
from tools.cli import from_args
args = argparse.Namespace(scenario="short", realtime=False, duration=None, seed=None, plan=PLAN)
p = from_args.run_plan(args, "baseline")
print(json.dumps({"loaded": sorted(m for m in ("scipy.interpolate", "scipy.ndimage",
    "scipy.signal") if m in sys.modules), "duration": p.trajectory.duration_s}))
"""


def test_a_part_given_the_saved_plan_plans_nothing_and_gets_the_same_route(
    tmp_path: Path,
) -> None:
    from tools.run import scenario

    route = scenario.load("short").route
    save_plan(plan(route), tmp_path / "plan.npz")

    def part(plan_file: str | None) -> dict[str, object]:
        code = _PART.replace("PLAN", repr(plan_file))
        out = subprocess.run(
            [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout
        return dict(json.loads(out.splitlines()[-1]))

    with_plan, without = part(str(tmp_path / "plan.npz")), part(None)
    assert with_plan["loaded"] == []
    assert without["loaded"] == ["scipy.interpolate", "scipy.ndimage", "scipy.signal"]
    assert with_plan["duration"] == without["duration"]
