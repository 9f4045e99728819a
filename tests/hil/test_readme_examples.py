"""The README's shell examples run, so that they cannot rot.

Every fenced ``sh`` block of README.md is one test.  A block is run as it is written, by
``bash -e`` in a scratch directory that holds the checkout's files (but its own ``out/``), with
this venv's ``wheelchair-hil`` on PATH.  An HTML comment on the line before a block says how
else to treat it:

* ``<!-- example: skip REASON -->``: not run; the test is skipped with REASON (hardware, root,
  or a run too long for the suite; the reason says what covers it instead);
* ``<!-- example: sandbox -->``: the lines run in one ``wheelchair-hil sandbox`` (a private
  network namespace), as typed into the shell the block before it opens;
* ``<!-- example: interactive -->``: each line is a program a person watches (a shell, a
  live view): it is started on a terminal of its own and must still be running, or have
  ended with status 0, after a few seconds; with ``sandbox``, each in a namespace of its own;
* ``<!-- example: install -->``: the install block, run as written in a copy of the
  checkout's tracked files with a home of its own by tests/integration/test_wheel.py
  (:mod:`tests.readme_install`), which then tests the wheel and the venvs it leaves: one test
  file builds it, so that no other pytest-xdist worker waits for it.
"""

from __future__ import annotations

import contextlib
import os
import pty
import re
import shlex
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests import readme_install

# make test starts the heaviest files first (tests/conftest.py)
pytestmark = pytest.mark.heavy(seconds=34)

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DIRECTIVE = re.compile(r"^<!-- example: (?P<body>.*?) -->$")
KINDS = ("skip", "sandbox", "interactive", "install")
#: An interactive program must survive this long on its terminal.
ALIVE_S = 4.0


@dataclass(frozen=True)
class Example:
    line: int  # of the opening fence, 1-based
    code: str
    directive: str

    @property
    def kinds(self) -> set[str]:
        return set(self.directive.split()[:2]) & set(KINDS) if self.directive else set()

    @property
    def skip_reason(self) -> str:
        return self.directive.removeprefix("skip").strip()


def examples(text: str) -> list[Example]:
    """Every fenced ``sh`` block with the directive on the line before it (if any)."""
    lines = text.splitlines()
    out = []
    i = 0
    while i < len(lines):
        if lines[i].strip() == "```sh":
            j = next(k for k in range(i + 1, len(lines)) if lines[k].strip() == "```")
            before = lines[i - 1].strip() if i else ""
            m = DIRECTIVE.match(before)
            out.append(Example(i + 1, "\n".join(lines[i + 1 : j]), m["body"] if m else ""))
            i = j
        i += 1
    return out


EXAMPLES = examples(README.read_text())


def _commands(code: str) -> list[str]:
    """The block's commands: one per line, joined at trailing backslashes."""
    joined = re.sub(r"\\\n\s*", " ", code)
    return [ln.strip() for ln in joined.splitlines() if ln.strip() and not ln.startswith("#")]


@pytest.fixture
def scratch(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A directory that looks like the checkout (its files linked) but writes its own out/."""
    for entry in ROOT.iterdir():
        if entry.name not in ("out", ".git"):
            (tmp_path / entry.name).symlink_to(entry)
    env = {k: v for k, v in os.environ.items() if k != "WHEELCHAIR_HIL_SCENARIOS"}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["TERM"] = env.get("TERM") or "xterm"
    return tmp_path, env


def _sandbox(argv: list[str]) -> list[str]:
    return [sys.executable, "-m", "tools.cli", "sandbox", "--", *argv]


def _check(res: subprocess.CompletedProcess[str], ex: Example) -> None:
    assert res.returncode == 0, (
        f"README.md:{ex.line}: exited {res.returncode}\n{ex.code}\n--- stdout\n{res.stdout}"
        f"\n--- stderr\n{res.stderr}"
    )


def _alive_on_a_terminal(
    argv: list[str], cwd: Path, env: dict[str, str], alive_s: float = ALIVE_S
) -> tuple[bool, str]:
    """Start ``argv`` on a pseudo-terminal; (still running after ``alive_s`` or ended 0, output)."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        argv, stdin=slave, stdout=slave, stderr=slave, cwd=cwd, env=env, start_new_session=True
    )
    os.close(slave)
    chunks: list[bytes] = []

    def drain() -> None:  # a full terminal would block the program
        with contextlib.suppress(OSError):
            while data := os.read(master, 4096):
                chunks.append(data)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        rc = proc.wait(timeout=alive_s)
        ok = rc == 0
    except subprocess.TimeoutExpired:
        ok = True
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    finally:
        os.close(master)
        reader.join(5)
    return ok, b"".join(chunks).decode(errors="replace")


def test_every_readme_block_is_run_or_says_why_not() -> None:
    assert len(EXAMPLES) >= 8
    for ex in EXAMPLES:
        assert not ex.directive or ex.kinds, f"README.md:{ex.line}: unknown directive"
        if "skip" in ex.kinds:
            assert ex.skip_reason, f"README.md:{ex.line}: a skip must say why"
    ran = [ex for ex in EXAMPLES if "skip" not in ex.kinds]
    assert any("cantools monitor" in ex.code for ex in ran)
    # the install block is run, as written, where the wheel is tested
    (install,) = [ex for ex in EXAMPLES if "install" in ex.kinds]
    assert readme_install.block() == (install.line, install.code)
    from tests.integration import test_wheel

    assert callable(test_wheel.test_the_readmes_install_block_runs_as_written)


#: the blocks this file runs (the install block: tests/integration/test_wheel.py)
RUN_HERE = [ex for ex in EXAMPLES if "install" not in ex.kinds]


@pytest.mark.hil
@pytest.mark.parametrize("ex", RUN_HERE, ids=[f"README.md:{ex.line}" for ex in RUN_HERE])
def test_readme_example_runs(ex: Example, scratch: tuple[Path, dict[str, str]]) -> None:
    cwd, env = scratch
    if "skip" in ex.kinds:
        pytest.skip(f"README.md:{ex.line}: {ex.skip_reason}")
    if "interactive" in ex.kinds:
        for cmd in _commands(ex.code):
            shell = ["bash", "-c", f"stty rows 40 cols 140; exec {cmd}"]
            argv = _sandbox(shell) if "sandbox" in ex.kinds else shell
            ok, output = _alive_on_a_terminal(argv, cwd, env)
            assert ok, f"README.md:{ex.line}: {cmd!r} failed on a terminal:\n{output[-3000:]}"
        return
    script = ex.code + ("\nwait" if "sandbox" in ex.kinds else "")
    argv = ["bash", "-e", "-c", script]
    res = subprocess.run(
        _sandbox(argv) if "sandbox" in ex.kinds else argv,
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    _check(res, ex)


def test_an_interactive_check_fails_a_program_that_exits_with_an_error(
    scratch: tuple[Path, dict[str, str]],
) -> None:
    cwd, env = scratch
    cmd = "cantools monitor -b udp_multicast -c 239.74.163.2 dbc/wheelchair.dbc"  # the old typo
    # a loaded machine can take longer than ALIVE_S just to import cantools: give the failing
    # program all the time it needs to fail (it exits at once when it runs; a check that
    # took it for alive would then still be wrong after two minutes)
    ok, output = _alive_on_a_terminal(
        _sandbox(["bash", "-c", f"exec {shlex.join(shlex.split(cmd))}"]), cwd, env, alive_s=120.0
    )
    assert not ok, output
