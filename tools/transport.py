"""Opening python-can buses, and the private network namespace for udp_multicast.

python-can is the only bus layer.  Configuration is python-can's own: an explicit
``--bus/--channel`` wins, then ``CAN_INTERFACE``/``CAN_CHANNEL``/``CAN_BITRATE`` and
can.conf (``can.util.load_config``).

udp_multicast carries frames as IP multicast.  Outside a private network
namespace the default route would send them off the machine, so
:func:`open_bus` refuses it unless the current namespace has no interface but
loopback (or the caller passes ``allow_network_multicast``).
:func:`sandbox_argv` builds the ``unshare -rn`` command line that creates such a
namespace, brings ``lo`` up and routes 224.0.0.0/4 to it.
"""

from __future__ import annotations

import contextlib
import errno
import os
import queue
import shutil
import socket
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import can
from can.interfaces.virtual import VirtualBus

from dbc.errors import BusError, NamespaceError

#: python-can's default IPv4 multicast group for udp_multicast.
DEFAULT_MULTICAST_GROUP = "239.74.163.2"
DEFAULT_BITRATE = 500_000
INTERFACES = ("virtual", "udp_multicast", "socketcan")
#: Marker in the environment of processes started inside our sandbox.
SANDBOX_ENV = "WHEELCHAIR_HIL_SANDBOX"


@dataclass(frozen=True)
class BusSpec:
    """Which bus to open: python-can interface, channel, bitrate."""

    interface: str
    channel: str
    bitrate: int = DEFAULT_BITRATE
    allow_network_multicast: bool = False

    def describe(self) -> str:
        return f"{self.interface}:{self.channel}"


def resolve(
    interface: str | None, channel: str | None, *, allow_network_multicast: bool = False
) -> BusSpec:
    """Resolve the bus from arguments, then python-can's environment and config files."""
    cfg: dict[str, Any] = {}
    if interface is None or channel is None:
        try:
            cfg = dict(can.util.load_config())
        except can.CanInterfaceNotImplementedError:
            cfg = {}
    iface = interface or cfg.get("interface")
    if iface is None:
        raise BusError(
            "no bus given: pass --bus (virtual, udp_multicast, socketcan) or set CAN_INTERFACE"
        )
    if iface not in INTERFACES:
        raise BusError(f"unsupported bus {iface!r}: choose one of {', '.join(INTERFACES)}")
    chan = channel or (cfg.get("channel") if cfg.get("interface") == iface else None)
    if chan is None:
        chan = {
            "virtual": "wheelchair",
            "udp_multicast": DEFAULT_MULTICAST_GROUP,
            "socketcan": "can0",
        }[iface]
    bitrate = int(cfg.get("bitrate") or DEFAULT_BITRATE)
    return BusSpec(iface, str(chan), bitrate, allow_network_multicast)


def interfaces() -> list[str]:
    """Network interfaces of the current namespace."""
    return sorted(name for _idx, name in socket.if_nameindex())


def in_private_namespace() -> bool:
    """True when loopback is the only network interface (nothing can leave the machine)."""
    return interfaces() == ["lo"]


def check_multicast_allowed(spec: BusSpec) -> None:
    """Refuse udp_multicast where frames could leave the machine (see module doc)."""
    if spec.interface != "udp_multicast" or spec.allow_network_multicast:
        return
    names = interfaces()
    if names != ["lo"]:
        others = ", ".join(n for n in names if n != "lo")
        raise NamespaceError(
            f"refusing udp_multicast: this network namespace has interfaces besides loopback "
            f"({others}), so multicast frames could leave the machine. Run inside "
            f"'wheelchair-hil sandbox -- ...' or pass --allow-network-multicast"
        )


def socketcan_available() -> tuple[bool, str]:
    """Whether the kernel supports SocketCAN, and why not."""
    if not hasattr(socket, "AF_CAN"):
        return False, "this Python has no socket.AF_CAN"
    try:
        s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError as err:
        return False, f"the kernel has no SocketCAN (AF_CAN: errno {err.errno}, {err.strerror})"
    s.close()
    return True, ""


def open_bus(spec: BusSpec, **kwargs: Any) -> can.BusABC:
    """Open a python-can bus for ``spec``; raise :class:`BusError` with the cause if it fails."""
    check_multicast_allowed(spec)
    args: dict[str, Any] = {"interface": spec.interface, "channel": spec.channel}
    if spec.interface == "socketcan":
        ok, why = socketcan_available()
        if not ok:
            raise BusError(f"cannot open socketcan channel {spec.channel}: {why}")
    if spec.interface == "virtual":
        args["preserve_timestamps"] = False
    args.update(kwargs)
    try:
        if spec.interface == "virtual":
            del args["interface"]
            bus: can.BusABC = LightVirtualBus(**args)
        else:
            bus = can.Bus(**args)
    except (can.CanError, OSError, ValueError, ImportError) as err:
        raise BusError(f"cannot open {spec.interface} channel {spec.channel}: {err}") from err
    if spec.interface == "udp_multicast":
        _enlarge_receive_buffer(bus)
    return bus


class LightVirtualBus(VirtualBus):
    """python-can's virtual bus, handing each receiver a plain copy instead of a deep copy.

    ``VirtualBus.send`` deep-copies every frame for every receiver, which is most of
    its cost; a CAN frame is flat (ints, flags and a byte array), so constructing the
    copy directly gives each receiver the same independent message for a fraction of
    it.  It shares python-can's channels, so it talks to plain ``virtual`` buses too.
    """

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is self.queue and not self.receive_own_messages:
                continue
            copy = can.Message(
                timestamp=timestamp,
                arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame,
                channel=self.channel_id,
                dlc=msg.dlc,
                data=bytearray(msg.data),
                is_fd=msg.is_fd,
                is_rx=bus_queue is not self.queue,
                bitrate_switch=msg.bitrate_switch,
                error_state_indicator=msg.error_state_indicator,
            )
            try:
                bus_queue.put(copy, block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")


def _enlarge_receive_buffer(bus: can.BusABC, size: int = 4 * 1024 * 1024) -> None:
    """Give a udp_multicast receiver room for bursts (the kernel caps it at rmem_max)."""
    sock = getattr(getattr(bus, "_multicast", None), "_socket", None)
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)


# --------------------------------------------------------------------------- sandbox

_SETUP = (
    f'ip link set lo up && ip route add 224.0.0.0/4 dev lo && export {SANDBOX_ENV}=1 && exec "$@"'
)


def sandbox_argv(cmd: Sequence[str]) -> list[str]:
    """Command line that runs ``cmd`` in a new private network namespace ready for udp_multicast."""
    missing = [tool for tool in ("unshare", "ip") if shutil.which(tool) is None]
    if missing:
        raise BusError(
            f"cannot create a private network namespace: {', '.join(missing)} not found "
            "(install util-linux and iproute2)"
        )
    return ["unshare", "--user", "--map-root-user", "--net", "--", "sh", "-c", _SETUP, "sh", *cmd]


def sandbox_supported() -> tuple[bool, str]:
    """Whether this system lets an unprivileged user create a network namespace here."""
    try:
        argv = sandbox_argv(["true"])
    except BusError as err:
        return False, str(err)
    import subprocess

    try:
        res = subprocess.run(argv, capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.TimeoutExpired) as err:
        return False, f"unshare failed: {err}"
    if res.returncode != 0:
        return False, f"unshare -rn failed: {res.stderr.strip() or res.returncode}"
    return True, ""


def exec_in_sandbox(cmd: Sequence[str]) -> int:
    """Run ``cmd`` in a private namespace and return its exit code (signals forwarded)."""
    import subprocess

    argv = sandbox_argv(cmd)
    proc = subprocess.Popen(argv)
    try:
        return proc.wait()
    except KeyboardInterrupt:
        proc.terminate()
        return proc.wait()


def python_argv(*args: str) -> list[str]:
    """Command line that runs this project's CLI with the current interpreter."""
    return [sys.executable, "-m", "tools.cli", *args]


def errno_name(code: int) -> str:
    return errno.errorcode.get(code, str(code))


def env_in_sandbox() -> bool:
    return os.environ.get(SANDBOX_ENV) == "1"
