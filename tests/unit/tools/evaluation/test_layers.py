"""The evaluation's three layers (docs/evaluation.md): the runs, the results and the
presentation, each module reading only its own layer and the one below."""

from __future__ import annotations

import ast
from pathlib import Path

import tools.evaluation

PACKAGE = Path(tools.evaluation.__file__).parent
#: Each module of tools/evaluation by layer, lowest first; the pipeline runs all three.
LAYERS = {
    "runs": {"plan", "variation", "campaign", "task", "execute"},
    "results": {"assemble", "results", "verdicts", "paper"},
    "presentation": {"report", "figures"},
}
ORDER = list(LAYERS)
TOP = {"pipeline", "__init__"}


def _imports(module: str) -> set[str]:
    """The tools.evaluation modules ``module`` imports (at any depth of its code)."""
    tree = ast.parse((PACKAGE / f"{module}.py").read_text())
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            if node.module == "tools.evaluation":
                out |= {a.name for a in node.names}
            elif node.module.startswith("tools.evaluation."):
                out.add(node.module.removeprefix("tools.evaluation."))
        elif isinstance(node, ast.Import):
            out |= {
                a.name.removeprefix("tools.evaluation.")
                for a in node.names
                if a.name.startswith("tools.evaluation.")
            }
    return out


def _layer(module: str) -> str:
    return next(name for name, mods in LAYERS.items() if module in mods)


def test_every_module_of_the_evaluation_has_its_layer() -> None:
    modules = {p.stem for p in PACKAGE.glob("*.py")}
    assert modules == set().union(*LAYERS.values()) | TOP


def test_each_layer_reads_only_itself_and_the_layer_below() -> None:
    for layer, modules in LAYERS.items():
        level = ORDER.index(layer)
        allowed = set(LAYERS[layer]) | (set(LAYERS[ORDER[level - 1]]) if level else set())
        for m in sorted(modules):
            assert _imports(m) <= allowed, (m, sorted(_imports(m) - allowed))


def test_the_presentation_reads_results_json_not_the_runs() -> None:
    for m in LAYERS["presentation"]:
        assert not _imports(m) & LAYERS["runs"], m
