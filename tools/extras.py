"""The distribution's optional extras: what a command or a feature needs beyond the chair's
install, and the one-line error that names the extra to install.

The chair's install (``pip install wheelchair-hil``) holds what runs on a chair's onboard
computer; the harness comes as extras (pyproject.toml's ``[project.optional-dependencies]``:
``bench``, ``eval``, ``live``, ``dask``, ``cvxpy``).  Which distributions an extra holds is read
from the installed distribution's own metadata (its ``Requires-Dist`` lines), so pyproject.toml
stays the one place that lists them.
"""

from __future__ import annotations

import re

from dbc.runtime.errors import WheelchairError

#: The distribution's name (pyproject.toml's ``[project] name``).
DIST = "wheelchair-hil"


class MissingExtraError(WheelchairError):
    """A command or feature needs an optional extra that is not installed."""


#: A ``Requires-Dist`` line of an extra, as setuptools writes it: ``tqdm==4.70.1; extra == "bench"``.
_EXTRA_LINE = re.compile(
    r"""^\s*([A-Za-z0-9][A-Za-z0-9._-]*).*;\s*extra\s*==\s*['"]([^'"]+)['"]\s*$"""
)


def requirements(extra: str) -> list[str]:
    """The distributions ``extra`` adds, from the installed metadata ([] when the
    distribution is not installed: a checkout used without ``pip install``)."""
    import importlib.metadata  # lazy: 50 ms, only for a command that needs an extra

    try:
        lines = importlib.metadata.requires(DIST) or []
    except importlib.metadata.PackageNotFoundError:
        return []
    matches = (_EXTRA_LINE.match(line) for line in lines)
    return [m.group(1) for m in matches if m is not None and m.group(2) == extra]


def missing(extra: str) -> list[str]:
    """The distributions of ``extra`` that are not installed."""
    import importlib.metadata  # lazy: as above

    absent = []
    for name in requirements(extra):
        try:
            importlib.metadata.distribution(name)
        except importlib.metadata.PackageNotFoundError:
            absent.append(name)
    return absent


def hint(extras: tuple[str, ...]) -> str:
    """``pip install 'wheelchair-hil[a,b]'``."""
    return f"pip install '{DIST}[{','.join(extras)}]'"


def require(what: str, *extras: str) -> None:
    """Raise :class:`MissingExtraError` naming ``what``, the extras and the command to install them,
    if any distribution of ``extras`` is not installed."""
    absent = [name for extra in extras for name in missing(extra)]
    if absent:
        raise MissingExtraError(
            f"{what} needs the optional extra{'s' if len(extras) > 1 else ''} "
            f"{', '.join(f'[{e}]' for e in extras)} ({', '.join(dict.fromkeys(absent))} not "
            f"installed): {hint(extras)}"
        )
