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
#: The commands that build extensions.  pip runs this file three times for one wheel (its
#: egg_info and dist_info hooks for the metadata, then bdist_wheel): mypyc's type check and
#: code generation, 14 of the 39 CPU seconds of a 2-core machine's wheel build apiece, run
#: only for a build.
BUILDS = frozenset(
    ("build", "build_ext", "bdist_wheel", "bdist_egg", "install", "develop", "editable_wheel")
)


def pure_python_warning(err: BaseException) -> None:
    print(
        f"wheelchair-hil: WARNING: compiling failed ({type(err).__name__}: {err}): "
        "the package is pure Python (slower: the bench's loops and the controller's "
        "float kernels run from source), its figures the same",
        file=sys.stderr,
    )


def c_compiler_error() -> BaseException | None:
    """Why a C extension cannot be compiled here (no compiler, no Python headers), or None:
    asked once, of a file that includes Python.h, before mypyc generates any C."""
    import sysconfig
    import tempfile

    try:
        from setuptools._distutils.ccompiler import new_compiler
        from setuptools._distutils.sysconfig import customize_compiler

        compiler = new_compiler()
        customize_compiler(compiler)
    except Exception:  # a setuptools without these: the build itself finds out (below)
        return None
    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "probe.c")
        with open(src, "w") as f:
            f.write("#include <Python.h>\nint probe(void) { return 0; }\n")
        try:
            compiler.compile([src], output_dir=tmp, include_dirs=[sysconfig.get_paths()["include"]])
        except Exception as err:  # CompileError, or the compiler's executable missing
            return err
    return None


def ext_modules() -> list:
    if os.environ.get("WHEELCHAIR_HIL_PURE_PYTHON") == "1":
        return []
    if not BUILDS.intersection(sys.argv[1:]):
        return []  # the metadata alone
    try:
        from mypyc.build import mypycify
    except ImportError as err:
        print(f"wheelchair-hil: no mypyc ({err}): everything stays pure Python", file=sys.stderr)
        return []
    err = c_compiler_error()
    if err is not None:
        pure_python_warning(err)
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
            pure_python_warning(err)


if __name__ == "__main__":  # (pip's hooks too); tests/unit/test_setup.py imports the rest
    setup(ext_modules=ext_modules(), cmdclass={"build_ext": AllOrNothingBuildExt})
