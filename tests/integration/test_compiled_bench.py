"""The compiled modules (dbc/runtime/compiled.py: the bench's inner loops, the controller's
float kernels) change no figure: a run with them and the same run from source
(``WHEELCHAIR_HIL_PURE_PYTHON=1``, another process) give the same summary and the same
setpoints; a compiled module older than its source is not used."""

from __future__ import annotations

import importlib.machinery
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import controller as controller_pkg
import firmware_sim
from controller import kernels
from dbc.runtime import compiled as compiled_mod
from firmware_sim import plant
from tests.integration.conftest import WALL_CLOCK_KEYS, setpoints
from tools.run import scenario as scenario_mod
from tools.run.experiment import run_experiment

PACKAGE_DIR = Path(firmware_sim.__file__).resolve().parent
#: a bench fault from 20 s, so the faulted paths of the physics and the drives run too
RUN = ("flat-left", "physical", "antifragile", 24.0)

_SOURCE_RUN = """
import json, sys
import firmware_sim, firmware_sim.plant as plant, controller.kernels as kernels
from dbc.runtime.compiled import compiled
from tools.run import scenario as scenario_mod
from tools.run.experiment import run_experiment
name, setting, controller, duration = json.loads(sys.argv[1])
scen = scenario_mod.with_setting(scenario_mod.load(name), setting)
summary = run_experiment(sys.argv[2], scen, controller, duration_s=duration)
print(json.dumps({"compiled": compiled(plant) or compiled(kernels), "summary": summary}, default=str))
"""


def _figures(summary: dict[str, Any]) -> dict[str, Any]:
    kept = {k: v for k, v in summary.items() if k not in WALL_CLOCK_KEYS}
    return dict(json.loads(json.dumps(kept, sort_keys=True, default=str)))


def _installed_compiled() -> bool:
    return any(
        (PACKAGE_DIR / f"{m}{ext}").exists()
        for m in compiled_mod.MODULES["firmware_sim"]
        for ext in importlib.machinery.EXTENSION_SUFFIXES
    )


def test_the_compiled_bench_and_the_bench_from_source_give_the_same_run(tmp_path: Path) -> None:
    if not _installed_compiled():
        pytest.skip("this install has no compiled bench (no mypyc or C compiler at install)")
    assert compiled_mod.compiled(plant), firmware_sim.SOURCES_BECAUSE
    assert compiled_mod.compiled(kernels), controller_pkg.SOURCES_BECAUSE
    name, setting, controller, duration = RUN
    scen = scenario_mod.with_setting(scenario_mod.load(name), setting)
    here = run_experiment(tmp_path / "compiled", scen, controller, duration_s=duration)
    env = {**os.environ, compiled_mod.PURE_PYTHON_ENV: "1"}
    proc = subprocess.run(
        [sys.executable, "-c", _SOURCE_RUN, json.dumps(RUN), str(tmp_path / "source")],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    there = json.loads(proc.stdout.splitlines()[-1])
    assert there["compiled"] is False
    assert here["samples"] > 1000 and here["fault_diagnosis"]["injected"] == name
    assert _figures(here) == _figures(there["summary"])
    a, b = setpoints(tmp_path / "compiled"), setpoints(tmp_path / "source")
    for side in ("Left", "Right"):
        assert a[side].size > 1000
        np.testing.assert_array_equal(a[side], b[side])


def _touch(path: Path, t: float) -> None:
    path.write_bytes(b"")
    os.utime(path, (t, t))


def test_a_compiled_module_older_than_its_source_is_stale(tmp_path: Path) -> None:
    """In a checkout (setup.py beside the package); an installed wheel's files carry the time
    pip unpacked them, so there nothing is stale (the wheel's own sources were compiled)."""
    ext = importlib.machinery.EXTENSION_SUFFIXES[0]
    now = time.time()
    pkg = tmp_path / "firmware_sim"
    pkg.mkdir()
    mods = compiled_mod.MODULES["firmware_sim"]
    for i, m in enumerate(mods):
        _touch(pkg / f"{m}.py", now - 100)
        _touch(pkg / f"{m}{ext}", now - 50)
        if i == 1:  # this one was edited after the build
            os.utime(pkg / f"{m}.py", (now, now))
    assert compiled_mod.stale(pkg) == []  # installed: no setup.py beside it
    (tmp_path / "setup.py").write_text("")
    assert compiled_mod.stale(pkg) == [mods[1]]
    (pkg / f"{mods[1]}{ext}").unlink()  # not compiled at all: not stale
    assert compiled_mod.stale(pkg) == []
