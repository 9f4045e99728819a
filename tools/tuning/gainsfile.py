"""The tuned gains file (``scenarios/tuning/gains.toml``): each controller's gains and where
they came from.

One table per controller (written by :func:`tools.tuning.tune.tune`)::

    [robust]
    date = "2026-12-02T01:40:00+00:00"   # when the tuning ended (UTC)
    optimiser = "scrambled Sobol design ..., Nelder-Mead ..."   # the method in one line
    objective = "..."                    # what was minimised
    objective_value = 0.0123             # at the gains below (the best point evaluated)
    objective_start = 0.0150             # at x0, the x0 stage's best point
    budget_evaluations = 250             # objective evaluations allowed (x0 stage included)
    evaluations = 131                    # made
    runs = 262                           # lock-step runs made (evaluations x scenarios)
    wall_s = 312.0
    converged = true                     # Nelder-Mead's own test ended the search
    message = "Optimization terminated successfully."
    scenarios = ["tune-hook", ...]
    tuned = ["k1_per_s", ...]
    [robust.x0_stage]                    # the design x0 came from
    design = "scipy.stats.qmc.Sobol(...)"
    points = 32
    seed = 2027
    objective_best = 0.0150
    objective_median = 0.0410
    [robust.x0_stage.x0]                 # x0's gains
    [robust.nelder_mead]                 # xatol_ln, fatol_m, simplex_step
    [robust.widening]                    # edge_fraction, factor, rounds (restarts after one)
    [robust.box_start]                   # key -> [lo, hi] as scenarios/tuning/space.toml has it
    [robust.box]                         # key -> [lo, hi] at the end (widened where touched)
    [robust.box_limit]                   # key -> the widest the box could grow
    [robust.on_edge.q1_per_s]            # a key still on an edge of its box at the end:
    side = "hi"                          #   which side, and whether that side is its limit
    at_limit = true
    [robust.gains]                       # overrides of controller/gains.toml [robust]
    k1_per_s = 2.3

:func:`load` validates every entry against the controller's declared gains, so a file
tuned for an older version of a controller is an error naming the file, the controller
and the key, never silently half-applied.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from controller.tracking import registry
from dbc.runtime import params
from dbc.runtime.errors import ConfigError

#: The provenance keys every entry carries.
PROVENANCE_KEYS = (
    "date",
    "optimiser",
    "objective",
    "objective_value",
    "objective_start",
    "budget_evaluations",
    "evaluations",
    "runs",
    "wall_s",
    "converged",
    "message",
    "scenarios",
    "tuned",
    "x0_stage",
    "nelder_mead",
    "widening",
    "box_start",
    "box",
    "box_limit",
    "on_edge",
)
#: The provenance keys that are tables.
TABLES = ("x0_stage", "nelder_mead", "widening", "box_start", "box", "box_limit", "on_edge")


def load(path: Path) -> dict[str, dict[str, Any]]:
    """controller -> {"gains": overrides, "provenance": {...}}; ConfigError if invalid."""
    if not path.is_file():
        raise ConfigError(f"{path}: tuned gains file not found (run `wheelchair-hil tune`)")
    table = params.load_toml(path)
    out: dict[str, dict[str, Any]] = {}
    for name, entry in table.items():
        if not isinstance(entry, dict):
            raise ConfigError(f"{path}: [{name}] must be a table")
        if name not in registry.names():
            raise ConfigError(
                f"{path}: [{name}]: unknown controller; known: {', '.join(registry.names())}"
            )
        unknown = sorted(set(entry) - set(PROVENANCE_KEYS) - {"gains"})
        if unknown:
            raise ConfigError(
                f"{path}: unknown key {name}.{unknown[0]}; known: "
                + ", ".join(("gains", *PROVENANCE_KEYS))
            )
        missing = [k for k in PROVENANCE_KEYS if k not in entry]
        if missing:
            raise ConfigError(f"{path}: [{name}] lacks its provenance key {missing[0]!r}")
        for k in TABLES:
            if not isinstance(entry[k], dict):
                raise ConfigError(f"{path}: [{name}.{k}] must be a table")
        boxes = {k: set(entry[k]) for k in ("box_start", "box", "box_limit")}
        if any(keys != set(entry["tuned"]) for keys in boxes.values()):
            raise ConfigError(f"{path}: [{name}]: the boxes do not name the tuned keys")
        gains = entry.get("gains", {})
        if not isinstance(gains, dict):
            raise ConfigError(f"{path}: [{name}.gains] must be a table")
        try:
            registry.load_params(name, gains)
        except ConfigError as err:
            raise ConfigError(
                f"{path}: [{name}.gains] does not fit the controller {name!r} as it is now "
                f"({err}); re-run `wheelchair-hil tune --controller {name}`"
            ) from err
        out[name] = {
            "gains": gains,
            "provenance": {k: entry[k] for k in PROVENANCE_KEYS},
        }
    return out


def update(path: Path, name: str, gains: Mapping[str, Any], provenance: Mapping[str, Any]) -> None:
    """Write (or replace) controller ``name``'s entry in ``path``, keeping the others."""
    entries = params.load_toml(path) if path.is_file() else {}
    entries[name] = {**{k: provenance[k] for k in PROVENANCE_KEYS}, "gains": dict(gains)}
    lines = [
        "# Tuned gains: written by `wheelchair-hil tune --controller NAME` (tools/tuning/tune.py).",
        "# Each table: the tuning's provenance, and [NAME.gains], the overrides of",
        "# controller/gains.toml that `wheelchair-hil evaluate` (make run) applies.",
        "",
    ]
    for ctl in sorted(entries):
        lines += _table(_key(ctl), entries[ctl])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))


def _table(prefix: str, table: Mapping[str, Any]) -> list[str]:
    lines = [f"[{prefix}]"]
    subs = []
    for k, v in table.items():
        if isinstance(v, Mapping):
            subs.append((k, v))
        else:
            lines.append(f"{_key(k)} = {_value(v)}")
    lines.append("")
    for k, v in subs:
        lines += _table(f"{prefix}.{_key(k)}", v)
    return lines


def _key(k: str) -> str:
    """``k`` as a TOML key: bare where it may be, else quoted (a dotted gain's name in a
    box table is one key)."""
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else _value(k)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            raise ValueError(f"a TOML file cannot hold {v}")
        return repr(v) if math.isfinite(v) else ("inf" if v > 0 else "-inf")  # no bound
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {type(v).__name__}")
