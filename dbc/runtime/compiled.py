"""Which modules are compiled, and running them from source when they must be.

Two packages have loops that cost more from source than their work: the bench's inner loops
(``firmware_sim``: the 1 kHz drive loops and the RK4 physics, ``plant``, ``drive`` with its
``pid`` and ``watchdog``, ``encoder``, ``sim``) and the controller's float kernels
(``controller.kernels``: the fault bank, the pose EKF's steps, the limiter's step and the
reference's spline).  They are plain, fully typed Python; at
install, ``setup.py`` compiles them with mypyc (:data:`MODULES`) into extension modules beside
their sources, which Python imports in their place.  The figures are bit for bit the same
(``tests/integration/test_compiled_bench.py`` runs a faulted route both ways;
``tests/unit/controller/test_kernels.py`` compares the kernels).  The chair's other code runs
from source, and all of it does where nothing was compiled (no mypyc or C compiler at install).

The compiled modules are build products, so they can be older than their sources (an
edited ``plant.py`` in a checkout that was installed before).  :func:`use_sources_if_needed`
(called when ``firmware_sim`` or ``controller`` is imported) then runs all of that package's
modules from source, with one warning saying so, instead of the stale code;
``WHEELCHAIR_HIL_PURE_PYTHON=1`` does the same on request (to compare, or to debug with a
Python debugger).  This module imports nothing of the project: ``setup.py`` reads
:data:`MODULES` from it.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import os
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

#: The compiled modules of each package, in the order they import each other.
MODULES: dict[str, tuple[str, ...]] = {
    "firmware_sim": ("encoder", "plant", "pid", "watchdog", "drive", "sim"),
    "controller": ("kernels",),
}
#: Set to 1: the compiled modules are ignored and the bench runs from source.
PURE_PYTHON_ENV = "WHEELCHAIR_HIL_PURE_PYTHON"


class _Sources(importlib.abc.MetaPathFinder):
    """Finds the named modules' ``.py`` files before the import system's extension loader."""

    def __init__(self, sources: dict[str, Path]) -> None:
        self.sources = sources

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        src = self.sources.get(fullname)
        return None if src is None else importlib.util.spec_from_file_location(fullname, src)


def stale(package_dir: Path) -> list[str]:
    """The compiled modules of the package in ``package_dir`` (named as the directory) older
    than their sources (by file time), in a
    checkout (``setup.py`` beside the package), where a source may be edited after
    ``make install``.  An installed wheel's modules were compiled from its own sources, and
    pip gives the files it unpacks the time of unpacking, a source often later than its
    extension by microseconds: there file times say nothing, and nothing is stale."""
    if not (package_dir.parent / "setup.py").is_file():
        return []
    out = []
    for name in MODULES.get(package_dir.name, ()):
        src = package_dir / f"{name}.py"
        for ext in importlib.machinery.EXTENSION_SUFFIXES:
            so = package_dir / f"{name}{ext}"
            if so.exists():
                if src.exists() and src.stat().st_mtime > so.stat().st_mtime:
                    out.append(name)
                break
    return out


def compiled(module: ModuleType) -> bool:
    """Whether ``module`` was loaded from an extension (compiled), not from source."""
    return isinstance(getattr(module, "__loader__", None), importlib.machinery.ExtensionFileLoader)


def use_sources_if_needed(package: str, package_dir: Path) -> str | None:
    """Make ``package``'s compiled modules load from source if asked to, or if any is stale;
    returns why (None: the compiled modules are used where they exist)."""
    if os.environ.get(PURE_PYTHON_ENV) == "1":
        why = f"{PURE_PYTHON_ENV}=1"
    else:
        old = stale(package_dir)
        if not old:
            return None
        why = f"{', '.join(f'{n}.py' for n in old)} changed since compiled"
        warnings.warn(
            f"{package}: {why}: its compiled modules run from source (slower) until they are "
            "compiled again (make install)",
            RuntimeWarning,
            stacklevel=2,
        )
    sources = {f"{package}.{n}": package_dir / f"{n}.py" for n in MODULES.get(package, ())}
    finder = next((f for f in sys.meta_path if isinstance(f, _Sources)), None)
    if finder is None:
        sys.meta_path.insert(0, _Sources(sources))
    else:
        finder.sources.update(sources)
    return why
