"""This checkout's lock-step real-time factor against another commit's, side by side.

``python -m tools.perf.versus REF [--rounds 5] [--controllers baseline,antifragile]``

A machine's speed drifts within an hour, so a speed-up is a ratio of two runs taken one after
the other, never two figures from different hours.  This checks ``REF`` out into a temporary
git worktree, compiles its modules there with this environment's mypyc (``setup.py build_ext
--inplace``, as ``make install`` does), then runs ``wheelchair-hil run --scenario fault-free
--bus virtual`` (the paper route, with its log: the factor ``bench`` reports) for each law, REF's
tree and this one in turn, round after round, and prints what each run printed as "x real
time" and the ratio (this one over REF's) round by round: median and range.  Measure with
nothing else running on the machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_CONTROLLERS = "baseline,antifragile,robust,resilient,adaptive"


def _git(*args: str, cwd: Path = ROOT) -> str:
    return subprocess.run(
        ["git", *args], cwd=cwd, check=True, capture_output=True, text=True
    ).stdout.strip()


def prepare(ref: str, where: Path) -> Path:
    """A worktree of ``ref`` in ``where`` with its compiled modules built in place."""
    tree = where / "ref"
    _git("worktree", "add", "--detach", str(tree), ref)
    build = subprocess.run(
        [sys.executable, "setup.py", "build_ext", "--inplace"],
        cwd=tree,
        capture_output=True,
        text=True,
    )
    if build.returncode != 0:
        raise SystemExit(f"versus: building {ref} failed:\n{build.stderr[-2000:]}")
    return tree


def factor(tree: Path, controller: str, out: Path) -> float:
    """The lock-step factor of one paper-route run of ``controller`` run from ``tree`` (its
    ``summary.json``'s ``real_time_factor``, what ``run`` prints as "x real time")."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    cmd = [sys.executable, "-c", "from tools.cli import entry; entry()", "run"]
    cmd += ["--controller", controller, "--scenario", "fault-free", "--bus", "virtual"]
    cmd += ["--out", str(out)]
    summary = out / "summary.json"
    summary.unlink(missing_ok=True)
    run = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    try:
        return float(json.loads(summary.read_text())["real_time_factor"])
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise SystemExit(
            f"versus: {controller} from {tree} gave no real_time_factor in {summary} ({err}; "
            f"exit {run.returncode}):\n{run.stdout[-1000:]}{run.stderr[-2000:]}"
        ) from err


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.perf.versus", description=__doc__)
    ap.add_argument("ref", help="the commit to compare with (a hash, a tag, a branch)")
    ap.add_argument("--rounds", type=int, default=5, help="rounds of every law (default 5)")
    ap.add_argument(
        "--controllers", default=DEFAULT_CONTROLLERS, help=f"default {DEFAULT_CONTROLLERS}"
    )
    args = ap.parse_args(argv)
    names = [c.strip() for c in args.controllers.split(",") if c.strip()]
    head = _git("rev-parse", "--short", "HEAD")
    if _git("status", "--porcelain", "--untracked-files=no"):
        head += "+changes"  # the working tree, not HEAD itself
    ref = _git("rev-parse", "--short", args.ref)
    with tempfile.TemporaryDirectory(prefix="versus-") as tmp:
        work = Path(tmp)
        tree = prepare(ref, work)
        try:
            got: dict[str, list[tuple[float, float]]] = {n: [] for n in names}
            for r in range(args.rounds):
                for name in names:
                    old = factor(tree, name, work / "out-ref")
                    new = factor(ROOT, name, work / "out-head")
                    got[name].append((old, new))
                    print(f"round {r + 1} {name}: {ref} {old:.1f}x, {head} {new:.1f}x", flush=True)
        finally:
            _git("worktree", "remove", "--force", str(tree))
    print(f"\n| controller | {ref} (median) | {head} (median) | ratio, median (range) |")
    print("|---|---|---|---|")
    for name, pairs in got.items():
        ratios = [new / old for old, new in pairs]
        print(
            f"| {name} | {statistics.median(o for o, _ in pairs):.1f}x "
            f"| {statistics.median(n for _, n in pairs):.1f}x "
            f"| {statistics.median(ratios):.2f} ({min(ratios):.2f}-{max(ratios):.2f}) |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
