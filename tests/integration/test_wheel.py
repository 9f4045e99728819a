"""The installable wheel: built from the checkout, installed with its pinned dependencies only
into a fresh venv, and used from a directory that is not the checkout: a short run,
``evaluate --duration`` and ``replay --verify`` find the packaged scenarios and routes.

The wheel is built with pip (``pip wheel --no-deps``, the build backend pinned in
pyproject.toml's ``[build-system]``); the dependencies come from pip's cache or index as
``make install`` gets them.  Each phase's time is printed (``pytest -s`` shows it).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("dbc", "firmware_sim", "controller", "tools")
#: Data files the installed stack cannot run without.
DATA = (
    "dbc/wheelchair.dbc",
    "dbc/keys/TEST-ONLY-secoc.key",
    "controller/controller.toml",
    "controller/gains.toml",
    "firmware_sim/chair.toml",
    "tools/scenarios/fault-free.toml",
    "tools/scenarios/short.toml",
    "tools/scenarios/routes/paper.toml",
    "tools/scenarios/routes/short.toml",
    "tools/scenarios/tuning/gains.toml",
    "tools/scenarios/tuning/space.toml",
)


def _run(argv: list[str | Path], *, cwd: Path, env: dict[str, str], timeout: float = 600) -> str:
    res = subprocess.run(
        [str(a) for a in argv],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )
    assert res.returncode == 0, (
        f"{' '.join(map(str, argv))} exited {res.returncode}\n{res.stdout}\n{res.stderr}"
    )
    return res.stdout


def _clean_env(venv: Path) -> dict[str, str]:
    """The environment of a user who installed the wheel: nothing of this checkout's venv."""
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("PYTHONPATH", "VIRTUAL_ENV", "WHEELCHAIR_HIL_SCENARIOS", "PYTHONHOME")
    }
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    dist = tmp_path_factory.mktemp("dist")
    t0 = time.monotonic()
    _run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", dist, ROOT],
        cwd=dist,
        env=dict(os.environ),
    )
    print(f"\nwheel built in {time.monotonic() - t0:.1f} s")
    (whl,) = dist.glob("wheelchair_hil-*.whl")
    return whl


def test_the_wheel_holds_every_package_and_the_scenarios_routes_and_data(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = [d for d in DATA if d not in names]
    assert not missing, f"{wheel.name} lacks {missing}"
    packages = sorted(
        str(init.parent.relative_to(ROOT))
        for pkg in PACKAGES
        for init in (ROOT / pkg).rglob("__init__.py")
    )
    absent = [p for p in packages if f"{p}/__init__.py" not in names]
    assert not absent, f"{wheel.name} lacks the packages {absent}"
    shipped = {
        n.removeprefix("tools/scenarios/") for n in names if n.startswith("tools/scenarios/")
    }
    in_checkout = {
        str(p.relative_to(ROOT / "scenarios")) for p in (ROOT / "scenarios").rglob("*.toml")
    }
    assert shipped == in_checkout
    assert not any(n.startswith(("tests/", "scenarios/")) for n in names)


def test_the_installed_wheel_runs_evaluates_and_replays_from_another_directory(
    wheel: Path, tmp_path: Path
) -> None:
    venv, work = tmp_path / "venv", tmp_path / "elsewhere"
    work.mkdir()
    t0 = time.monotonic()
    _run([sys.executable, "-m", "venv", venv], cwd=work, env=dict(os.environ))
    env = _clean_env(venv)
    py = venv / "bin" / "python"
    _run([py, "-m", "pip", "install", "-q", wheel], cwd=work, env=env)
    t_install = time.monotonic() - t0
    where = _run(
        [py, "-c", "import tools, dbc; print(tools.__file__, dbc.__file__)"], cwd=work, env=env
    )
    assert str(ROOT) not in where and str(venv) in where, where
    cli = venv / "bin" / "wheelchair-hil"
    assert _run([cli, "--version"], cwd=work, env=env).split() == ["wheelchair-hil", "0.1.0"]

    t1 = time.monotonic()
    out = _run(
        [
            cli,
            "run",
            "--bus",
            "virtual",
            "--scenario",
            "short",
            "--duration",
            "6",
            "--out",
            "short",
        ],
        cwd=work,
        env=env,
    )
    assert "baseline on short" in out
    assert (work / "short" / "summary.json").is_file()
    _run(
        [
            *(cli, "evaluate", "--out", "eval", "--duration", "3"),
            *("--controllers", "ANTIFRAGILE", "--scenarios", "fault-free", "--no-cascaded"),
            *("--workers", "1", "--no-progress"),
        ],
        cwd=work,
        env=env,
    )
    assert (work / "eval" / "results.json").is_file()
    assert (work / "eval" / "report.md").is_file()
    verify = _run([cli, "replay", "short/run.mcap", "--verify"], cwd=work, env=env)
    assert "verify: OK" in verify
    t_use = time.monotonic() - t1
    print(f"\nfresh venv + install {t_install:.1f} s; run, evaluate, replay --verify {t_use:.1f} s")
