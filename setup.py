"""Build hook: the bench's inner loops and the controller's float kernels compiled with mypyc
(dbc/runtime/compiled.py says which and why); everything is declared in pyproject.toml.  Without
mypyc, without a C compiler or Python's headers (a chair's computer may have neither), or with
WHEELCHAIR_HIL_PURE_PYTHON=1, the package installs as pure Python, with one warning, and runs
the same."""

import atexit
import os
import runpy
import shutil
import sys

from setuptools import setup
from setuptools.command.build_ext import build_ext

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


class AllOrNothingBuildExt(build_ext):
    """Builds every compiled module or none: where one fails to compile or link, whatever was
    built is removed and the package is pure Python (a compiled module without the library its
    group was linked into would not import).  On every core unless ``--parallel`` says otherwise
    (pip's builds give none: 26 s of compiling on one core of a 2-core machine, 16 s on both)."""

    def finalize_options(self) -> None:
        super().finalize_options()
        if not self.parallel:
            self.parallel = os.cpu_count() or 1

    def run(self) -> None:
        try:
            super().run()
        except Exception as err:  # CompileError, LinkError, a missing compiler or header
            for ext in self.extensions:
                for path in (
                    self.get_ext_fullpath(ext.name),
                    os.path.join(self.build_lib, self.get_ext_filename(ext.name)),
                ):
                    if os.path.exists(path):
                        os.remove(path)
            self.extensions = []
            print(
                f"wheelchair-hil: WARNING: compiling failed ({type(err).__name__}: {err}): "
                "the package is pure Python (slower: the bench's loops and the fault bank's "
                "wheel models run from source), its figures the same",
                file=sys.stderr,
            )


setup(ext_modules=ext_modules(), cmdclass={"build_ext": AllOrNothingBuildExt})
