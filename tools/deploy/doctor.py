"""The doctor's checks: what the controller needs before it may arm, checked without moving a
wheel.

Each check is one line (:class:`~tools.deploy.check.Check`): ``ok``, ``warning`` or ``FAIL``
with the fix, and ``n/a`` where a check does not apply (udp_multicast and the virtual bus have
no CAN controller, so no bitrate and no error state).  ``wheelchair-hil doctor``
(tools/cli/doctor.py) prints them and exits 1 on any failure, so that a service's
``ExecStartPre=`` refuses to start the controller.

What it sends: only requests a drive answers without acting on them, RTRs (Get_Error, and
Get_Version where the wire contract has that frame) and RxSdo *reads* (opcode 0) of the
wire-contract hash, which a drive answers without authentication.  No setpoint, no state
request, no configuration, no Host_Heartbeat.  For ``window_s`` (2 s) it listens to
everything: the drives' heartbeats and encoder estimates, other hosts, and every frame for
the bus load.

The checks, in the order printed: ``config`` (the chair's TOML loads), ``limits`` (the
controller's limits against the ones it pushes to the drives with Set_Limits and
Set_Watchdog), ``key`` (readable by this user, by nobody else), ``realtime`` (SCHED_FIFO and
mlockall permitted), ``clock`` (monotonic, its source, its rate), ``interface`` (up,
bitrate, error state from ``ip -details -json link``), ``bus`` (opened), ``drive left`` /
``drive right`` (heartbeat, axis state, error bits, encoder estimates), ``nodes`` (no
heartbeat from a node ID the contract does not know, no other host), ``version``
(Get_Version), ``contract`` (the drives' wire-contract hash equals the host's) and
``busload``.

This module runs them (:func:`run_checks`); the checks live by what they check:
:mod:`~tools.deploy.host_checks` (the controller's computer and configuration),
:mod:`~tools.deploy.interface_checks` (the CAN interface), :mod:`~tools.deploy.capture` (what
the doctor asks and hears) and :mod:`~tools.deploy.bus_checks` (what was heard);
:mod:`~tools.deploy.check` is a report line.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from controller.config import ControllerConfig, load_config, node_map
from dbc.codec import DRIVES, Codec
from dbc.nodemap import NodeMap
from dbc.runtime.errors import ConfigError, WheelchairError
from tools.bus.transport import BusSpec, open_bus
from tools.deploy.bus_checks import (
    check_busload,
    check_contract,
    check_drive,
    check_nodes,
    check_version,
)
from tools.deploy.capture import Capture, listen
from tools.deploy.check import Check, Status
from tools.deploy.host_checks import (
    check_clock,
    check_compiled,
    check_key,
    check_limits,
    check_realtime,
    clocks,
)
from tools.deploy.interface_checks import bus_fix, check_interface
from tools.deploy.service import CHAIR_TEMPLATE

#: How long the doctor listens to the bus (the bus load is measured over it).
WINDOW_S = 2.0


#: The detail of a check that depends on one that failed: reported, not failed again.
NOT_CHECKED = "not checked:"


def _keys(table: Mapping[str, Any], prefix: str = "") -> set[str]:
    out: set[str] = set()
    for k, v in table.items():
        if isinstance(v, dict):
            out |= _keys(v, f"{prefix}{k}.")
        else:
            out.add(f"{prefix}{k}")
    return out


def bench_defaults(config_path: Path) -> list[str]:
    """The keys of the chair template (every value a chair must measure or choose) that the
    chair's file leaves out, so that they take the bench's values: deleting
    ``geometry.wheel_radius_m`` from a chair file gave "valid" and the bench's radius."""
    try:
        mine = _keys(tomllib.loads(config_path.read_text()))
    except (OSError, tomllib.TOMLDecodeError):
        return []  # load_config has said what is wrong with it
    return sorted(_keys(tomllib.loads(CHAIR_TEMPLATE.read_text())) - mine)


def run_checks(
    config_path: str | Path | None,
    spec: BusSpec | None,
    *,
    window_s: float = WINDOW_S,
    rt_priority: int = 0,
    codec: Codec | None = None,
    spec_error: str = "",
) -> list[Check]:
    """Every check, in report order.  Never raises for what it checks: each problem is a line.

    ``spec`` None (with ``spec_error``) when the bus could not even be resolved.
    """
    codec = codec or Codec.default()
    checks: list[Check] = []
    cfg: ControllerConfig | None = None
    try:
        cfg = load_config(config_path)
        where = config_path or "controller/controller.toml (the defaults: a chair names its own)"
        left = bench_defaults(Path(config_path)) if config_path else []
        if left:
            shown = ", ".join(left[:6]) + (f" and {len(left) - 6} more" if len(left) > 6 else "")
            checks.append(
                Check(
                    "config",
                    Status.WARN,
                    f"{where}: valid, but {len(left)} keys of the chair template are not in it "
                    f"and take the bench's values: {shown}",
                    "measure each on the chair and set it (the template says how: "
                    "wheelchair-hil install-service --chair-template PATH)",
                )
            )
        else:
            checks.append(Check("config", Status.OK, f"{where}: valid"))
    except ConfigError as err:
        checks.append(
            Check(
                "config",
                Status.FAIL,
                str(err),
                "correct that key (`wheelchair-hil params` lists every key, unit and bound)",
            )
        )
    if cfg is not None:
        checks += check_limits(cfg, codec)
        checks.append(check_key(cfg))
    else:
        # one failure per cause: what depends on the config is not checked, not failed again
        checks.append(Check("limits", Status.NA, "not checked: the config did not load"))
        checks.append(Check("key", Status.NA, "not checked: the config did not load"))
    checks.append(check_realtime(rt_priority))
    checks.append(check_compiled())
    clock_start = clocks()
    if spec is None:
        if cfg is None and spec_error.startswith(NOT_CHECKED):
            checks.append(Check("bus", Status.NA, spec_error))  # the config's failure says it
        else:
            checks.append(
                Check("bus", Status.FAIL, spec_error, "name the bus: --bus/--channel or [bus]")
            )
        checks.append(check_clock([clock_start, clocks()]))
        return checks
    checks.append(check_interface(spec))
    nodes = node_map(cfg) if cfg is not None else NodeMap()
    cap: Capture | None = None
    try:
        bus = open_bus(spec)
    except WheelchairError as err:
        checks.append(Check("bus", Status.FAIL, str(err), bus_fix(spec)))
    else:
        try:
            checks.append(Check("bus", Status.OK, f"{spec.describe()} open"))
            cap = listen(bus, codec, window_s, check_version=True, nodes=nodes)
        finally:
            bus.shutdown()
    if cap is None:
        checks.append(check_clock([clock_start, clocks()]))
        for name in ("drive left", "drive right", "contract", "busload"):
            checks.append(Check(name, Status.NA, "not checked: the bus did not open"))
        return checks
    checks.append(check_clock(cap.clocks))
    cfg_or_default = cfg or ControllerConfig()
    checks += [check_drive(cap, n, codec, nodes) for n in DRIVES]
    checks.append(check_nodes(cap, codec, nodes))
    checks.append(check_version(cap, codec))
    checks.append(check_contract(cap, cfg_or_default, codec))
    checks.append(check_busload(cap, spec))
    return checks
