"""The docstring count of the public surface: how much of each package is documented.

``python -m tools.doc_coverage [PACKAGE ...] [--missing]`` parses every ``.py`` module of each
package with :mod:`ast` (nothing is imported) and counts the public definitions (module-level
functions and classes whose name does not start with ``_``, and the public methods of those
classes) that have a docstring, and the modules that open with one.  ``--missing`` lists each
undocumented definition as ``path:line name``.
"""

from __future__ import annotations

import argparse
import ast
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("controller", "dbc", "firmware_sim")

Def = ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef


@dataclass
class Coverage:
    """One package's counts, and where each undocumented definition is."""

    name: str
    definitions: int = 0
    documented: int = 0
    modules: int = 0
    modules_documented: int = 0
    missing: list[str] = field(default_factory=list)

    def line(self) -> str:
        """The summary line: definitions and modules documented, with the share in percent."""
        return (
            f"{self.name}: {self.documented} of {self.definitions} public definitions documented "
            f"({percent(self.documented, self.definitions)} %), {self.modules_documented} of "
            f"{self.modules} modules open with a docstring"
        )


def percent(part: int, whole: int) -> int:
    """``part`` of ``whole`` in whole percent, 100 only when nothing is missing."""
    if part >= whole:
        return 100
    return min(round(100 * part / whole), 99)


def public(tree: ast.Module) -> Iterator[tuple[str, Def]]:
    """The module's public functions and classes and their public methods, with dotted names."""
    for node in tree.body:
        if not isinstance(node, Def) or node.name.startswith("_"):
            continue
        yield node.name, node
        if isinstance(node, ast.ClassDef):
            methods = (
                s for s in node.body if isinstance(s, ast.FunctionDef | ast.AsyncFunctionDef)
            )
            for sub in methods:
                if not sub.name.startswith("_"):
                    yield f"{node.name}.{sub.name}", sub


def coverage(package_dir: Path) -> Coverage:
    """Count the docstrings of every module under ``package_dir``."""
    cov = Coverage(package_dir.name)
    for f in sorted(package_dir.rglob("*.py")):
        tree = ast.parse(f.read_text(), filename=str(f))
        rel = f.relative_to(package_dir.parent)
        cov.modules += 1
        cov.modules_documented += ast.get_docstring(tree) is not None
        for name, node in public(tree):
            cov.definitions += 1
            if ast.get_docstring(node) is None:
                cov.missing.append(f"{rel}:{node.lineno} {name}")
            else:
                cov.documented += 1
    return cov


def main(argv: Sequence[str] | None = None) -> int:
    """Print each package's line (and with ``--missing`` its undocumented definitions)."""
    ap = argparse.ArgumentParser(prog="python -m tools.doc_coverage", description=__doc__)
    ap.add_argument("packages", nargs="*", default=list(PACKAGES), metavar="PACKAGE")
    ap.add_argument("--missing", action="store_true", help="list undocumented definitions")
    args = ap.parse_args(argv)
    for pkg in args.packages:
        path = Path(pkg) if Path(pkg).is_dir() else ROOT / pkg
        cov = coverage(path)
        print(cov.line())
        if args.missing:
            for m in cov.missing:
                print(m)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
