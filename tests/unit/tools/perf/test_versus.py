"""tools.perf.versus: the ratio round by round, and the reference's worktree removed after."""

from __future__ import annotations

from pathlib import Path

import pytest

from tools.perf import versus


def test_the_ratio_is_this_trees_factor_over_the_references_round_by_round(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    git: list[tuple[str, ...]] = []

    def fake_git(*args: str, cwd: Path = versus.ROOT) -> str:
        git.append(args)
        return "" if args[0] == "status" else "abc1234"

    # the reference's factors 40, 50; this tree's 60, 50 (ratios 1.5 and 1.0)
    factors: dict[tuple[bool, str], list[float]] = {
        (True, "baseline"): [40.0, 50.0],
        (False, "baseline"): [60.0, 50.0],
    }
    trees: list[Path] = []

    def fake_prepare(ref: str, where: Path) -> Path:
        trees.append(where / "ref")
        return where / "ref"

    def fake_factor(tree: Path, controller: str, out: Path) -> float:
        return factors[(tree in trees, controller)].pop(0)

    monkeypatch.setattr(versus, "_git", fake_git)
    monkeypatch.setattr(versus, "prepare", fake_prepare)
    monkeypatch.setattr(versus, "factor", fake_factor)
    assert versus.main(["v1", "--rounds", "2", "--controllers", "baseline"]) == 0
    out = capsys.readouterr().out
    assert "| baseline | 45.0x | 55.0x | 1.25 (1.00-1.50) |" in out
    assert ("worktree", "remove", "--force", str(trees[0])) in git


def test_a_run_without_a_factor_names_the_law_and_the_tree(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match=r"nosuchlaw from .* gave no real_time_factor"):
        versus.factor(tmp_path, "nosuchlaw", tmp_path / "out")
