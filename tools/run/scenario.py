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
    [[faults]]                 # fault schedule, validated by firmware_sim.faultspec
    type = "flat-tire"         # docs/faults.md lists every type and its parameters
    side = "right"
    onset_s = 20.0             # simulation time
    duration_s = 0.0           # 0 = permanent
    to_radius_m = 0.26
    [controller]               # overrides of controller/controller.toml, validated there
    [gains.antifragile]        # overrides of a controller's gains (controller/gains.toml)

``[scenario] fault_setting`` says how the schedule reaches the run (:data:`FAULT_SETTINGS`):
``diagnosed`` (default) and ``physical`` put every fault on the bench, ``diagnosed`` with
the filter bank's radii fed back into odometry, ``physical`` without; ``paper`` injects the
flat tires as the paper does, as *sensor* faults in the controller's odometry
(``[[estimation.perceived_flats]]``, :mod:`controller.sensor_faults`) while the bench's
wheel stays nominal, and the other faults on the bench, without feedback.

Unknown tables or keys and out-of-range values are :class:`ConfigError` naming
the file and the key (``scenarios/x.toml: faults[0].to_radius_m = 0.7 is above its
maximum 0.6 (m)``).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from controller.config import load_config
from controller.planner import RouteParams, load_route
from controller.tracking import registry
from dbc.runtime import params
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import param
from firmware_sim.config import load_bench_config
from firmware_sim.faultspec import FaultSpec, parse_schedule

#: The environment variable naming a directory of scenarios searched before the packaged ones
#: (``--scenario-dir DIR`` sets it, so that the processes a command starts see it too).
ENV_VAR = "WHEELCHAIR_HIL_SCENARIOS"
#: The package data directory the scenarios are shipped in (``scenarios/`` in the checkout).
PACKAGE_DATA = ("tools", "scenarios")
_TABLES = ("scenario", "bench", "faults", "controller", "gains")
#: The packaged scenarios' directory (in the checkout ``scenarios/``; in a wheel
#: ``tools/scenarios``), without checking it exists (:func:`packaged_dir` does).
SCENARIO_DIR = Path(str(resources.files(PACKAGE_DATA[0]) / PACKAGE_DATA[1])).resolve()
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


#: The checkout (or the installed packages' root): relative paths given by the user.
REPO_ROOT = Path(__file__).resolve().parents[2]

#: How a scenario's faults reach a run, with the label every output carries.
FAULT_SETTINGS: dict[str, str] = {
    "paper": "(a) paper: flat tires as sensor faults in the controller's odometry, "
    "bumps on the bench's wheel; no diagnosis feedback",
    "physical": "(b) physical: every fault on the bench's wheel, the controller believes "
    "the nominal chair; no diagnosis feedback",
    "diagnosed": "(c) diagnosed: (b) plus the filter bank's radii fed back into odometry",
}
#: Fault kinds the paper injects as sensor faults (into the controller's estimate).
SENSOR_FAULT_KINDS = ("flat-tire",)


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
    fault_setting: str = param(
        "diagnosed",
        unit="",
        choices=tuple(FAULT_SETTINGS),
        doc="how the faults reach the run: paper, physical or diagnosed (module doc)",
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
    #: overrides of the controller's configuration ([controller])
    controller: dict[str, Any] = field(default_factory=dict)
    #: controller name -> overrides of its gains ([gains.NAME])
    gains: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.params.name or self.path.stem

    @property
    def setting(self) -> str:
        return self.params.fault_setting

    @property
    def bench_faults(self) -> tuple[FaultSpec, ...]:
        """The faults the bench injects in this scenario's fault setting."""
        if self.setting != "paper":
            return self.faults
        return tuple(f for f in self.faults if f.kind not in SENSOR_FAULT_KINDS)

    @property
    def sensor_faults(self) -> tuple[FaultSpec, ...]:
        """The faults injected into the controller's estimate instead (setting ``paper``)."""
        if self.setting != "paper":
            return ()
        return tuple(f for f in self.faults if f.kind in SENSOR_FAULT_KINDS)

    def controller_overrides(self) -> dict[str, Any]:
        """Overrides of the controller's configuration: ``[controller]`` and the setting's."""
        est: dict[str, Any] = {"diagnosis_feedback": self.setting == "diagnosed"}
        flats = [_perceived_flat(f) for f in self.sensor_faults]
        if flats:
            est["perceived_flats"] = flats
        out = {k: dict(v) if isinstance(v, Mapping) else v for k, v in self.controller.items()}
        out["estimation"] = {**dict(out.get("estimation") or {}), **est}
        return out

    def gains_for(self, controller: str) -> dict[str, Any] | None:
        """Overrides of ``controller``'s gains, or None.  A variant (``adaptive-integral``)
        takes those given for its law (``[gains.adaptive]``), then its own on top."""
        law = registry.gains_section(controller)
        g = {**(self.gains.get(law) or {}), **(self.gains.get(controller) or {})}
        return dict(g) if g else None

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
    controller = table.get("controller", {})
    gains = table.get("gains", {})
    if not isinstance(controller, dict) or not isinstance(gains, dict):
        raise ConfigError(f"{path}: [controller] and [gains] must be tables")
    scen = Scenario(path, sp, route, route_path, bench, faults, controller, gains)
    validate_overrides(scen)
    return scen


def validate_overrides(scen: Scenario) -> None:
    """Raise ConfigError naming the file and key if the scenario's controller configuration
    (with its fault setting) or gains overrides are not valid."""
    load_config(overrides=scen.controller_overrides())
    for name, table in scen.gains.items():
        if not isinstance(table, dict):
            raise ConfigError(f"{scen.path}: [gains.{name}] must be a table")
        if name not in registry.names():
            raise ConfigError(
                f"{scen.path}: [gains.{name}]: unknown controller; known: "
                + ", ".join(registry.names())
            )
        registry.load_params(name, table)


def with_setting(scen: Scenario, setting: str) -> Scenario:
    """``scen`` in fault setting ``setting`` (:data:`FAULT_SETTINGS`)."""
    if setting not in FAULT_SETTINGS:
        raise ConfigError(f"unknown fault setting {setting!r}; known: {', '.join(FAULT_SETTINGS)}")
    sp = params.replace(
        scen.params, {"fault_setting": setting}, source=str(scen.path), prefix="scenario"
    )
    return dataclasses.replace(scen, params=sp)


def effective_setting(scen: Scenario, setting: str) -> str:
    """The setting that gives the same run: ``paper`` without a sensor fault is ``physical``."""
    if setting == "paper" and not any(f.kind in SENSOR_FAULT_KINDS for f in scen.faults):
        return "physical"
    return setting


def _perceived_flat(spec: FaultSpec) -> dict[str, Any]:
    p = spec.params
    return {
        "side": spec.side,
        "onset_s": p.onset_s,
        "duration_s": p.duration_s,
        "to_radius_m": p.to_radius_m,
        "time_constant_s": p.time_constant_s,
    }
