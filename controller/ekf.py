"""filterpy's :class:`ExtendedKalmanFilter`, imported without loading ``scipy.stats``.

``import filterpy.kalman`` runs ``filterpy/__init__``, which imports every subpackage.  Two of
them cost most of the import and serve nothing here: ``filterpy.stats`` imports ``scipy.stats``
for the one function the Kalman filters take from it, ``logpdf``, read only by their
``log_likelihood`` properties (never read here: the fault bank computes its own likelihoods),
and ``filterpy.discrete_bayes`` imports ``scipy.ndimage``.  They were 0.9 s of the
controller's 1.9 s start-up on a 2-core machine (``python -X importtime -c 'import
controller.node'``), far more in a user-mode Linux guest, and every controller process pays it.

While filterpy is imported, those two are stand-in modules (``logpdf`` loads the real one at
its first call); then the stand-ins are removed, so that ``import filterpy.stats`` anywhere
else gets the real module.  A filterpy that takes more from them gets the plain import;
``tests/unit/controller/test_ekf.py`` checks that the stand-in ``logpdf`` gives what the real
one gives and that neither scipy module is loaded (with the tested filterpy).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

__all__ = ["ExtendedKalmanFilter"]


def _logpdf(*args: Any, **kwargs: Any) -> Any:
    """filterpy.stats.logpdf, imported at the first call."""
    real = sys.modules.get("filterpy.stats")
    if real is None or real is _STANDINS["filterpy.stats"]:
        sys.modules.pop("filterpy.stats", None)
        real = importlib.import_module("filterpy.stats")
    return real.logpdf(*args, **kwargs)


def _standin(name: str, **attrs: Any) -> types.ModuleType:
    mod = types.ModuleType(name, f"stand-in for {name} while filterpy is imported (controller.ekf)")
    for k, v in attrs.items():
        setattr(mod, k, v)
    return mod


_STANDINS = {
    "filterpy.stats": _standin("filterpy.stats", logpdf=_logpdf),
    "filterpy.discrete_bayes": _standin("filterpy.discrete_bayes"),
}


def _import_ekf() -> type:
    if "filterpy" in sys.modules:  # imported whole already: nothing to save
        from filterpy.kalman import ExtendedKalmanFilter as Ekf  # lazy: the real modules

        return Ekf
    sys.modules.update(_STANDINS)
    try:
        from filterpy.kalman import ExtendedKalmanFilter as Ekf  # lazy: with the stand-ins
    except ImportError:  # a filterpy that takes more from them: the plain import
        for name in [n for n in sys.modules if n == "filterpy" or n.startswith("filterpy.")]:
            del sys.modules[name]
        from filterpy.kalman import ExtendedKalmanFilter as Ekf  # lazy: the real modules

        return Ekf
    finally:
        parent = sys.modules.get("filterpy")
        for name, mod in _STANDINS.items():
            if sys.modules.get(name) is mod:
                del sys.modules[name]
            attr = name.rsplit(".", 1)[1]
            if parent is not None and getattr(parent, attr, None) is mod:
                delattr(parent, attr)  # ``import filterpy.stats`` then loads the real one
    return Ekf


if TYPE_CHECKING:
    from filterpy.kalman import ExtendedKalmanFilter
else:
    ExtendedKalmanFilter = _import_ekf()
