"""Opening python-can buses, and the private network namespace for udp_multicast.

python-can is the only bus layer.  Configuration is python-can's own: an explicit
``--bus/--channel`` wins, then ``CAN_INTERFACE``/``CAN_CHANNEL``/``CAN_BITRATE`` and
can.conf (``can.util.load_config``).

udp_multicast carries frames as IP multicast.  Outside a private network
namespace the default route would send them off the machine, so
:func:`open_bus` refuses it unless the current namespace has no interface but
loopback (or the caller passes ``allow_network_multicast``).
:func:`sandbox_argv` builds the ``unshare`` command line that creates such a
namespace (``--net`` as root, so that the parts keep SCHED_FIFO and mlock; ``-rn``, a
user namespace too, for anyone else), brings ``lo`` up and routes 224.0.0.0/4 to it.
"""

from __future__ import annotations

import errno
import os
import queue
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import msgpack
from can.interfaces.udp_multicast import UdpMulticastBus
from can.interfaces.udp_multicast.utils import unpack_message
from can.interfaces.virtual import VirtualBus
from can.interfaces.virtual import channels_lock as virtual_channels_lock

from dbc.runtime import stopping
from dbc.runtime.busio import bare_message
from dbc.runtime.errors import BusError, NamespaceError
from tools.bus import rxloss
from tools.bus.lean_socketcan import LeanSocketcanBus

#: python-can's default IPv4 multicast group for udp_multicast.
DEFAULT_MULTICAST_GROUP = "239.74.163.2"
DEFAULT_BITRATE = 500_000
#: python-can ``Bus`` keyword arguments that ``BusSpec`` carries itself.
_RESERVED_OPTIONS = frozenset({"interface", "bustype", "channel", "bitrate"})
#: Marker in the environment of processes started inside our sandbox.
SANDBOX_ENV = "WHEELCHAIR_HIL_SANDBOX"


@dataclass(frozen=True)
class BusSpec:
    """Which bus to open: python-can interface, channel, bitrate."""

    interface: str
    channel: str
    bitrate: int = DEFAULT_BITRATE
    allow_network_multicast: bool = False
    #: further python-can ``Bus`` keyword arguments (``--bus-option KEY=VALUE``)
    options: tuple[tuple[str, Any], ...] = ()

    def describe(self) -> str:
        return f"{self.interface}:{self.channel}"


def python_can_config() -> dict[str, Any]:
    """python-can's own configuration (``CAN_INTERFACE``/``CAN_CHANNEL``/..., can.conf)."""
    try:
        return dict(can.util.load_config())
    except can.CanInterfaceNotImplementedError:
        return {}


def resolve(
    interface: str | None,
    channel: str | None,
    *,
    allow_network_multicast: bool = False,
    bitrate: int | None = None,
    options: dict[str, Any] | None = None,
) -> BusSpec:
    """Resolve the bus from arguments, then python-can's environment and config files.

    ``interface`` is any python-can interface name (``can.interfaces.VALID_INTERFACES``);
    ``options`` are passed to ``can.Bus`` as python-can's keyword arguments.
    """
    cfg: dict[str, Any] = {}
    if interface is None or channel is None or bitrate is None:
        cfg = python_can_config()
    iface = interface or cfg.get("interface")
    if iface is None:
        raise BusError(
            "no bus given: pass --bus (virtual, udp_multicast, socketcan, pcan, kvaser, ...) "
            "or set CAN_INTERFACE"
        )
    valid = sorted(can.interfaces.VALID_INTERFACES)
    if iface not in valid:
        raise BusError(f"unknown bus {iface!r}: python-can's interfaces are {', '.join(valid)}")
    chan = channel or (cfg.get("channel") if cfg.get("interface") == iface else None)
    if chan is None:
        chan = profile(iface).default_channel
    if chan is None:
        raise BusError(f"bus {iface!r} needs a channel: pass --channel or set CAN_CHANNEL")
    if bitrate is None:
        bitrate = int(cfg.get("bitrate") or DEFAULT_BITRATE)
    if not 10_000 <= bitrate <= 1_000_000:
        raise BusError(f"bitrate {bitrate} bit/s is outside [10000, 1000000] (classic CAN)")
    opts = dict(options or {})
    reserved = sorted(_RESERVED_OPTIONS & set(opts))
    if reserved:
        raise BusError(f"bus option {reserved[0]!r} has its own flag (--bus, --channel, --bitrate)")
    return BusSpec(iface, str(chan), bitrate, allow_network_multicast, tuple(sorted(opts.items())))


def interfaces() -> list[str]:
    """Network interfaces of the current namespace."""
    return sorted(name for _idx, name in socket.if_nameindex())


def in_private_namespace() -> bool:
    """True when loopback is the only network interface (nothing can leave the machine)."""
    return interfaces() == ["lo"]


def check_multicast_allowed(spec: BusSpec) -> None:
    """Refuse udp_multicast where frames could leave the machine (see module doc)."""
    if not profile(spec.interface).private_namespace or spec.allow_network_multicast:
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


def open_bus(spec: BusSpec, *, part: str | None = None, **kwargs: Any) -> can.BusABC:
    """Open a python-can bus for ``spec``; raise :class:`BusError` with the cause if it fails.

    ``part`` (``sim``, ``control``, ``record``) names the receiver for its receive-buffer
    size (:mod:`tools.bus.rxloss`); ``kwargs`` go to python-can.
    """
    check_multicast_allowed(spec)
    prof = profile(spec.interface)
    prof.check(spec)
    args: dict[str, Any] = {"channel": spec.channel, **prof.open_options}
    args.update(spec.options)
    if prof.has_bitrate:  # a CAN adapter: python-can sets its bitrate
        args["bitrate"] = spec.bitrate
    args.update(kwargs)
    try:
        if prof.opener is not None:
            bus: can.BusABC = prof.opener(**args)
        else:
            bus = can.Bus(interface=spec.interface, **args)
    except (can.CanError, OSError, ValueError, ImportError) as err:
        raise BusError(f"cannot open {spec.interface} channel {spec.channel}: {err}") from err
    if prof.kernel_socket:
        rxloss.size_receive_buffer(bus, part=part)
    return bus


class _Inbox(queue.SimpleQueue[can.Message]):
    """A receiver's queue on a virtual channel, with the frames its filters accept.

    ``accept`` is ``None`` (every frame), a set of ``(arbitration_id, is_extended_id)``
    (exact-ID filters, the common case) or the receiving bus (anything else: its own
    ``_matches_filters`` decides).  Plain python-can virtual buses on the same channel
    put into it like into their own queues and never look at ``accept``.
    """

    __slots__ = ("accept",)
    accept: Any


class LightVirtualBus(VirtualBus):
    """python-can's virtual bus, made cheap enough for lock-step runs in one process.

    These differences from ``VirtualBus``, none visible on the bus:

    * each receiver gets a plain copy of a frame instead of a deep copy (a CAN frame is
      flat: ints, flags and a byte array);
    * the receive queue is a ``queue.SimpleQueue`` (put and get in C) instead of a
      ``queue.Queue`` (a Python lock and condition per call);
    * a receiver's filters (:meth:`set_filters`) are applied when a frame is sent, so a
      frame nobody wants is neither copied nor queued, like a CAN controller's acceptance
      filter.  ``recv`` still checks them, as python-can does, and takes frames straight
      from the queue (python-can's ``recv`` adds a debug-log call per frame);
    * a listener with a ``take(msg, timestamp)`` method gets the sender's frame itself,
      to copy what it keeps (:class:`tools.logs.bustap.ChannelTap`).

    And one addition: :attr:`on_idle`, if set, is called when ``recv`` finds the queue
    empty and would wait; a run with the bench and the controller in one thread runs the
    controller there (:mod:`tools.run.in_process`).  It must not wait itself.

    It shares python-can's channels, so it talks to plain ``virtual`` buses too.
    """

    #: Called by ``recv`` (in the receiving thread) before it waits for a frame.
    on_idle: Callable[[], object] | None = None

    def __init__(self, channel: Any = "channel-0", **kwargs: Any) -> None:
        if kwargs.get("rx_queue_size"):
            raise ValueError("LightVirtualBus has unbounded receive queues (rx_queue_size=0)")
        super().__init__(channel=channel, **kwargs)
        inbox = _Inbox()
        inbox.accept = _accept_for(self._filters, self)
        with virtual_channels_lock:
            members: list[Any] = self.channel
            i = next(k for k, q in enumerate(members) if q is self.queue)
            members[i] = inbox
            self.queue = inbox  # type: ignore[assignment]

    def _apply_filters(self, filters: Any) -> None:
        inbox = getattr(self, "queue", None)  # None while BusABC.__init__ sets the filters
        if isinstance(inbox, _Inbox):
            inbox.accept = _accept_for(filters, self)

    def _matches_filters(self, msg: can.Message) -> bool:
        accept = getattr(self.queue, "accept", self)
        if accept is None:
            return True
        if isinstance(accept, frozenset):
            return (msg.arbitration_id, msg.is_extended_id) in accept
        return super()._matches_filters(msg)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """python-can's ``recv`` (same filters and timeout), straight from the queue."""
        if not self._open:
            self._check_if_open()  # raises python-can's error
        get = self.queue.get
        accept = getattr(self.queue, "accept", None)
        deadline = None if timeout is None else time.monotonic() + max(0.0, timeout)
        left = timeout
        on_idle = self.on_idle
        while True:
            if on_idle is not None and (left is None or left > 0) and self.queue.empty():
                on_idle()  # the other parts of a one-thread run go on while this one would wait
            try:
                msg: can.Message = get(True, left) if left is None or left > 0 else get(False)
            except queue.Empty:
                return None
            if accept is None:
                return msg
            if type(accept) is frozenset:  # exact-ID filters (_matches_filters, inline)
                if (msg.arbitration_id, msg.is_extended_id) in accept:
                    return msg
            elif self._matches_filters(msg):
                return msg
            if deadline is not None:
                left = deadline - time.monotonic()
                if left <= 0:
                    return None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self._open:
            self._check_if_open()  # raises python-can's error
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        key = (msg.arbitration_id, msg.is_extended_id)
        own = self.queue
        for inbox in self.channel:
            if inbox is own and not self.receive_own_messages:
                continue
            take = getattr(inbox, "take", None)
            if take is not None:  # a listener keeping its own copy (tools.logs.bustap.ChannelTap)
                take(msg, timestamp)
                continue
            accept = getattr(inbox, "accept", None)
            if accept is not None:
                if isinstance(accept, frozenset):
                    if key not in accept:
                        continue
                elif not accept._matches_filters(msg):
                    continue
            # python-can's copy (can.Message of the sent frame's values), without the
            # constructor's checks: a sent frame is a frame already
            remote = msg.is_remote_frame
            inbox.put(
                bare_message(
                    timestamp, msg.arbitration_id, msg.is_extended_id, remote,
                    msg.is_error_frame, self.channel_id, msg.dlc,
                    bytearray() if remote else bytearray(msg.data), msg.is_fd,
                    inbox is not own, msg.bitrate_switch, msg.error_state_indicator,
                )
            )  # fmt: skip


_FLAGS = (
    "is_extended_id",
    "is_remote_frame",
    "is_error_frame",
    "is_fd",
    "bitrate_switch",
    "error_state_indicator",
)


class EchoFreeUdpMulticastBus(UdpMulticastBus):
    """python-can's udp_multicast bus, without the echo of its own frames.

    Multicast loopback hands every datagram to every socket on the host, the sender's
    too, and python-can's interface cannot tell its own apart (it accepts only
    ``receive_own_messages=False`` but does not enforce it).  This bus remembers the
    datagrams it sent and drops their echoes before unpacking them, so that, as on
    SocketCAN and the virtual bus, a bus receives the other participants' frames only.
    Each frame without a timestamp is sent with the sending time, which makes the
    datagrams of different senders distinct (python-can receivers replace it with their
    receive time anyway).  The wire format is python-can's: plain ``udp_multicast``
    buses (``can_viewer``, ``cantools monitor``) share the bus and see every frame.
    """

    #: Echoes awaited at most: beyond, the oldest are taken as lost (a full receive buffer).
    MAX_AWAITED = 4096

    def __init__(self, channel: str = UdpMulticastBus.DEFAULT_GROUP_IPv6, **kwargs: Any) -> None:
        super().__init__(channel, **kwargs)
        self._awaited: deque[bytes] = deque()
        self.echoes_dropped = 0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_fd and self.protocol is not can.CanProtocol.CAN_FD:
            raise can.CanOperationError("cannot send FD message over bus with CAN FD disabled")
        data = msgpack.packb(
            {
                "timestamp": msg.timestamp or time.time(),
                "arbitration_id": msg.arbitration_id,
                "is_extended_id": msg.is_extended_id,
                "is_remote_frame": msg.is_remote_frame,
                "is_error_frame": msg.is_error_frame,
                "channel": msg.channel,
                "dlc": msg.dlc,
                "data": msg.data,
                "is_fd": msg.is_fd,
                "bitrate_switch": msg.bitrate_switch,
                "error_state_indicator": msg.error_state_indicator,
            },
            use_bin_type=True,
        )
        self._multicast.send(data, timeout)
        awaited = self._awaited
        awaited.append(data)
        if len(awaited) > self.MAX_AWAITED:
            awaited.popleft()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        left = timeout
        awaited = self._awaited
        while True:
            result = self._multicast.recv(left)
            if not result:
                return None, False
            data = result[0]
            if awaited and (data == awaited[0] or data in awaited):
                # our own frame: loopback returns them in the order they were sent, so any
                # awaited before it were lost on the way back
                while awaited.popleft() != data:
                    pass
                self.echoes_dropped += 1
                if deadline is not None:  # past it, still take what is already queued
                    left = max(0.0, deadline - time.monotonic())
                continue
            try:
                msg = unpack_message(data, replace={"timestamp": result[2]}, check=True)
                if msg.is_fd and self.protocol is not can.CanProtocol.CAN_FD:
                    raise ValueError("a CAN FD frame on a bus with CAN FD disabled")
                # python-can's check takes any value for a flag (is_fd = 66): a frame's
                # flags are booleans, its ID and DLC integers
                if any(type(getattr(msg, f)) is not bool for f in _FLAGS) or not (
                    type(msg.arbitration_id) is int and type(msg.dlc) is int
                ):
                    raise ValueError("a flag that is not a boolean, or an ID or DLC not an int")
            except Exception as err:
                # python-can's own behaviour (the receiver counts and drops it: dbc.runtime.busio);
                # an FD frame, which python-can drops without a word, is one of them here
                raise can.CanOperationError("could not unpack received message") from err
            return msg, False


def _check_socketcan(spec: BusSpec) -> None:
    ok, why = socketcan_available()
    if not ok:
        raise BusError(f"cannot open socketcan channel {spec.channel}: {why}")


@dataclass(frozen=True)
class BusProfile:
    """What the stack does differently for one kind of python-can interface: one row of
    :data:`PROFILES` per transport it treats apart, :data:`ADAPTER` for any other (a CAN
    adapter python-can opens).  The doctor's interface check and fix are keyed by the same
    names (``tools/deploy/interface_checks.py``)."""

    name: str
    #: the channel when none is given (None: the user must name one)
    default_channel: str | None
    #: the class that opens it (None: ``can.Bus(interface=name)``), and its fixed options
    opener: Callable[..., can.BusABC] | None = None
    open_options: Mapping[str, Any] = field(default_factory=dict)
    #: an emulation of a bus (no CAN controller, no bitrate: the virtual bus, IP multicast)
    emulated: bool = False
    #: a CAN adapter whose bitrate python-can sets when it opens it (socketcan's is the
    #: kernel's link setting)
    has_bitrate: bool = False
    #: a kernel socket: its receive buffer is sized and its drops counted (tools.bus.rxloss)
    kernel_socket: bool = False
    #: frames reach other processes (the virtual bus is one process's)
    between_processes: bool = True
    #: opened only inside a private network namespace (frames could leave the machine)
    private_namespace: bool = False
    #: a network device the kernel names (systemd's unit binds to it)
    network_device: bool = False
    #: before opening: raise BusError with the cause where it cannot work here
    precheck: Callable[[BusSpec], None] | None = None

    def check(self, spec: BusSpec) -> None:
        if self.precheck is not None:
            self.precheck(spec)


#: The transports the stack treats apart, by python-can interface name.
PROFILES: dict[str, BusProfile] = {
    p.name: p
    for p in (
        BusProfile(
            "virtual",
            "wheelchair",
            LightVirtualBus,
            {"preserve_timestamps": False},
            emulated=True,
            between_processes=False,
        ),
        BusProfile(
            "udp_multicast",
            DEFAULT_MULTICAST_GROUP,
            EchoFreeUdpMulticastBus,
            emulated=True,
            kernel_socket=True,
            private_namespace=True,
        ),
        BusProfile(
            "socketcan",
            "can0",
            LeanSocketcanBus,
            kernel_socket=True,
            network_device=True,
            precheck=_check_socketcan,
        ),
    )
}
#: The transports this module adds behaviour to; any other python-can interface is a CAN
#: adapter opened through ``can.Bus`` with the bitrate and options given.
INTERFACES = tuple(PROFILES)
#: Any other python-can interface: a CAN adapter (pcan, kvaser, slcan, gs_usb, ...).
ADAPTER = BusProfile("adapter", None, has_bitrate=True)


def profile(interface: str) -> BusProfile:
    """The profile of python-can interface ``interface`` (:data:`ADAPTER` for an adapter)."""
    return PROFILES.get(interface, ADAPTER)


def _accept_for(filters: Any, bus: can.BusABC) -> frozenset[tuple[int, bool]] | can.BusABC | None:
    """What :class:`_Inbox.accept` holds for python-can ``filters`` (see there)."""
    if not filters:
        return None
    keys = []
    for f in filters:
        ext = f.get("extended")
        full = 0x1FFFFFFF if ext else 0x7FF
        if ext is None or f["can_mask"] & full != full:
            return bus
        keys.append((f["can_id"] & full, bool(ext)))
    return frozenset(keys)


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
    return [*_unshare_argv(), "--", "sh", "-c", _SETUP, "sh", *cmd]


def _unshare_argv() -> list[str]:
    """``unshare --net`` as root (the parts keep their capabilities: SCHED_FIFO, mlock),
    ``unshare --user --map-root-user --net`` for anyone else (root only inside)."""
    if os.geteuid() == 0 and _root_can_unshare():
        return ["unshare", "--net"]
    return ["unshare", "--user", "--map-root-user", "--net"]


_ROOT_UNSHARE: bool | None = None


def _root_can_unshare() -> bool:
    """Whether a plain ``unshare --net`` works here (root without CAP_SYS_ADMIN, e.g. in
    some containers, cannot: then a user namespace it is)."""
    global _ROOT_UNSHARE
    if _ROOT_UNSHARE is None:
        try:
            res = subprocess.run(
                ["unshare", "--net", "--", "true"], capture_output=True, timeout=10, check=False
            )
            _ROOT_UNSHARE = res.returncode == 0
        except (OSError, subprocess.TimeoutExpired):
            _ROOT_UNSHARE = False
    return _ROOT_UNSHARE


def sandbox_supported() -> tuple[bool, str]:
    """Whether this system lets an unprivileged user create a network namespace here."""
    try:
        argv = sandbox_argv(["true"])
    except BusError as err:
        return False, str(err)

    try:
        res = subprocess.run(argv, capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.TimeoutExpired) as err:
        return False, f"unshare failed: {err}"
    if res.returncode != 0:
        why = f"{' '.join(argv[:-6])} failed: {res.stderr.strip() or res.returncode}"
        return False, why + userns_hint()
    return True, ""


#: Where a kernel with AppArmor's restriction (Ubuntu 23.10 and later) says whether it refuses
#: unprivileged user namespaces.
APPARMOR_USERNS = Path("/proc/sys/kernel/apparmor_restrict_unprivileged_userns")


def userns_hint(path: Path = APPARMOR_USERNS) -> str:
    """The setting that refuses unprivileged user namespaces here, if one does: a hint to add
    to the error (empty where none is known)."""
    try:
        if path.read_text().strip() == "1":
            return (
                f"; {path} is 1 (AppArmor refuses unprivileged user namespaces): "
                "sudo sysctl -w kernel.apparmor_restrict_unprivileged_userns=0"
            )
    except OSError:
        pass
    return ""


def bus_options_of(items: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings to python-can keyword arguments (values as can.conf casts them)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise BusError(f"--bus-option {item!r}: expected KEY=VALUE")
        out[key.strip()] = can.util.cast_from_string(value)
    return out


def bus_argv(spec: BusSpec) -> list[str]:
    """The command-line flags that reopen ``spec`` in a child process (a run's parts)."""
    argv = ["--bus", spec.interface, "--channel", spec.channel, "--bitrate", str(spec.bitrate)]
    for key, value in spec.options:
        argv += ["--bus-option", f"{key}={value}"]
    if spec.allow_network_multicast:
        argv.append("--allow-network-multicast")
    return argv


def exec_in_sandbox(cmd: Sequence[str]) -> int:
    """Run ``cmd`` in a private namespace and return its exit code.

    A stop signal to this process (:mod:`dbc.runtime.stopping`) is passed on to ``cmd``, which
    ends with its own status; ``cmd`` starts with the stop signals blocked until its handlers
    are in place, so none can kill it.
    """
    argv = sandbox_argv(cmd)
    stop = stopping.stop_event()
    with stopping.blocked():
        proc = subprocess.Popen(argv)
    forwarded = False
    while True:
        try:
            return proc.wait(0.05)
        except subprocess.TimeoutExpired:
            pass
        if stop.is_set() and not forwarded:
            forwarded = True
            sigs = stopping.received()
            proc.send_signal(signal.SIGINT if sigs and sigs[-1] == "SIGINT" else signal.SIGTERM)


def python_argv(*args: str) -> list[str]:
    """Command line that runs this project's CLI with the current interpreter."""
    return [sys.executable, "-m", "tools.cli", *args]


def errno_name(code: int) -> str:
    return errno.errorcode.get(code, str(code))


def env_in_sandbox() -> bool:
    return os.environ.get(SANDBOX_ENV) == "1"
