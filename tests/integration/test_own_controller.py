"""A controller of one's own, from its own package, with no edit of this one
(docs/own-controller.md): ``examples/own_controller`` installed as the guide says, then chosen
by name by ``run``, listed by ``params``, refused by ``tune`` without its search space with a
message naming ``--space``, and tracking the route from a start 30 cm off it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "own_controller"


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The example installed with pip (its own build, into a directory of its own: the
    checkout's venv stays as it is), and the environment that sees it."""
    target = tmp_path_factory.mktemp("own-controller")
    res = subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", target, EXAMPLE],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    return {**os.environ, "PYTHONPATH": str(target)}


def _cli(env: dict[str, str], cwd: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tools.cli", *argv],
        cwd=cwd, env={**env, "PYTHONPATH": f"{env['PYTHONPATH']}{os.pathsep}{ROOT}"},
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip


def test_an_installed_controller_runs_by_name_from_a_large_start_error(
    installed: dict[str, str], tmp_path: Path
) -> None:
    res = _cli(installed, tmp_path, "run", "--controller", "PURSUIT", "--scenario",
               "start-right-of-path", "--bus", "virtual", "--out", str(tmp_path / "run"))  # fmt: skip
    assert res.returncode == 0, res.stderr
    # it runs on its Params defaults, and says so
    assert "'pursuit' has no [pursuit] section" in res.stderr and "--space" in res.stderr
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["controller"] == "pursuit"
    assert summary["stop_reason"] == "ROUTE_DONE", summary["stop_reason"]
    assert summary["max_pos_err_m"] > 0.25  # it started 30 cm off the path ...
    assert summary["final_pos_err_m"] < 0.05  # ... and ended on it
    params = _cli(installed, tmp_path, "params")
    assert (
        params.returncode == 0 and "pursuit" in params.stdout and "lookahead_min_m" in params.stdout
    )


def test_tuning_it_needs_its_search_space_and_says_how(
    installed: dict[str, str], tmp_path: Path
) -> None:
    res = _cli(installed, tmp_path, "tune", "--controller", "pursuit", "--dry-run")
    assert res.returncode != 0
    assert "has no [pursuit]" in res.stderr and "--space FILE" in res.stderr
    # with the example's space file it is accepted up to the budget check (a budget of 1 is
    # too small for any controller: refused before any run, naming the budget)
    res = _cli(installed, tmp_path, "tune", "--controller", "pursuit", "--space",
               str(EXAMPLE / "space.toml"), "--budget", "1", "--dry-run")  # fmt: skip
    assert res.returncode != 0, res.stderr
    assert "--budget 1: at least 36 objective evaluations for pursuit" in res.stderr


def test_a_plugin_cannot_take_a_built_in_laws_name(tmp_path: Path) -> None:
    dist = tmp_path / "fake-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: fake\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[wheelchair_hil.controllers]\nrobust = pursuit_controller:PurePursuit\n"
    )
    probe = (
        "from controller.tracking import registry\n"
        "print(registry.controller_class('robust').__name__, 'robust' in registry.plugins())\n"
    )
    res = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=False,
        env={**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}"},
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["RobustSMC", "False"]
    assert "a built-in law's name; ignored" in res.stderr
