"""A chair's computer may lack gcc or Python's headers: the build finds that out before mypyc
generates any C (setup.py's probe; a compile that fails later, its build that compiles every
module or none: tests/unit/test_setup.py), so the wheel is pure Python, says so, and carries
every source.  A file of its own, so that a pytest-xdist worker runs it beside test_wheel.py's
README install, not after it."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

from dbc.runtime.compiled import MODULES
from tests import readme_install


def test_without_a_c_compiler_the_wheel_builds_as_pure_python_with_a_warning(
    tmp_path: Path,
) -> None:
    src = tmp_path / "src"
    readme_install._clone(src)
    env = {k: v for k, v in os.environ.items() if k != "WHEELCHAIR_HIL_PURE_PYTHON"}
    env["CC"] = "/bin/false"  # every compile fails, as without a compiler
    proc = subprocess.run(
        [
            *(sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-v"),
            *("-w", str(tmp_path / "dist"), "."),
        ],
        cwd=src,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "compiling failed" in proc.stdout + proc.stderr
    (whl,) = (tmp_path / "dist").glob("wheelchair_hil-*.whl")
    names = zipfile.ZipFile(whl).namelist()
    assert not [n for n in names if n.endswith(".so")]
    for pkg, mods in MODULES.items():
        for m in mods:
            assert f"{pkg}/{m}.py" in names
