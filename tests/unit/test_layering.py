"""controller/ and firmware_sim/ never import each other; only dbc/ is shared."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _imports(pkg: str) -> set[tuple[str, str]]:
    found = set()
    for f in (ROOT / pkg).rglob("*.py"):
        tree = ast.parse(f.read_text(), filename=str(f))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                found.update((str(f.relative_to(ROOT)), a.name.split(".")[0]) for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add((str(f.relative_to(ROOT)), node.module.split(".")[0]))
    return found


@pytest.mark.parametrize(
    ("pkg", "forbidden"),
    [
        ("controller", {"firmware_sim", "tools"}),
        ("firmware_sim", {"controller", "tools"}),
        ("dbc", {"controller", "firmware_sim", "tools"}),
    ],
)
def test_package_does_not_import(pkg: str, forbidden: set[str]) -> None:
    bad = sorted((f, m) for f, m in _imports(pkg) if m in forbidden)
    assert not bad, f"{pkg} imports {bad}"


def test_signal_names_and_struct_packing_live_only_in_the_codec() -> None:
    offenders = []
    for pkg in ("controller", "firmware_sim", "tools"):
        for f in (ROOT / pkg).rglob("*.py"):
            text = f.read_text()
            if "struct.pack" in text or "import struct" in text:
                offenders.append(str(f.relative_to(ROOT)))
    assert not offenders, offenders


PACKAGES = ("dbc", "firmware_sim", "controller", "tools")


def _module_name(f: Path) -> str:
    parts = list(f.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _module_graph() -> dict[str, set[str]]:
    """Project module -> the project modules it imports at its top level (not TYPE_CHECKING)."""
    files = {_module_name(f): f for pkg in PACKAGES for f in (ROOT / pkg).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, f in files.items():
        deps: set[str] = set()
        for node in ast.parse(f.read_text(), filename=str(f)).body:
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            deps.update(t for t in targets if t in files and t != name)
        graph[name] = deps
    return graph


def test_domain_modules_import_at_the_top() -> None:
    """Imports inside functions are only for optional extras, profiling, and what a part that
    shares the module does not need at start-up (the bench and the recorder, controller.node),
    marked ``# lazy``."""
    inner = []
    for pkg in ("dbc", "tools"):
        for f in (ROOT / pkg).rglob("*.py"):
            src = f.read_text()
            lines = src.splitlines()
            for node in ast.walk(ast.parse(src, filename=str(f))):
                if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    continue
                for sub in ast.walk(node):
                    if isinstance(sub, (ast.Import, ast.ImportFrom)):
                        line = lines[sub.lineno - 1]
                        if "# lazy" not in line:
                            inner.append(f"{f.relative_to(ROOT)}:{sub.lineno}: {line.strip()}")
    assert not inner, "\n".join(inner)


def test_no_import_cycles_between_project_modules() -> None:
    graph = _module_graph()
    cycles: list[list[str]] = []
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                cycles.append([*stack[stack.index(d) :], d])
            elif d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "\n".join(" -> ".join(c) for c in cycles)


def test_the_cycle_check_sees_a_cycle() -> None:
    """The graph the cycle test walks has real edges (so an empty result means something)."""
    graph = _module_graph()
    assert "tools.evaluation.results" in graph["tools.evaluation.report"]
    assert "dbc.codec" in graph["controller.node"]
