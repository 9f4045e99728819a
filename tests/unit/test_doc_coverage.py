"""tools.doc_coverage counts the public surface's docstrings, and ours has one everywhere."""

from __future__ import annotations

from pathlib import Path

import pytest

from tools import doc_coverage

ROOT = Path(__file__).resolve().parents[2]

MODULE = '''"""A tiny module."""


def documented() -> int:
    """Return one."""
    return 1


def undocumented() -> int:
    return 2


def _private() -> int:
    return 3


class Thing:
    def __init__(self) -> None:
        self.n = 0

    def method(self) -> int:
        """Return n."""
        return self.n

    def _helper(self) -> None:
        pass
'''


@pytest.fixture
def tiny(tmp_path: Path) -> Path:
    pkg = tmp_path / "tiny"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "mod.py").write_text(MODULE)
    return pkg


def test_counts_public_functions_classes_and_methods(tiny: Path) -> None:
    cov = doc_coverage.coverage(tiny)
    assert (cov.definitions, cov.documented) == (4, 2)
    assert (cov.modules, cov.modules_documented) == (2, 1)
    assert cov.missing == ["tiny/mod.py:9 undocumented", "tiny/mod.py:17 Thing"]


def test_prints_one_line_per_package_and_the_missing_with_their_place(
    tiny: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert doc_coverage.main([str(tiny), "--missing"]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "tiny: 2 of 4 public definitions documented (50 %), 1 of 2 modules open with a docstring",
        "tiny/mod.py:9 undocumented",
        "tiny/mod.py:17 Thing",
    ]


@pytest.mark.parametrize("package", doc_coverage.PACKAGES)
def test_every_public_definition_of_the_stack_is_documented(package: str) -> None:
    cov = doc_coverage.coverage(ROOT / package)
    assert not cov.missing, "\n".join(cov.missing)
    assert cov.modules_documented == cov.modules
