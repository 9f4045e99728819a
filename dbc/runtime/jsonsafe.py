"""JSON the project writes is valid JSON: no NaN or Infinity, ``null`` with a reason instead.

:func:`dumps` is ``json.dumps`` with ``allow_nan=False`` after replacing every
non-finite float (numpy's too) by ``None``.  A top-level mapping that had any gets a
``"null_reasons"`` entry naming each such key (dotted path) and the value it stood for
(``"nan: no value was measured"``), so a reader can tell a missing figure from a zero.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
from collections.abc import Mapping
from typing import Any

_WHY = {
    "nan": "nan: no value was measured (no samples, or the computation failed)",
    "inf": "inf: unbounded",
    "-inf": "-inf: unbounded",
}


def clean(obj: Any, reasons: dict[str, str] | None = None, path: str = "") -> Any:
    """``obj`` with non-finite floats as None (each noted in ``reasons`` by path)."""
    if hasattr(obj, "item") and callable(obj.item) and not isinstance(obj, (str, bytes)):
        with contextlib.suppress(TypeError, ValueError):
            obj = obj.item()  # numpy scalars
    if isinstance(obj, float):
        if math.isfinite(obj):
            return obj
        if reasons is not None:
            reasons[path or "."] = _WHY[repr(obj)]
        return None
    if isinstance(obj, Mapping):
        return {
            str(k): clean(v, reasons, f"{path}.{k}" if path else str(k)) for k, v in obj.items()
        }
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [clean(v, reasons, f"{path}[{i}]") for i, v in enumerate(obj)]
    return obj


def dumps(obj: Any, *, default: Any = str, **kwargs: Any) -> str:
    """Valid JSON for ``obj`` (see module doc); ``default`` as in ``json.dumps``."""
    # objects json cannot encode become what ``default`` makes of them first
    obj = json.loads(json.dumps(obj, default=default, allow_nan=True))
    reasons: dict[str, str] = {}
    out = clean(obj, reasons)
    if reasons and isinstance(out, dict):
        prior = out.get("null_reasons")
        out["null_reasons"] = {**(prior if isinstance(prior, dict) else {}), **reasons}
    return json.dumps(out, allow_nan=False, **kwargs)


def write(path: str | os.PathLike[str], obj: Any, **kwargs: Any) -> None:
    """Write ``dumps(obj)`` to ``path`` whole or not at all.

    The text goes to a temporary file next to it, renamed over ``path`` once written; a
    full disk or any other OS error removes the temporary file and raises the
    ``OSError`` with ``path`` as its file name, so no empty or half file is left.
    """
    text = dumps(obj, **kwargs) + "\n"
    tmp = f"{os.fspath(path)}.tmp{os.getpid()}"
    try:
        with open(tmp, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except OSError as err:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise OSError(err.errno, err.strerror, os.fspath(path)) from err
