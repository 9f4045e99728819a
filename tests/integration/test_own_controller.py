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

# make test starts the heaviest files first (tests/conftest.py)
pytestmark = pytest.mark.heavy(seconds=26)

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


def test_a_campaign_judges_it_against_the_papers_laws_in_a_family_of_its_own(
    installed: dict[str, str], tmp_path: Path
) -> None:
    out = tmp_path / "eval"
    res = _cli(installed, tmp_path, "evaluate", "--out", str(out), "--controllers",
               "antifragile,robust,pursuit", "--scenarios", "fault-free", "--settings",
               "physical", "--seeds", "3", "--duration", "20", "--no-cascaded",
               "--no-figures", "--no-progress", "--workers", "2")  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    results = json.loads((out / "results.json").read_text())
    block = results["settings"]["physical"]
    tests = block["challenger_tests"]
    assert set(tests) == {"rmse_xe_m", "rmse_ye_m", "rmse_phie_rad"}
    pairs = {k for m in tests.values() for k in m}
    assert pairs == {"pursuit|antifragile", "pursuit|robust"}
    for m in tests.values():
        for t in m.values():
            assert t["n"] == 3 and t["family"] == 6
            assert t["verdict"] in ("better", "worse", "undecided")
    # the paper's pairs keep their own family (one pair, three components)
    assert {t["family"] for m in block["pair_tests"].values() for t in m.values()} == {3}
    report = (out / "report.md").read_text()
    assert "### Controllers of your own against the paper's four" in report
    assert "| PURSUIT - ANTIFRAGILE |" in report
    assert "PURSUIT ran on its Params defaults" in report
