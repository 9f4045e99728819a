"""What tuning may change, and how: the search space file (``scenarios/tuning/space.toml``).

For each tunable controller the same number of its declared gains, each with an explicit box
``[lo, hi]`` chosen from the physics of the law, and the widest the box may grow (its declared
bounds, or a tighter ``[NAME.limits]`` entry): :func:`space` gives them as :class:`Dim`
objects, checked against the law's ``Params``.  The file's ``[method]`` table is the one
:class:`Method` every controller is tuned by (:func:`method`).  A point of the search is a
table of gain overrides (:func:`gains_table`, each gain rounded by :func:`gain`).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controller.tracking import registry
from dbc.runtime import params as params_mod
from dbc.runtime.errors import ConfigError, WheelchairError
from dbc.runtime.params import param
from tools.run import scenario as scenario_mod

#: The tuning's own directory among the scenarios: the space file, the tuning scenarios and
#: the tuned gains file.
TUNING_DIR = scenario_mod.SCENARIO_DIR / "tuning"
SPACE_FILE = TUNING_DIR / "space.toml"
#: Significant digits of a tuned gain (the values the runs use and the gains file holds).
GAIN_DIGITS = 6
#: The space file's table that is the method, not a controller.
METHOD_TABLE = "method"
#: A controller's subtable of the space file with the widest its boxes may grow.
LIMITS_TABLE = "limits"


class TuningError(WheelchairError):
    """A tuning cannot be set up (unknown controller or gain, bad box or budget)."""


@dataclass(frozen=True)
class Method:
    """How every controller is tuned (``[method]`` of the space file)."""

    sobol_points: int = param(
        32,
        unit="evaluations",
        lo=2,
        hi=1024,
        doc="points of the x0 stage's scrambled Sobol design (a power of 2)",
    )
    sobol_seed: int = param(
        2027, unit="1", lo=0, hi=2**31 - 1, doc="seed of the Sobol design's scrambling"
    )
    simplex_step: float = param(
        0.25,
        unit="1",
        lo=0.01,
        hi=0.5,
        doc="initial simplex: a step of this fraction of each box's log width along each axis",
    )
    xatol_ln: float = param(
        0.1,
        unit="1 (ln of a gain)",
        lo=1e-4,
        hi=1.0,
        doc="Nelder-Mead's xatol: every vertex within this of the best in every ln(gain)",
    )
    fatol_m: float = param(
        1e-4,
        unit="m",
        lo=1e-7,
        hi=0.01,
        doc="Nelder-Mead's fatol: every vertex's objective within this of the best",
    )
    edge_fraction: float = param(
        0.02,
        unit="1",
        lo=0.0,
        hi=0.25,
        doc="a gain this close to its box's edge, as a fraction of the box's log width, "
        "is on the edge",
    )
    widen_factor: float = param(
        3.0, unit="1", lo=1.1, hi=100.0, doc="an edge of a box is moved out by this factor"
    )


@dataclass(frozen=True)
class Dim:
    """One tuned gain: its dotted key, its box ``[lo, hi]`` and the widest it may grow,
    ``[limit_lo, limit_hi]`` (``limit_lo`` 0: no lower limit in log scale)."""

    key: str
    lo: float
    hi: float
    limit_lo: float
    limit_hi: float

    def widened(self, side: str, factor: float) -> Dim:
        """This box with its ``side`` ("lo" or "hi") moved out by ``factor``, cut to the
        limit."""
        if side == "hi":
            return dataclasses.replace(self, hi=min(self.hi * factor, self.limit_hi))
        return dataclasses.replace(self, lo=max(self.lo / factor, self.limit_lo))

    def at_limit(self, side: str) -> bool:
        """Whether the box's ``side`` is as far out as it may go."""
        if side == "hi":
            return self.hi >= self.limit_hi * (1.0 - 1e-12)
        return self.lo <= self.limit_lo * (1.0 + 1e-12)


def tunable(*, path: Path = SPACE_FILE) -> list[str]:
    """The controllers the space file gives boxes to, in its order (``--controller all``)."""
    return [k for k, v in params_mod.load_toml(path).items() if k != METHOD_TABLE and v]


def method(*, path: Path = SPACE_FILE) -> Method:
    """The space file's ``[method]``, validated (unit, bounds; a power-of-2 design); a space
    file of one's own without it (``tune --space``) takes the packaged file's, so that every
    controller is tuned the same way."""
    table = params_mod.load_toml(path).get(METHOD_TABLE) or params_mod.load_toml(SPACE_FILE).get(
        METHOD_TABLE, {}
    )
    m = params_mod.load(Method, table, source=str(path), prefix=METHOD_TABLE)
    if m.sobol_points & (m.sobol_points - 1):
        raise ConfigError(f"{path}: method.sobol_points = {m.sobol_points} must be a power of 2")
    return m


def space(name: str, *, path: Path = SPACE_FILE) -> list[Dim]:
    """The gains of controller ``name`` that tuning may change, with their boxes."""
    name = registry.canonical(name)
    cls = registry.controller_class(name)
    table = params_mod.load_toml(path)
    entry = table.get(name)
    if not isinstance(entry, dict) or not entry:
        raise TuningError(
            f"controller {name!r} is not tuned: {path} has no [{name}] with its gains' boxes; "
            f"tunable: {', '.join(tunable(path=path))} (a controller of your own: --space FILE "
            f"with its [{name}] boxes, docs/own-controller.md)"
        )
    limits = entry.get(LIMITS_TABLE, {})
    if not isinstance(limits, dict):
        raise ConfigError(f"{path}: [{name}.{LIMITS_TABLE}] must be a table")
    boxes = {k: v for k, v in entry.items() if k != LIMITS_TABLE}
    for key in limits:
        if key not in boxes:
            raise ConfigError(f"{path}: {name}.{LIMITS_TABLE}.{key}: {key!r} has no box")
    defaults = registry.load_params(name)
    dims = []
    for key, box in boxes.items():
        src = f"{path}: {name}.{key}"
        field = _field(cls.Params, defaults, key, source=f"{path} [{name}]")
        lo, hi = _interval(box, src)
        if not 0.0 < lo < hi:
            raise ConfigError(f"{src} = [{lo}, {hi}]: need 0 < lo < hi (searched in log scale)")
        decl_lo, decl_hi, lo_open = _declared(field)
        lim_lo, lim_hi = decl_lo, decl_hi
        if key in limits:
            lim_lo, lim_hi = _interval(limits[key], f"{path}: {name}.{LIMITS_TABLE}.{key}")
            if lim_lo < decl_lo or lim_hi > decl_hi:
                raise ConfigError(
                    f"{path}: {name}.{LIMITS_TABLE}.{key} = [{lim_lo}, {lim_hi}] leaves the "
                    f"declared bounds [{decl_lo}, {decl_hi}] of {name}.{key}"
                )
        if lo < lim_lo or hi > lim_hi:
            raise ConfigError(
                f"{src} = [{lo}, {hi}] leaves [{lim_lo}, {lim_hi}], the widest {key} may be "
                f"({'its limit in ' + LIMITS_TABLE if key in limits else 'its declared bounds'})"
            )
        if lo_open and lim_lo == decl_lo and lo <= lim_lo:
            raise ConfigError(f"{src} = [{lo}, {hi}]: {key} must exceed {decl_lo}")
        if lo_open and lim_lo == decl_lo > 0.0:
            lim_lo *= 1.0 + 1e-9  # an open bound: widening stops just above it
        dims.append(Dim(key, lo, hi, max(0.0, lim_lo), lim_hi))
    if not dims:
        raise TuningError(f"{path}: [{name}] declares no gain to tune")
    return dims


def _interval(value: Any, src: str) -> tuple[float, float]:
    ok = (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    )
    if not ok or not all(math.isfinite(v) for v in value):
        raise ConfigError(f"{src} must be an interval [lo, hi] of two finite numbers")
    return float(value[0]), float(value[1])


def _declared(field: dataclasses.Field[Any]) -> tuple[float, float, bool]:
    """The declared bounds of a gain (infinite where none) and whether ``lo`` is open."""
    lo = field.metadata.get("lo")
    hi = field.metadata.get("hi")
    lo_f = -math.inf if lo is None else float(lo)
    return lo_f, math.inf if hi is None else float(hi), bool(field.metadata.get("lo_open"))


def _field(cls: Any, obj: Any, key: str, *, source: str) -> dataclasses.Field[Any]:
    """The field a dotted ``key`` names in a Params dataclass, or ConfigError."""
    *sections, last = key.split(".")
    for sec in sections:
        if not hasattr(obj, sec) or not dataclasses.is_dataclass(getattr(obj, sec)):
            raise ConfigError(f"{source}: {key!r}: {sec!r} is not a section of the gains")
        obj = getattr(obj, sec)
    fields = {f.name: f for f in dataclasses.fields(obj)}
    if last not in fields:
        raise ConfigError(f"{source}: unknown gain {key!r}; known: {', '.join(sorted(fields))}")
    hints = typing.get_type_hints(type(obj))
    if hints.get(last) is not float:
        raise ConfigError(f"{source}: {key!r} is not a real-valued gain")
    return fields[last]


def gain(value: float) -> float:
    """A gain rounded to :data:`GAIN_DIGITS` significant digits."""
    return float(f"{value:.{GAIN_DIGITS}g}")


def gains_table(dims: Sequence[Dim], values: Sequence[float]) -> dict[str, Any]:
    """The overrides (nested for dotted keys) that set ``dims`` to ``values``."""
    out: dict[str, Any] = {}
    for d, v in zip(dims, values, strict=True):
        *sections, last = d.key.split(".")
        node = out
        for sec in sections:
            node = node.setdefault(sec, {})
        node[last] = gain(float(v))
    return out
