"""Scenario files: route, controller, bench overrides and fault schedule, in TOML.

A scenario is given as a path or looked up by name (``fault-free`` -> ``fault-free.toml``):
first in the directory ``--scenario-dir DIR`` or the environment variable
``WHEELCHAIR_HIL_SCENARIOS`` names, then in the scenarios shipped with the package (the
checkout's ``scenarios/``, installed as package data ``tools/scenarios`` and found through
:mod:`importlib.resources`).  Routes are looked up by name the same way, in ``routes/`` next
to the scenario file first.  Layout::

    [scenario]                 # this module's ScenarioParams
    name = "fault-free"
    route = "paper"            # scenarios/routes/paper.toml, or a path
    controller = "baseline"    # default; --controller overrides
    [bench]                    # overrides of firmware_sim's parameters, validated there
    [[faults]]                 # fault schedule, validated by firmware_sim.faults
    type = "flat-tire"         # docs/faults.md lists every type and its parameters
    side = "right"
    onset_s = 20.0             # simulation time
    duration_s = 0.0           # 0 = permanent
    to_radius_m = 0.26

Unknown tables or keys and out-of-range values are :class:`ConfigError` naming
the file and the key (``scenarios/x.toml: faults[0].to_radius_m = 0.7 is above its
maximum 0.6 (m)``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from controller.planner import RouteParams, load_route
from dbc.runtime import params
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import param
from firmware_sim.config import load_bench_config
from firmware_sim.faults import FaultSpec, parse_schedule

#: The environment variable naming a directory of scenarios searched before the packaged ones
#: (``--scenario-dir DIR`` sets it, so that the processes a command starts see it too).
ENV_VAR = "WHEELCHAIR_HIL_SCENARIOS"
#: The package data directory the scenarios are shipped in (``scenarios/`` in the checkout).
PACKAGE_DATA = ("tools", "scenarios")
_TABLES = ("scenario", "bench", "faults")
#: Bounds of ``scenario.seed`` (and of ``--seed``, which overrides it).
SEED_MIN, SEED_MAX = 0, 2**31 - 1


def packaged_dir() -> Path:
    """The scenarios shipped with the package (in the checkout: ``scenarios/``)."""
    root = resources.files(PACKAGE_DATA[0]) / PACKAGE_DATA[1]
    path = Path(str(root)).resolve()  # in the checkout: scenarios/, not the link to it
    if not path.is_dir():
        raise ConfigError(
            f"the packaged scenarios are missing ({root} is not a directory); "
            f"reinstall wheelchair-hil or set {ENV_VAR} to a scenario directory"
        )
    return path


def search_path() -> list[Path]:
    """Where scenario names are looked up, in order: ``$WHEELCHAIR_HIL_SCENARIOS``, packaged."""
    dirs = []
    env = os.environ.get(ENV_VAR, "")
    if env:
        dirs.append(Path(env))
    dirs.append(packaged_dir())
    return dirs


def check_seed(seed: int, *, source: str = "--seed") -> int:
    """``seed`` if the scenario's bounds admit it; ConfigError naming ``source`` and the bound."""
    if not SEED_MIN <= seed <= SEED_MAX:
        raise ConfigError(f"{source} {seed} is outside [{SEED_MIN}, {SEED_MAX}] (scenario.seed)")
    return seed


@dataclass(frozen=True)
class ScenarioParams:
    name: str = param("", unit="", doc="scenario name (defaults to the file name)")
    description: str = param("", unit="", doc="one line for reports")
    route: str = param(
        "paper", unit="", doc="route name (in routes/ of the scenario directories) or a file"
    )
    controller: str = param(
        "baseline", unit="", doc="controller used when the command line names none"
    )
    seed: int = param(
        1, unit="", lo=SEED_MIN, hi=SEED_MAX, doc="seed of every random process of the run"
    )
    tail_s: float = param(
        3.0, unit="s", lo=0.0, hi=600.0, doc="simulated time after the route's end"
    )
    duration_s: float = param(
        0.0, unit="s", lo=0.0, hi=86400.0, doc="simulated duration; 0 = arming + route + tail"
    )
    initial_offset: tuple[float, float, float] = param(
        (0.0, 0.0, 0.0),
        unit="m, m, rad",
        lo=-100.0,
        hi=100.0,
        doc="chair placed at the route start plus (along, left, heading) offset",
    )


@dataclass(frozen=True)
class Scenario:
    path: Path
    params: ScenarioParams
    route: RouteParams
    route_path: Path
    bench: dict[str, Any]
    faults: tuple[FaultSpec, ...]

    @property
    def name(self) -> str:
        return self.params.name or self.path.stem

    def text(self) -> str:
        return self.path.read_text()


def _known(dirs: list[Path]) -> str:
    return ", ".join(sorted({q.stem for d in dirs for q in d.glob("*.toml")}))


def find(name_or_path: str) -> Path:
    """Resolve a scenario name or path to an existing file."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or os.sep in name_or_path:
        if not p.is_file():
            raise ConfigError(f"{p}: scenario file not found")
        return p
    dirs = search_path()
    for d in dirs:
        cand = d / f"{name_or_path}.toml"
        if cand.is_file():
            return cand
    raise ConfigError(
        f"unknown scenario {name_or_path!r} (looked in {', '.join(map(str, dirs))}); "
        f"known: {_known(dirs)}"
    )


def route_file(name: str) -> Path:
    """The route file named ``name`` in ``routes/`` of the scenario directories."""
    dirs = [d / "routes" for d in search_path()]
    for d in dirs:
        if (d / f"{name}.toml").is_file():
            return d / f"{name}.toml"
    raise ConfigError(
        f"unknown route {name!r} (looked in {', '.join(map(str, dirs))}); known: {_known(dirs)}"
    )


def find_route(name_or_path: str, relative_to: Path) -> Path:
    p = Path(name_or_path)
    if p.suffix == ".toml":
        q = p if p.is_absolute() else (relative_to.parent / p)
        if q.is_file():
            return q
        raise ConfigError(f"{relative_to}: scenario.route = {name_or_path!r}: file {q} not found")
    sibling = relative_to.parent / "routes" / f"{name_or_path}.toml"
    if sibling.is_file():
        return sibling
    try:
        return route_file(name_or_path)
    except ConfigError as err:
        raise ConfigError(f"{relative_to}: scenario.route = {name_or_path!r}: {err}") from None


def load(name_or_path: str) -> Scenario:
    """Load and validate a scenario: route, fault schedule and bench overrides (the bench's own
    validation: types, bounds, physical plausibility), before any process or file exists."""
    path = find(name_or_path)
    table = params.load_toml(path)
    unknown = sorted(set(table) - set(_TABLES))
    if unknown:
        raise ConfigError(
            f"{path}: unknown table [{unknown[0]}]; known tables: {', '.join(_TABLES)}"
        )
    sp = params.load(ScenarioParams, table.get("scenario", {}), source=str(path), prefix="scenario")
    route_path = find_route(sp.route, path)
    route = load_route(route_path)
    bench = table.get("bench", {})
    if not isinstance(bench, dict):
        raise ConfigError(f"{path}: [bench] must be a table")

    load_bench_config(bench, source=f"{path} [bench]")  # raises naming the key and the bound
    raw = table.get("faults", [])
    if not isinstance(raw, list) or not all(isinstance(f, dict) for f in raw):
        raise ConfigError(f"{path}: faults must be an array of tables ([[faults]])")
    faults = parse_schedule(raw, source=str(path))
    return Scenario(path, sp, route, route_path, bench, faults)
