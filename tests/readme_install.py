"""The README's install block ("Installing it as a package"), run as written, once per session.

The block builds the wheel in a clone, installs it into ``~/chair`` (no extra) and
``~/bench`` (with extras) and runs a route from ``~``.  Here it runs with ``bash -e`` in a
copy of the checkout's tracked files (what a clean clone holds) with its own ``HOME``, the
system's ``python3`` on ``PATH`` and nothing of this checkout's venv in the environment.
``tests/hil/test_readme_examples.py`` checks that the block ran; ``tests/integration/
test_wheel.py`` then tests the wheel and the two venvs it left: the tests use what the
README tells a user to build, not a build of their own.  Under pytest-xdist the first test
to need it builds it while the others wait (:func:`once`).
"""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: The directive on the line before the block in README.md.
DIRECTIVE = "<!-- example: install -->"
#: Environment variables of this checkout's venv and test run that a user's shell lacks.
_FOREIGN = ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME", "WHEELCHAIR_HIL_SCENARIOS")


@dataclass(frozen=True)
class Install:
    """Where the block left its results."""

    root: Path
    stdout: str

    @property
    def checkout(self) -> Path:
        return self.root / "checkout"

    @property
    def home(self) -> Path:
        return self.root / "home"

    @property
    def wheel(self) -> Path:
        (whl,) = (self.checkout / "dist").glob("wheelchair_hil-*.whl")
        return whl


def block() -> tuple[int, str]:
    """(line of the opening fence, the code) of the README's install block."""
    lines = README.read_text().splitlines()
    for i, line in enumerate(lines):
        if line.strip() == DIRECTIVE and lines[i + 1].strip() == "```sh":
            end = next(k for k in range(i + 2, len(lines)) if lines[k].strip() == "```")
            return i + 2, "\n".join(lines[i + 2 : end])
    raise AssertionError(f"README.md has no sh block after {DIRECTIVE}")


def once(factory: pytest.TempPathFactory, name: str, build: Callable[[Path], None]) -> Path:
    """``name``'s directory, built by ``build`` once for the whole test session: under
    pytest-xdist the workers share the session's base directory, and the first to take the
    lock builds while the others wait."""
    base = factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    d = root / name
    with (root / f"{name}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (d / ".built").exists():
            shutil.rmtree(d, ignore_errors=True)
            d.mkdir()
            build(d)
            (d / ".built").touch()
    return d


def user_env(home: Path) -> dict[str, str]:
    """A user's shell: ``HOME``, and ``PATH`` without this checkout's venv."""
    venv_bin = str(Path(sys.prefix) / "bin")
    env = {k: v for k, v in os.environ.items() if k not in _FOREIGN}
    env["PATH"] = os.pathsep.join(
        p for p in env.get("PATH", "").split(os.pathsep) if p and p != venv_bin
    )
    env["HOME"] = str(home)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    # pip does not byte-compile what it installs (--no-compile; pip reads a "no-" option's
    # variable as the option's value, so 0 sets it): the same files, and Python writes the
    # bytecode of what it imports when it imports it.  Compiling numpy, scipy and matplotlib
    # in both venvs took about 10 s of each install.
    env["PIP_NO_COMPILE"] = "0"
    return env


def _clone(dst: Path) -> None:
    """The checkout's tracked files as a clean clone has them (no venv, no build products)."""
    files = subprocess.run(
        ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True
    ).stdout.split(b"\0")
    for raw in files:
        if not raw:
            continue
        rel = raw.decode()
        src = ROOT / rel
        out = dst / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        if src.is_symlink():  # as git keeps it (tools/scenarios -> ../scenarios)
            out.symlink_to(os.readlink(src))
        elif src.is_file():  # (not: deleted in the working tree)
            shutil.copy2(src, out)


def run(factory: pytest.TempPathFactory) -> Install:
    """The README's install block, run once per session (an AssertionError with its output
    if it failed)."""

    def build(d: Path) -> None:
        _clone(d / "checkout")
        (d / "home").mkdir()
        line, code = block()
        res = subprocess.run(
            ["bash", "-e", "-x", "-c", code],
            cwd=d / "checkout",
            env=user_env(d / "home"),
            capture_output=True,
            text=True,
            timeout=1200,
            check=False,
        )
        (d / "output.txt").write_text(res.stdout + "\n--- stderr\n" + res.stderr)
        assert res.returncode == 0, (
            f"README.md:{line}: exited {res.returncode}\n{code}\n--- stdout\n{res.stdout}"
            f"\n--- stderr\n{res.stderr[-6000:]}"
        )

    d = once(factory, "readme-install", build)
    return Install(d, (d / "output.txt").read_text())


#: the README's block names its venvs by these paths under HOME
CHAIR = "chair"
BENCH = "bench"


def venv_of(inst: Install, name: str) -> Path:
    venv = inst.home / name
    assert (venv / "bin" / "wheelchair-hil").exists(), f"the README's block made no ~/{name}"
    return venv
