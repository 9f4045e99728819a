"""In CI a skip fails unless tests/conftest.py's ALLOWED_SKIPS names its reason."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

CONFTEST = Path(__file__).resolve().parents[1] / "conftest.py"
TESTS = """
import pytest

def test_quiet():
    pytest.skip("node is not installed")

def test_readme_block():
    pytest.skip("README.md:12: hardware: a CAN adapter on can0")

@pytest.mark.skipif(True, reason="no private network namespace: unshare failed")
def test_marked():
    pass
"""


@pytest.mark.parametrize("ci", ["true", "1", ""])
def test_a_skip_fails_in_ci_unless_its_reason_is_allowed(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch, ci: str
) -> None:
    monkeypatch.setenv("CI", ci)
    pytester.makeconftest(CONFTEST.read_text())
    pytester.makepyfile(test_skips=TESTS)
    res = pytester.runpytest("-p", "no:cacheprovider")
    if ci:
        # the README block's skip is allowed; the other two fail, naming the list
        res.assert_outcomes(skipped=1, failed=1, errors=1)
        res.stdout.fnmatch_lines(["*not one of tests/conftest.py's ALLOWED_SKIPS*node*"])
    else:
        res.assert_outcomes(skipped=3)
