"""Build hook: the bench's inner loops and the controller's float kernels compiled with mypyc
(dbc/runtime/compiled.py says which and why); everything is declared in pyproject.toml.  Without
mypyc or a C compiler, or with WHEELCHAIR_HIL_PURE_PYTHON=1, the package installs as pure Python
and runs the same."""

import atexit
import os
import runpy
import shutil
import sys

from setuptools import setup

MODULES = runpy.run_path(os.path.join("dbc", "runtime", "compiled.py"))["MODULES"]


def ext_modules() -> list:
    if os.environ.get("WHEELCHAIR_HIL_PURE_PYTHON") == "1":
        return []
    try:
        from mypyc.build import mypycify
    except ImportError as err:
        print(f"wheelchair-hil: no mypyc ({err}): everything stays pure Python", file=sys.stderr)
        return []
    # a fresh target directory and no mypy cache: mypyc 2.4's incremental rebuild from an
    # earlier build's files fails inside its code generator.  Relative to this file's
    # directory: setuptools refuses an extension whose sources have an absolute path (pip's
    # wheel and install builds)
    target = os.path.join("build", f"mypyc-{os.getpid()}")
    shutil.rmtree(target, ignore_errors=True)
    atexit.register(shutil.rmtree, target, ignore_errors=True)
    try:
        return mypycify(
            [
                "--cache-dir=/dev/null",
                *(f"{pkg}/{m}.py" for pkg, mods in MODULES.items() for m in mods),
            ],
            opt_level="3",
            separate=True,
            target_dir=target,
        )
    except Exception as err:  # a build without the compiled bench still works
        print(
            f"wheelchair-hil: mypyc failed ({err}): everything stays pure Python", file=sys.stderr
        )
        return []


setup(ext_modules=ext_modules())
