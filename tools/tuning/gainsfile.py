"""The tuned gains file (``scenarios/tuning/gains.toml``): each controller's gains and where
they came from.

One table per controller::

    [robust]
    date = "2026-12-02T01:40:00+00:00"   # when the tuning ended (UTC)
    optimiser = "scipy.optimize.minimize(method='Nelder-Mead')"
    objective = "..."                    # what was minimised
    objective_value = 0.0123             # at the gains below
    objective_start = 0.0150             # at controller/gains.toml's gains
    budget_evaluations = 24              # objective evaluations allowed
    evaluations = 24                     # made
    runs = 48                            # lock-step runs made (evaluations x scenarios)
    wall_s = 312.0
    converged = false                    # the optimiser's own verdict
    message = "Maximum number of function evaluations has been exceeded."
    scenarios = ["tune-figure-eight", ...]
    [robust.gains]                       # overrides of controller/gains.toml [robust]
    lambda_x = 2.3

:func:`load` validates every entry against the controller's declared gains, so a file
tuned for an older version of a controller is an error naming the file, the controller
and the key, never silently half-applied.
"""

from __future__ import annotations

import math
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
)


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
        lines += _table(ctl, entries[ctl])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))


def _table(prefix: str, table: Mapping[str, Any]) -> list[str]:
    lines = [f"[{prefix}]"]
    subs = []
    for k, v in table.items():
        if isinstance(v, Mapping):
            subs.append((k, v))
        else:
            lines.append(f"{k} = {_value(v)}")
    lines.append("")
    for k, v in subs:
        lines += _table(f"{prefix}.{k}", v)
    return lines


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"a TOML file cannot hold {v}")
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {type(v).__name__}")
