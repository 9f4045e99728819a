"""The chair's install in docs/deploy.md § 1 is the README's install block, which CI runs
(tests/readme_install.py, then tests/integration/test_wheel.py): the same wheel build and the
same pip line, only the venv's place differs.  A guide that installed differently would send a
chair through commands no test has run."""

from __future__ import annotations

import re
import shlex

from .benchkit import ROOT

DEPLOY_MD = ROOT / "docs" / "deploy.md"
README = ROOT / "README.md"


def _commands(block: str) -> list[list[str]]:
    """The ``python3``/``pip`` commands of a ``sh`` block, as argv: ``&&`` chains split,
    comments, ``sudo`` and a venv's directory (``~/chair/bin/``, ``.venv/bin/``) left out."""
    out = []
    for line in block.splitlines():
        line = line.split("  #", 1)[0].strip()
        for part in line.split("&&"):
            argv = shlex.split(part, comments=True)
            if argv[:1] == ["sudo"]:
                argv = argv[1:]
            if not argv:
                continue
            exe = re.sub(r"^(~/\w+|\.venv)/bin/", "", argv[0])
            if exe in ("python3", "pip"):
                out.append([exe, *argv[1:]])
    return out


def _block(text: str, after: str) -> str:
    start = text.index(after)
    m = re.search(r"```sh\n(.*?)```", text[start:], flags=re.S)
    assert m, f"no sh block after {after!r}"
    return m.group(1)


def test_the_deploy_guides_chair_install_is_the_readmes_tested_install() -> None:
    guide = _commands(_block(DEPLOY_MD.read_text(), "## 1. The onboard computer"))
    readme = _commands(_block(README.read_text(), "<!-- example: install -->"))
    assert guide, "docs/deploy.md § 1 has no install command"
    wheel = ["python3", "-m", "pip", "wheel", "--no-deps", "-w", "dist", "."]
    assert wheel in guide and wheel in readme
    chair = ["pip", "install", "-c", "constraints.txt", "dist/wheelchair_hil-*.whl"]
    assert chair in guide and chair in readme
    # nothing else installs: no `pip install .`, no editable install the tests never build
    for argv in guide:
        assert argv[:2] != ["pip", "install"] or argv == chair, argv
        assert ("-e" not in argv and argv[-1:] != ["."]) or argv == wheel, argv
