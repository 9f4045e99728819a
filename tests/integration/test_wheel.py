"""The installable wheel as the README builds and installs it, used from a directory that is
not the checkout.

The README's install block (tests/readme_install.py runs it as written, once per session:
``pip wheel`` in a copy of the checkout's tracked files, then two fresh venvs with the
tested pins) leaves the wheel and two installs of it: the chair's (``~/chair``, no extra:
what runs on a chair's onboard computer) holds no part of the harness, runs ``control``,
``doctor``, ``install-service`` and ``record`` (``install-service`` writes the chair config
template and the systemd unit into a temporary directory, which ``doctor`` then reads), and a
bench command there names the extra it needs; the bench's (``~/bench``, ``[bench,eval,live]``):
a short run, ``evaluate --duration`` and ``replay --verify`` find the packaged scenarios and
routes.  The base wheel's ``Requires-Dist`` is printed (``pytest -s`` shows it).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import time
import zipfile
from pathlib import Path

import pytest

from dbc.runtime.compiled import MODULES
from tests import readme_install
from tools.cli import COMMANDS

# make test starts the heaviest files first (tests/conftest.py)
pytestmark = pytest.mark.heavy(seconds=120)

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
    "tools/deploy/templates/chair.toml",
    "tools/deploy/templates/wheelchair-hil.service",
)
#: What a chair runs: the base install (no extra) must run these.
CHAIR_COMMANDS = ("control", "doctor", "install-service", "record")
#: The harness's packages (import name: distribution), which the chair's install must not hold.
HARNESS = {"tqdm": "tqdm", "foxglove": "foxglove-sdk", "websockets": "websockets"}


def _run(
    argv: list[str | Path],
    *,
    cwd: Path,
    env: dict[str, str],
    timeout: float = 600,
    returncode: int = 0,
) -> str:
    res = subprocess.run(
        [str(a) for a in argv],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )
    assert res.returncode == returncode, (
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
    # bytecode is written into the temporary venv (installed --no-compile): the first
    # command compiles what it imports, the later ones start from it
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


@pytest.fixture(scope="module")
def readme(tmp_path_factory: pytest.TempPathFactory) -> readme_install.Install:
    """The README's install block, run as written (once per session: tests/readme_install.py)."""
    return readme_install.run(tmp_path_factory)


@pytest.fixture(scope="module")
def wheel(readme: readme_install.Install) -> Path:
    """The wheel the README's ``pip wheel`` built (with setup.py's mypyc step: the bench's
    compiled modules beside their sources)."""
    return readme.wheel


def test_the_readmes_install_block_runs_as_written(readme: readme_install.Install) -> None:
    # the fixture ran it with bash -e (an AssertionError with its output otherwise)
    for name in (readme_install.CHAIR, readme_install.BENCH):
        readme_install.venv_of(readme, name)
    assert readme.wheel.name.endswith(".whl")
    assert (readme.home / "short" / "summary.json").is_file()  # the route it ran from ~


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
    # the compiled modules (the bench's, the controller's kernels), and their sources for a
    # machine that must run from them
    for pkg, mods in MODULES.items():
        for m in mods:
            assert f"{pkg}/{m}.py" in names
            assert any(n.startswith(f"{pkg}/{m}.") and n.endswith(".so") for n in names), m


def _venv(readme: readme_install.Install, name: str) -> tuple[Path, dict[str, str]]:
    """A venv the README's block made (``~/chair``, ``~/bench``), and the environment of a
    user of it."""
    venv = readme_install.venv_of(readme, name)
    env = _clean_env(venv)
    py = venv / "bin" / "python"
    where = _run(
        [py, "-c", "import tools, dbc; print(tools.__file__, dbc.__file__)"], cwd=venv, env=env
    )
    # imported from the venv's site-packages, not a checkout
    site = [str(p) for p in venv.glob("lib/python*/site-packages")]
    assert site and all(f.startswith(tuple(site)) for f in where.split()), where
    return venv, env


@pytest.fixture(scope="module")
def chair(readme: readme_install.Install) -> tuple[Path, dict[str, str]]:
    """The chair's install: the wheel without extras (the README's ``~/chair``)."""
    return _venv(readme, readme_install.CHAIR)


@pytest.fixture(scope="module")
def installed(readme: readme_install.Install) -> tuple[Path, dict[str, str]]:
    """The bench's install: the wheel with the extras of run, evaluate, replay and the live
    view (the README's ``~/bench``)."""
    return _venv(readme, readme_install.BENCH)


def _requires_dist(wheel: Path) -> list[str]:
    """The wheel's ``Requires-Dist`` lines (its METADATA)."""
    with zipfile.ZipFile(wheel) as z:
        (meta,) = [n for n in z.namelist() if n.endswith(".dist-info/METADATA")]
        text = z.read(meta).decode()
    return [
        ln.split(":", 1)[1].strip() for ln in text.splitlines() if ln.startswith("Requires-Dist:")
    ]


def test_the_base_wheel_requires_the_chairs_dependencies_alone_as_bounded_ranges(
    wheel: Path,
) -> None:
    """``unzip -p dist/wheelchair_hil-*.whl '*/METADATA' | grep Requires-Dist`` shows the same:
    ranges from the tested version to the next major (constraints.txt pins the tested set)."""
    requires = _requires_dist(wheel)
    base = [r for r in requires if "extra ==" not in r]
    print(f"\n{wheel.name} Requires-Dist (base):\n  " + "\n  ".join(base))
    ranged = r"[A-Za-z0-9._-]+(<[0-9][A-Za-z0-9.]*,>=[0-9][A-Za-z0-9.]*|>=[0-9][A-Za-z0-9.]*,<[0-9][A-Za-z0-9.]*)"
    assert base and all(re.fullmatch(ranged, r) for r in base), base
    names = {re.split(r"[<>=]", r)[0] for r in base}
    assert names == {
        "python-can",
        "msgpack",
        "cantools",
        "numpy",
        "scipy",
        "filterpy",
        "osqp",
        "mcap",
    }
    extras = {re.sub(r".*extra == \"([^\"]+)\".*", r"\1", r) for r in requires if "extra ==" in r}
    assert {"bench", "eval", "live", "dev"} <= extras


def test_the_chairs_install_holds_no_harness_and_runs_the_chairs_commands(
    chair: tuple[Path, dict[str, str]], tmp_path: Path
) -> None:
    venv, env = chair
    cli = venv / "bin" / "wheelchair-hil"
    probe = (
        "import importlib, importlib.metadata as md, json, sys\n"
        f"harness = {HARNESS!r}\n"
        "def installed(d):\n"
        "    try:\n"
        "        md.distribution(d)\n"
        "    except md.PackageNotFoundError:\n"
        "        return False\n"
        "    return True\n"
        "def importable(m):\n"
        "    try:\n"
        "        importlib.import_module(m)\n"
        "    except ImportError:\n"
        "        return False\n"
        "    return True\n"
        "out = {'installed': [d for d in harness.values() if installed(d)],\n"
        "       'importable': [m for m in harness if importable(m)]}\n"
        "for m in [m for m in sys.modules if m.split('.')[0] in harness]:\n"
        "    del sys.modules[m]\n"
        "import tools.cli\n"
        f"for name in {CHAIR_COMMANDS!r}:\n"
        "    cmd = tools.cli.COMMANDS[name]\n"
        "    importlib.import_module(cmd.arguments)\n"
        "    importlib.import_module(cmd.entry.split(':')[0])\n"
        "out['loaded'] = sorted({m.split('.')[0] for m in sys.modules} & {*harness, 'matplotlib'})\n"
        "# matplotlib is filterpy's requirement (its metadata), not ours\n"
        "out['need_matplotlib'] = sorted(d.metadata['Name'] for d in md.distributions()\n"
        "    if any(r.split(';')[0].strip().lower().startswith('matplotlib')\n"
        "           and 'extra' not in r for r in d.requires or []))\n"
        "print(json.dumps(out))\n"
    )
    found = json.loads(_run([venv / "bin" / "python", "-c", probe], cwd=tmp_path, env=env))
    print(f"\nthe chair's install: {found}")
    assert found == {
        "installed": [],
        "importable": [],
        "loaded": [],
        "need_matplotlib": ["filterpy"],
    }
    for name in CHAIR_COMMANDS:
        assert "usage: wheelchair-hil" in _run([cli, name, "--help"], cwd=tmp_path, env=env)
    # the chair replays and summarizes its own logs (tqdm's bar is optional): the command gets
    # as far as the log it is given
    res = subprocess.run(
        [cli, "summarize", "no-such-log.mcap"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert res.returncode != 0 and "no-such-log.mcap" in res.stderr, res.stderr
    assert "extra" not in res.stderr, res.stderr
    # a bench command: one line naming the extra to install, status 2, nothing written
    for name in ("evaluate",):
        res = subprocess.run(
            [cli, name, "--out", "x"],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        (extra,) = COMMANDS[name].extras
        print(res.stderr.strip())
        assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
        assert res.stderr.startswith(
            f"wheelchair-hil: error: {name} needs the optional extra [{extra}]"
        )
        assert res.stderr.rstrip().endswith(f"pip install 'wheelchair-hil[{extra}]'")
    assert not (tmp_path / "x").exists()


def test_the_installed_wheel_runs_evaluates_and_replays_from_another_directory(
    installed: tuple[Path, dict[str, str]], tmp_path: Path
) -> None:
    venv, env = installed
    work = tmp_path / "elsewhere"
    work.mkdir()
    cli = venv / "bin" / "wheelchair-hil"
    assert _run([cli, "--version"], cwd=work, env=env).split() == ["wheelchair-hil", "0.1.0"]
    # the bench the wheel compiled is the one that runs (pip's unpacking times made every
    # source look newer than its extension, and the bench ran from source, with a warning)
    probe = (
        "import warnings; warnings.simplefilter('error')\n"
        "from dbc.runtime import compiled\n"
        "from firmware_sim import sim\n"
        "from controller import kernels\n"
        "print(compiled.compiled(sim), compiled.compiled(kernels))\n"
    )
    assert _run([venv / "bin" / "python", "-c", probe], cwd=work, env=env).split() == ["True"] * 2

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
    print(f"\nrun, evaluate, replay --verify {time.monotonic() - t1:.1f} s")


def _unit_keys(text: str) -> dict[str, list[str]]:
    """``Section.Key`` -> values, as systemd reads a unit (comments and blank lines skipped)."""
    out: dict[str, list[str]] = {}
    section = ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("["):
            section = line[1:-1]
            continue
        key, _, value = line.partition("=")
        out.setdefault(f"{section}.{key}", []).append(value)
    return out


def test_the_chairs_install_writes_the_chair_template_and_the_unit_and_doctor_reads_them(
    chair: tuple[Path, dict[str, str]], tmp_path: Path
) -> None:
    """install-service and doctor from the chair's install; nothing outside ``tmp_path`` is
    written (the unit goes into ``--dest``, not /etc/systemd/system)."""
    venv, env = chair
    work = tmp_path / "elsewhere"
    work.mkdir()
    cli = venv / "bin" / "wheelchair-hil"
    t0 = time.monotonic()
    chair = work / "etc" / "chair.toml"
    _run([cli, "install-service", "--chair-template", chair], cwd=work, env=env)
    assert chair.read_text() == (ROOT / "tools" / "deploy" / "templates" / "chair.toml").read_text()
    out = _run(
        [
            *(cli, "install-service", "--config", chair, "--scenario", "short"),
            *("--dest", work / "units", "--log-dir", work / "logs"),
        ],
        cwd=work,
        env=env,
    )
    unit = work / "units" / "wheelchair-hil.service"
    assert f"wrote {unit}" in out
    keys = _unit_keys(unit.read_text())
    (pre,) = keys["Service.ExecStartPre"]
    (start,) = keys["Service.ExecStart"]
    exe = str(cli.resolve())
    scenario = venv.glob("lib/python*/site-packages/tools/scenarios/short.toml")
    assert pre.split()[:2] == [exe, "doctor"] and f"--config {chair}" in pre
    assert start.split()[:2] == [exe, "control"]
    assert f"--config {chair}" in start and f"--scenario {next(scenario)}" in start
    assert "--bus socketcan --channel can0 --bitrate 500000" in start  # the template's [bus]
    assert f"--log-root {work / 'logs'}" in start
    assert keys["Service.Restart"] == ["no"] and keys["Service.CPUSchedulingPolicy"] == ["fifo"]
    # the unit shipped for docs/deploy.md's paths is what the installed code writes for them
    same = _run(
        [
            venv / "bin" / "python",
            "-c",
            "from tools.deploy import service as s; "
            "print(s.SHIPPED_UNIT.read_text() == s.render(s.UnitOptions()))",
        ],
        cwd=work,
        env=env,
    )
    assert same.split() == ["True"]
    # the doctor reads the template with the installed loader: valid; the chair's key and
    # drives are missing here, so it fails (exit 1) naming them, and moves nothing
    doctor = _run(
        [cli, "doctor", "--bus", "virtual", "--config", chair, "--window", "0.2"],
        cwd=work,
        env=env,
        returncode=1,
    )
    lines = doctor.splitlines()
    assert f"ok      config      {chair}: valid" in lines
    assert any(
        ln.startswith("FAIL    key") and "/etc/wheelchair-hil/secoc.key" in ln for ln in lines
    )
    assert lines[-1].endswith("the controller must not arm")
    print(f"\ninstall-service, doctor {time.monotonic() - t0:.1f} s")
