"""run's --live when it re-executes itself in a private network namespace."""

from __future__ import annotations

from tools.cli.run import without_live


def test_run_hands_its_view_to_the_namespace_without_its_live_option() -> None:
    argv = ["run", "--live", "8765", "--scenario", "short", "--live=0", "--out", "o"]
    assert without_live(argv) == ["run", "--scenario", "short", "--out", "o"]
