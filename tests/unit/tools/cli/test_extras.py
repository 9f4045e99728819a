"""The chair's install and the extras: each command imports, at the top of its modules, only the
chair's dependencies and the extras it declares; a missing extra is one line naming it.

tests/integration/test_wheel.py checks the same on a real install of the base wheel.
"""

from __future__ import annotations

import ast
import importlib.metadata
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from packaging.requirements import Requirement

from tools import extras
from tools.cli import COMMANDS, main

ROOT = Path(__file__).resolve().parents[4]
PACKAGES = ("dbc", "firmware_sim", "controller", "tools")
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
PYPROJECT_BUILD = tomllib.loads((ROOT / "pyproject.toml").read_text())["build-system"]
#: The commands a chair runs: the base install must carry all they import.
CHAIR_COMMANDS = ("control", "doctor", "install-service", "record")


def _dist(req: str) -> str:
    m = re.match(r"[A-Za-z0-9][A-Za-z0-9._-]*", req)
    assert m, req
    return re.sub(r"[-_.]+", "-", m.group(0)).lower()


def _module_name(f: Path) -> str:
    parts = list(f.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


FILES = {_module_name(f): f for pkg in PACKAGES for f in (ROOT / pkg).rglob("*.py")}


def _imports(name: str, *, actions: bool = False) -> tuple[set[str], set[str]]:
    """The project modules and the other top-level packages ``name`` imports when it is
    imported: module level, also under ``if``/``try`` (not ``TYPE_CHECKING``), not in
    functions unless ``actions`` (a command's module: its action and the action's helpers
    import what the command runs)."""
    project: set[str] = set()
    other: set[str] = set()

    def walk(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if actions:
                    walk(node.body)
                continue
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                walk(node.orelse)
                continue
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            else:
                for part in ("body", "orelse", "finalbody"):
                    walk(getattr(node, part, []))
                for handler in getattr(node, "handlers", []):
                    walk(handler.body)
                continue
            for t in targets:
                if t.split(".")[0] in PACKAGES:
                    project.update(p for p in _parents(t) if p in FILES)
                else:
                    other.add(t.split(".")[0])

    walk(ast.parse(FILES[name].read_text(), filename=str(FILES[name])).body)
    return project, other


def _parents(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[: i + 1]) for i in range(len(parts))]


def _third_party(roots: list[str], entry: str | None = None) -> set[str]:
    """The top-level packages outside the project and the standard library that importing
    ``roots`` imports, and calling ``entry`` ("module:function", a command's action, and
    every other function of its module: the helpers of the action beside it)."""
    seen: set[str] = set()
    found: set[str] = set()
    stack = [p for r in roots for p in _parents(r) if p in FILES]
    while stack:
        m = stack.pop()
        if m in seen:
            continue
        seen.add(m)
        module = (entry or "").partition(":")[0]
        project, other = _imports(m, actions=m == module)
        found |= other
        stack.extend(project - seen)
    return {p for p in found if p not in sys.stdlib_module_names and p != "__future__"}


def _distributions(packages: set[str]) -> dict[str, set[str]]:
    """Import name -> the distributions that provide it (in this fully installed venv)."""
    provided = importlib.metadata.packages_distributions()
    return {p: {_dist(d) for d in provided.get(p, [])} for p in packages}


def _allowed(command_extras: tuple[str, ...]) -> set[str]:
    groups = [PYPROJECT["dependencies"]] + [
        PYPROJECT["optional-dependencies"][e] for e in command_extras
    ]
    return {_dist(r) for g in groups for r in g}


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_command_imports_only_the_chairs_dependencies_and_the_extras_it_declares(
    name: str,
) -> None:
    cmd = COMMANDS[name]
    used = _third_party(["tools.cli", cmd.arguments, cmd.entry.split(":")[0]], cmd.entry)
    allowed = _allowed(cmd.extras)
    outside = {p: d for p, d in _distributions(used).items() if not d & allowed}
    assert not outside, f"{name} imports {outside} beyond the base install and {cmd.extras}"


def test_the_chairs_commands_need_no_extra_and_the_scan_sees_the_extras() -> None:
    assert all(COMMANDS[c].extras == () for c in CHAIR_COMMANDS)
    # the scan is not blind: evaluate's figures import matplotlib; the progress bar's tqdm is
    # optional (plain lines without it), so no command needs an extra for it
    evaluate = COMMANDS["evaluate"]
    assert "matplotlib" in _third_party([evaluate.entry.split(":")[0]], evaluate.entry)
    replay = COMMANDS["replay"]
    assert "tqdm" not in _third_party([replay.entry.split(":")[0]], replay.entry)
    assert "matplotlib" not in _allowed(())


def test_every_extra_a_command_declares_is_one_of_pyprojects() -> None:
    declared = {e for c in COMMANDS.values() for e in c.extras}
    assert declared <= set(PYPROJECT["optional-dependencies"]), declared
    for extra in declared:
        assert sorted(extras.requirements(extra)) == sorted(
            _dist(r) for r in PYPROJECT["optional-dependencies"][extra]
        ), f"the installed metadata of [{extra}] differs from pyproject.toml: make install"


def test_every_requirement_is_a_bounded_range_whose_tested_pin_is_in_constraints_txt() -> None:
    """pyproject.toml asks for ranges (a package beside others on a chair's computer), each
    bounded above and admitting the version constraints.txt pins (the set make installs and
    tests); the dev extra, the project's own tooling, stays pinned."""
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, _, version = line.partition("==")
            pins[_dist(name)] = version.strip()
    extras = PYPROJECT["optional-dependencies"]
    groups = {"base": PYPROJECT["dependencies"], **extras}
    for group, reqs in groups.items():
        for text in reqs:
            req = Requirement(text)
            name = _dist(req.name)
            assert name in pins, f"{text} ([{group}]) has no pin in constraints.txt"
            assert req.specifier.contains(pins[name]), f"{text}: the tested {pins[name]} is outside"
            if group == "dev":
                assert str(req.specifier).startswith("=="), f"{text}: the dev tools stay pinned"
            else:
                assert any(s.operator == "<" for s in req.specifier), f"{text}: no upper bound"
    for text in PYPROJECT_BUILD["requires"]:
        req = Requirement(text)
        assert pins.get(_dist(req.name)) == str(req.specifier).removeprefix("=="), text
    base = [_dist(Requirement(r).name) for r in PYPROJECT["dependencies"]]
    assert len(base) == len(set(base)), base


def test_a_command_whose_extra_is_missing_says_which_to_install_in_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    real = importlib.metadata.distribution

    def without_matplotlib(name: str) -> importlib.metadata.Distribution:
        if _dist(name) == "matplotlib":
            raise importlib.metadata.PackageNotFoundError(name)
        return real(name)

    monkeypatch.setattr(importlib.metadata, "distribution", without_matplotlib)
    # checked before the command's arguments are parsed (--help would exit 0 otherwise)
    assert main(["evaluate", "--help"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "wheelchair-hil: error: evaluate needs the optional extra [eval] (matplotlib not "
        "installed): pip install 'wheelchair-hil[eval]'"
    )


def test_an_extras_missing_module_names_the_extra_where_no_metadata_tells() -> None:
    """From a checkout used without ``pip install`` there is no metadata to ask: the import
    error itself then names the extra (a process where ``import matplotlib`` fails)."""
    code = (
        "import sys; sys.modules['matplotlib'] = None; "  # import matplotlib raises ImportError
        "from tools import extras; extras.missing = lambda extra: []; "
        "from tools.cli import main; sys.exit(main(['evaluate', '--out', 'no-such-dir']))"
    )
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 2, res.stderr
    (line,) = res.stderr.splitlines()
    assert line.startswith("wheelchair-hil: error: evaluate is unavailable: ")
    assert "matplotlib" in line and line.endswith("(pip install 'wheelchair-hil[eval]')")


def test_summarize_and_replay_run_without_tqdm_showing_plain_progress_lines() -> None:
    """A progress bar is no reason to refuse a command: without tqdm (a chair's install)
    progress on a terminal is the plain lines."""
    code = (
        "import sys, io; sys.modules['tqdm'] = None\n"
        "from tools.console.progress import Progress\n"
        "class Tty(io.StringIO):\n"
        "    def isatty(self): return True\n"
        "out = Tty()\n"
        "with Progress(10, 'replay', 'frame', stream=out) as p:\n"
        "    for _ in range(10): p.update()\n"
        "print(out.getvalue())\n"
        "from tools.cli import main; sys.exit(main(['summarize', 'no-such-log.mcap']))"
    )
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert "replay: 10/10 frames (100 %)" in res.stdout, res.stdout
    # summarize got as far as its argument: the log that is not there
    assert res.returncode != 0 and "no-such-log.mcap" in res.stderr, res.stderr
    assert "unavailable" not in res.stderr and "extra" not in res.stderr
