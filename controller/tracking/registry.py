"""Tracking controllers by name, imported on first use (python-can's interface-table habit).

A controller module that cannot be imported (say, a missing optional solver)
breaks that one controller with a clear message, not the whole program.  Each
controller class declares ``name``, a typed ``Params`` dataclass and a
constructor ``(params, geometry, trajectory, *, limits)``; its gains come from its section
of ``controller/gains.toml`` and are the same for every scenario.  The chair's limits
(``LimitParams``) are not gains: every law receives the same ones, the node's
(``controller.toml [limits]``), and saturates with them wherever it saturates (one envelope).

A *variant* (:data:`VARIANTS`) is a registered law under another name with a few gains
changed: it reads its law's section of ``gains.toml`` (:func:`gains_section`), so it inherits
every gain of that law, tuned overrides given for it included, and changes only its own keys.

A controller of one's own comes from another installed package, with no edit here: its
package declares it under the entry-point group :data:`ENTRY_POINT_GROUP` (``name =
"module:Class"``, the same form as :data:`REGISTRY`), and every command takes its name
(docs/own-controller.md).  A plug-in cannot take a built-in law's name.  Its gains are its
``Params`` defaults unless ``gains.toml`` has its section; :func:`load_params` says so once.
"""

from __future__ import annotations

import functools
import importlib
import importlib.metadata
import inspect
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from controller.config import BodyParams, GeometryParams, LimitParams, MotorParams, load_config
from controller.types import Controller, Trajectory
from dbc.runtime import params
from dbc.runtime.errors import ConfigError

log = logging.getLogger(__name__)

GAINS_PATH = Path(__file__).resolve().parent.parent / "gains.toml"
#: The entry-point group under which another package registers its controllers.
ENTRY_POINT_GROUP = "wheelchair_hil.controllers"

#: name -> "module:Class", imported lazily.
REGISTRY: dict[str, str] = {
    "baseline": "controller.tracking.baseline:Kanayama",
    "antifragile": "controller.tracking.antifragile:Antifragile",
    "robust": "controller.tracking.robust:RobustSMC",
    "adaptive": "controller.tracking.adaptive:AdaptiveMPC",
    "resilient": "controller.tracking.resilient:ResilientTSK",
}

#: variant name -> (the registered law it is, the gains it sets on top of that law's).
VARIANTS: dict[str, tuple[str, Mapping[str, Any]]] = {
    # ADAPTIVE with the offset-free MPC's integral action, which the paper's cost does not have
    # (docs/controllers.md, "ADAPTIVE"); `adaptive` itself runs without it.
    "adaptive-integral": (
        "adaptive",
        {"disturbance_rate_per_s": 0.5, "disturbance_max_radps": 0.5},
    ),
}


@functools.cache
def plugins() -> dict[str, str]:
    """The controllers other installed packages register (:data:`ENTRY_POINT_GROUP`):
    name (lower case) -> "module:Class".  One that takes a built-in name is left out, said."""
    found: dict[str, str] = {}
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        key = ep.name.strip().lower()
        where = f"{ep.dist.name if ep.dist else '?'}'s entry point {ep.name} = {ep.value}"
        if key in REGISTRY or key in VARIANTS:
            log.warning("controller plug-in %s: %r is a built-in law's name; ignored", where, key)
            continue
        if key in found:
            log.warning("controller plug-in %s: %r is registered twice; ignored", where, key)
            continue
        found[key] = ep.value
    return found


def _targets() -> dict[str, str]:
    return {**REGISTRY, **plugins()}


def names() -> list[str]:
    """Every name a controller can be chosen by: the laws, their variants, then the
    controllers other packages register (:func:`plugins`)."""
    return [*REGISTRY, *VARIANTS, *plugins()]


def is_plugin(name: str) -> bool:
    """Whether ``name`` is a controller another package registers."""
    return name.strip().lower() in plugins()


def canonical(name: str) -> str:
    """The registered spelling of ``name``: names are case-insensitive (``ANTIFRAGILE``, the
    reports' spelling, is ``antifragile``); ConfigError if no controller has it."""
    key = name.strip().lower()
    if key not in REGISTRY and key not in VARIANTS and key not in plugins():
        raise ConfigError(f"unknown controller {name!r}; choose one of {', '.join(names())}")
    return key


def gains_section(name: str) -> str:
    """The registered law whose ``gains.toml`` section (and tuned gains) controller ``name``
    reads: the law itself, or for a variant the law it is (``adaptive-integral``:
    ``adaptive``).  ConfigError if unknown."""
    name = canonical(name)
    return VARIANTS[name][0] if name in VARIANTS else name


def controller_class(name: str) -> Any:
    """The class registered under ``name`` (any case; a variant: its law's); ConfigError if
    unknown or not importable."""
    name = gains_section(name)
    target = _targets()[name]
    module, _, cls = target.partition(":")
    try:
        mod = importlib.import_module(module)
    except ImportError as err:
        raise ConfigError(f"controller {name!r} is unavailable: {err}") from err
    try:
        return getattr(mod, cls)
    except AttributeError:
        raise ConfigError(f"controller {name!r}: {module} has no {cls!r} ({target})") from None


def load_params(
    name: str, overrides: Mapping[str, Any] | None = None, *, gains_path: Path = GAINS_PATH
) -> Any:
    """The typed gains of controller ``name``: its law's section of ``gains.toml``, a
    variant's own keys (:data:`VARIANTS`), then ``overrides`` (for a variant, those of its law
    apply as well: its other gains are its law's)."""
    name = canonical(name)
    section = gains_section(name)
    cls = controller_class(name)
    gains = params.load_toml(gains_path)
    if section not in gains:
        _untuned(name, gains_path)
    table = gains.get(section, {})
    p = params.load(cls.Params, table, source=str(gains_path), prefix=section)
    if name in VARIANTS:
        p = params.replace(p, VARIANTS[name][1], source="registry.VARIANTS", prefix=name)
    if overrides:
        p = params.replace(p, overrides, source="overrides", prefix=name)
    return p


@functools.cache
def _untuned(name: str, gains_path: Path) -> None:
    """Say once per process that ``name`` runs on its Params defaults."""
    log.warning(
        "controller %r has no [%s] section in %s: it runs on its Params defaults "
        "(wheelchair-hil tune --controller %s --space FILE tunes it as the paper's laws were; "
        "docs/own-controller.md)",
        name,
        name,
        gains_path,
        name,
    )


def create(
    name: str,
    geometry: GeometryParams,
    trajectory: Trajectory,
    *,
    overrides: Mapping[str, Any] | None = None,
    gains_path: Path = GAINS_PATH,
    motor: MotorParams | None = None,
    body: BodyParams | None = None,
    limits: LimitParams | None = None,
) -> Controller:
    """Instantiate controller ``name`` with its gains.

    ``limits`` (the chair's, the ones the node's limiter applies) go to every controller.
    ``motor`` (the deployment's believed motor parameters) goes to controllers whose
    constructor takes it, i.e. those that tune the drives' inner loop; ``body`` (the believed
    mass and inertia) to those whose law uses the dynamic model.  Any of the three not given
    is the default deployment file's (controller/controller.toml), read here once: the laws
    themselves require what they take.
    """
    cls = controller_class(name)
    accepted = inspect.signature(cls).parameters
    given = {"limits": limits, "motor": motor, "body": body}
    wanted = {k: v for k, v in given.items() if k == "limits" or k in accepted}
    if any(v is None for v in wanted.values()):
        cfg = load_config()
        wanted = {k: v if v is not None else getattr(cfg, k) for k, v in wanted.items()}
    params = load_params(name, overrides, gains_path=gains_path)
    return cls(params, geometry, trajectory, **wanted)
