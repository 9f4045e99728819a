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
