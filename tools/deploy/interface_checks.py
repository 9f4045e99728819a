"""The doctor's check of the CAN interface: up, bitrate, error state (SocketCAN, from
``ip -details -json link``); an honest n/a where there is no CAN controller (udp_multicast, the
virtual bus).
"""

from __future__ import annotations

import json
import shutil
import subprocess
from collections.abc import Callable
from typing import Any

from dbc.runtime.errors import WheelchairError
from tools.bus.transport import PROFILES, BusSpec, socketcan_available
from tools.deploy.check import Check, Status


def check_interface(spec: BusSpec) -> Check:
    """The CAN interface: up, bitrate, error state (SocketCAN); honest n/a elsewhere."""
    return _CHECKS.get(spec.interface, _check_adapter)(spec)


def _check_udp_multicast(spec: BusSpec) -> Check:
    up = _iface_up("lo")
    if up is False:
        return Check(
            "interface",
            Status.FAIL,
            "udp_multicast: loopback lo is down, no frame can pass",
            "ip link set lo up (or run inside wheelchair-hil sandbox)",
        )
    return Check(
        "interface",
        Status.NA,
        f"udp_multicast ({spec.channel}) has no CAN controller: no bitrate, no error state "
        "(loopback up; the bench's bus, never a chair's)",
    )


def _check_virtual(spec: BusSpec) -> Check:
    return Check("interface", Status.NA, "virtual bus: in this process only, no controller")


def _check_adapter(spec: BusSpec) -> Check:
    return Check(
        "interface",
        Status.NA,
        f"{spec.interface}: the adapter's state is not readable here; python-can sets "
        f"{spec.bitrate} bit/s when it opens it",
    )


def _iface_up(name: str) -> bool | None:
    """Whether interface ``name`` of this network namespace is up (None: cannot tell).

    Asked of the kernel through ``ip``: /sys/class/net shows the namespace that mounted
    /sys, which inside ``wheelchair-hil sandbox`` is the host's.
    """
    try:
        link = ip_link(name)
    except (WheelchairError, OSError, subprocess.TimeoutExpired):
        return None
    return "UP" in link.get("flags", [])


def bus_fix(spec: BusSpec) -> str:
    """What to do where the bus did not open."""
    return _FIXES.get(spec.interface, lambda _s: "check the adapter and its driver")(spec)


def _fix_socketcan(spec: BusSpec) -> str:
    ok, why = socketcan_available()
    if not ok:  # no interface to bring up: the kernel itself lacks CAN
        return (
            f"no SocketCAN here ({why}): load the kernel's CAN modules (sudo modprobe can "
            "can_raw, and vcan for a virtual bus) or boot a kernel built with CAN; on a "
            "machine without, wheelchair-hil sandbox --socketcan runs a user-mode Linux "
            "guest that has it"
        )
    return _bringup(spec.channel, spec.bitrate)


def _fix_udp_multicast(spec: BusSpec) -> str:
    return "run inside wheelchair-hil sandbox (loopback up, 224.0.0.0/4 routed to it)"


def _fix_virtual(spec: BusSpec) -> str:
    return "a virtual bus always opens: a fault in this process (run with -vv)"


def _bringup(channel: str, bitrate: int) -> str:
    return (
        f"sudo ip link set {channel} down; sudo ip link set {channel} type can bitrate {bitrate} "
        f"restart-ms 100; sudo ip link set {channel} txqueuelen 1000; sudo ip link set {channel} up"
    )


def ip_link(channel: str) -> dict[str, Any]:
    """``ip -details -statistics -json link show dev CHANNEL`` as a dict (WheelchairError if not)."""
    ip = shutil.which("ip")
    if ip is None:
        raise WheelchairError("ip (iproute2) is not installed")
    res = subprocess.run(
        [ip, "-details", "-statistics", "-json", "link", "show", "dev", channel],
        capture_output=True,
        text=True,
        timeout=10,
        check=False,
    )
    if res.returncode != 0:
        raise WheelchairError(res.stderr.strip() or f"ip exited with {res.returncode}")
    try:
        data = json.loads(res.stdout)
    except json.JSONDecodeError as err:
        raise WheelchairError(f"ip -json gave no JSON ({err}): iproute2 too old?") from err
    if not isinstance(data, list) or not data or not isinstance(data[0], dict):
        raise WheelchairError(f"ip -json link show {channel}: unexpected output {res.stdout!r}")
    link: dict[str, Any] = data[0]
    return link


def judge_socketcan(link: dict[str, Any], channel: str, bitrate: int) -> Check:
    """Judge one ``ip -json`` link record (separate from :func:`ip_link` so it can be tested)."""
    flags = link.get("flags", [])
    info = link.get("linkinfo", {}) or {}
    kind = info.get("info_kind", "?")
    data = info.get("info_data", {}) or {}
    txq = link.get("txqlen")
    if "UP" not in flags:
        fix = f"sudo ip link set {channel} up" if kind == "vcan" else _bringup(channel, bitrate)
        return Check("interface", Status.FAIL, f"{channel} ({kind}) is down", fix)
    if kind == "vcan":
        return Check(
            "interface",
            Status.OK,
            f"{channel} up (vcan: virtual CAN, no bitrate and no error state; txqueuelen {txq})",
        )
    if kind != "can":
        return Check(
            "interface", Status.FAIL, f"{channel} is a {kind} link, not a CAN interface", ""
        )
    state = data.get("state", "?")
    have = (data.get("bittiming") or {}).get("bitrate")
    restart_ms = data.get("restart_ms", 0)
    berr = data.get("berr_counter") or {}
    stats = (link.get("stats64") or link.get("stats") or {}).get("rx", {}) or {}
    detail = (
        f"{channel} up, {have} bit/s, {state}, restart-ms {restart_ms}, txqueuelen {txq}, "
        f"error counters tx {berr.get('tx', 0)} rx {berr.get('rx', 0)}, "
        f"rx errors {stats.get('errors', 0)}"
    )
    if have != bitrate:
        return Check(
            "interface",
            Status.FAIL,
            f"{detail}: bitrate {have}, the drives' is {bitrate}",
            _bringup(channel, bitrate),
        )
    if state in ("BUS-OFF", "STOPPED", "ERROR-PASSIVE"):
        return Check(
            "interface",
            Status.FAIL,
            f"{detail}: the controller is {state}",
            "check CAN_H/CAN_L wiring, one 120 ohm terminator at each end, every node's bitrate; "
            + _bringup(channel, bitrate),
        )
    if state == "ERROR-WARNING":
        return Check("interface", Status.WARN, detail, "check wiring and termination")
    if not restart_ms:
        return Check(
            "interface",
            Status.WARN,
            f"{detail}: restart-ms 0, a bus-off never recovers by itself",
            _bringup(channel, bitrate),
        )
    if isinstance(txq, int) and txq < 100:
        return Check(
            "interface",
            Status.WARN,
            f"{detail}: a short transmit queue fails a burst of frames with ENOBUFS",
            f"sudo ip link set {channel} txqueuelen 1000",
        )
    return Check("interface", Status.OK, detail)


def _check_socketcan(spec: BusSpec) -> Check:
    try:
        link = ip_link(spec.channel)
    except (WheelchairError, OSError, subprocess.TimeoutExpired) as err:
        return Check(
            "interface",
            Status.FAIL,
            f"{spec.channel}: {err}",
            f"is the adapter plugged in and its driver loaded? {_bringup(spec.channel, spec.bitrate)}",
        )
    return judge_socketcan(link, spec.channel, spec.bitrate)


#: The doctor's check and fix of each transport the stack treats apart, keyed as
#: tools.bus.transport.PROFILES (any other interface is an adapter); the module refuses to
#: load while the tables differ.
_CHECKS: dict[str, Callable[[BusSpec], Check]] = {
    "virtual": _check_virtual,
    "udp_multicast": _check_udp_multicast,
    "socketcan": _check_socketcan,
}
_FIXES: dict[str, Callable[[BusSpec], str]] = {
    "virtual": _fix_virtual,
    "udp_multicast": _fix_udp_multicast,
    "socketcan": _fix_socketcan,
}
if set(_CHECKS) != set(PROFILES) or set(_FIXES) != set(PROFILES):
    raise ImportError("tools.deploy.interface_checks: its tables and transport.PROFILES differ")
