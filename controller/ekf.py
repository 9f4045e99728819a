"""filterpy's :class:`ExtendedKalmanFilter`, imported without loading ``scipy.stats`` or
``scipy.linalg``.

``import filterpy.kalman`` runs ``filterpy/__init__``, which imports every subpackage.  Two of
them cost most of the import and serve nothing here: ``filterpy.stats`` imports ``scipy.stats``
for the one function the Kalman filters take from it, ``logpdf``, read only by their
``log_likelihood`` properties (never read here: the fault bank computes its own likelihoods),
and ``filterpy.discrete_bayes`` imports ``scipy.ndimage``.  They were 0.9 s of the
controller's 1.9 s start-up on a 2-core machine (``python -X importtime -c 'import
controller.node'``), far more in a user-mode Linux guest, and every controller process pays it.

The third is ``scipy.linalg``: filterpy's Kalman filters import it at module level (``inv``,
``cholesky``, ``qr``, ``pinv``; ``expm`` and ``block_diag`` in ``filterpy.common``) for their
own ``update`` and for filters the controller does not use.  The controller's filters never
call them: the pose EKF and the fault bank make their updates in :mod:`controller.kernels`.
It was 0.27 s of the controller's 0.62 s import (``python -X importtime -c 'import
controller.node'``, 2026-12-07), and 16 times that in the socketcan lane's guest.

While filterpy is imported, those three are stand-in modules: ``logpdf`` loads the real
``filterpy.stats`` at its first call, and each function filterpy takes from ``scipy.linalg``
(and any other name read from it) loads the real ``scipy.linalg`` at its first use; then the
stand-ins are removed, so that ``import filterpy.stats`` or ``import scipy.linalg`` anywhere
else gets the real module.  A filterpy that takes more from them gets the plain import;
``tests/unit/controller/test_ekf.py`` checks that the stand-ins give what the real functions
give and that no such scipy module is loaded (with the tested filterpy).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

__all__ = ["ExtendedKalmanFilter"]


def _real(name: str) -> types.ModuleType:
    """The real module ``name`` of a stand-in (imported now if it is not yet)."""
    real = sys.modules.get(name)
    if real is None or real is _STANDINS[name]:
        sys.modules.pop(name, None)
        real = importlib.import_module(name)
    return real


def _logpdf(*args: Any, **kwargs: Any) -> Any:
    """filterpy.stats.logpdf, imported at the first call."""
    return _real("filterpy.stats").logpdf(*args, **kwargs)


def _lazy_linalg(name: str) -> Any:
    """A function that calls ``scipy.linalg.<name>``, imported at the first call."""

    def call(*args: Any, **kwargs: Any) -> Any:
        return getattr(_real("scipy.linalg"), name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"scipy.linalg.{name}, imported at the first call (controller.ekf)."
    return call


def _linalg_attr(name: str) -> Any:
    """Any other name read from the stand-in: the real module's (imported now)."""
    if name.startswith("__"):
        raise AttributeError(name)
    return getattr(_real("scipy.linalg"), name)


def _standin(name: str, **attrs: Any) -> types.ModuleType:
    mod = types.ModuleType(name, f"stand-in for {name} while filterpy is imported (controller.ekf)")
    for k, v in attrs.items():
        setattr(mod, k, v)
    return mod


#: what filterpy 1.4.5 takes from scipy.linalg when it is imported
_LINALG_NAMES = ("inv", "cholesky", "qr", "pinv", "expm", "block_diag")

_STANDINS = {
    "filterpy.stats": _standin("filterpy.stats", logpdf=_logpdf),
    "filterpy.discrete_bayes": _standin("filterpy.discrete_bayes"),
    "scipy.linalg": _standin(
        "scipy.linalg", __getattr__=_linalg_attr, **{n: _lazy_linalg(n) for n in _LINALG_NAMES}
    ),
}


def _import_ekf() -> type:
    if "filterpy" in sys.modules:  # imported whole already: nothing to save
        from filterpy.kalman import ExtendedKalmanFilter as Ekf  # lazy: the real modules

        return Ekf
    # a module already loaded (scipy.linalg by a caller) is the real one, not replaced
    sys.modules.update({k: v for k, v in _STANDINS.items() if k not in sys.modules})
    try:
        from filterpy.kalman import ExtendedKalmanFilter as Ekf  # lazy: with the stand-ins
    except ImportError:  # a filterpy that takes more from them: the plain import
        for name in [n for n in sys.modules if n == "filterpy" or n.startswith("filterpy.")]:
            del sys.modules[name]
        for name, mod in _STANDINS.items():
            if sys.modules.get(name) is mod:
                del sys.modules[name]
        from filterpy.kalman import ExtendedKalmanFilter as Ekf  # lazy: the real modules

        return Ekf
    finally:
        for name, mod in _STANDINS.items():
            if sys.modules.get(name) is mod:
                del sys.modules[name]
            pkg, attr = name.rsplit(".", 1)
            parent = sys.modules.get(pkg)
            if parent is not None and parent.__dict__.get(attr) is mod:
                delattr(parent, attr)  # ``import filterpy.stats`` then loads the real one
    return Ekf


if TYPE_CHECKING:
    from filterpy.kalman import ExtendedKalmanFilter
else:
    ExtendedKalmanFilter = _import_ekf()
