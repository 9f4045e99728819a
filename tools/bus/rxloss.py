"""What a receiving part's kernel socket may hold, and what the kernel dropped for it.

A lock-step run never loses a frame by design (the bench waits for the controller's
acks and stays at most ``RECORDER_WINDOW_STEPS`` ahead of the recorder), but a
socket's receive queue is finite: a recorder that falls behind by more frames than
its queue holds loses the rest in the kernel, where nobody sees it.  So every part
that receives on ``socketcan`` or ``udp_multicast``

* sizes its socket's receive buffer for the lock-step window
  (:func:`size_receive_buffer`, :data:`WINDOW_BUFFER_BYTES`), and
* counts the frames the kernel dropped for it (:func:`kernel_drops`): the socket's
  ``sk_drops`` counter, read with ``SO_MEMINFO``.  It is the counter ``SO_RXQ_OVFL``
  reports with each frame; both SocketCAN's ``CAN_RAW`` and UDP sockets count a frame
  refused for a full receive queue there.

The virtual bus has unbounded queues and drops nothing (:func:`kernel_drops` is 0).
A run whose parts dropped anything is incomplete (``tools.run.summary``).
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import sys
from typing import Any

import can

from dbc.runtime.errors import BusError

log = logging.getLogger(__name__)

#: Lock-step steps a recorder may lag behind the bench (``tools.run.parts``).
WINDOW_STEPS = 100
#: Frames on the bus per 10 ms step, bounded above (the paper route averages 9.6).
FRAMES_PER_STEP = 16
#: Kernel memory charged per queued frame, bounded above: 768 B for a CAN_RAW frame
#: (measured on Linux 6.1), up to about 2 KiB for a udp_multicast datagram.
BYTES_PER_FRAME = 2048
#: Receive buffer that holds the whole lock-step window, with 10 steps to spare.
WINDOW_BUFFER_BYTES = (WINDOW_STEPS + 10) * FRAMES_PER_STEP * BYTES_PER_FRAME
#: Environment override of every part's receive buffer, in bytes (a test's tiny buffer).
RCVBUF_ENV = "WHEELCHAIR_HIL_RCVBUF"
RCVBUF_MIN, RCVBUF_MAX = 1024, 1 << 30
#: The parts of a run that receive.
PARTS = ("sim", "control", "record")
#: Exit status of a part, and of ``run``, that lost frames: it ran, but what it read is partial.
LOSS_EXIT = 3

_SO_MEMINFO = getattr(socket, "SO_MEMINFO", 55)
_SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
_SK_MEMINFO_DROPS = 8  # index of sk_drops in SO_MEMINFO's u32 array


def kernel_socket(bus: can.BusABC) -> socket.socket | None:
    """The kernel socket a python-can bus receives on (socketcan, udp_multicast), or None."""
    sock = getattr(bus, "socket", None)  # python-can's SocketcanBus
    if isinstance(sock, socket.socket):
        return sock
    sock = getattr(getattr(bus, "_multicast", None), "_socket", None)  # UdpMulticastBus
    return sock if isinstance(sock, socket.socket) else None


def requested_buffer_bytes(part: str | None = None) -> int | None:
    """The receive buffer ``part`` asks for: ``$WHEELCHAIR_HIL_RCVBUF`` if it names one, else None.

    The variable is ``BYTES`` (every part) or ``PART=BYTES`` (``sim``, ``control`` or
    ``record`` only; e.g. a test's tiny recorder buffer).  None: the default,
    :data:`WINDOW_BUFFER_BYTES`.
    """
    raw = os.environ.get(RCVBUF_ENV, "").strip()
    if not raw:
        return None
    target, sep, value_s = raw.rpartition("=")
    if sep and target not in PARTS:
        raise BusError(f"{RCVBUF_ENV}={raw!r}: the part must be one of {', '.join(PARTS)}")
    try:
        value = int(value_s)
    except ValueError:
        raise BusError(f"{RCVBUF_ENV}={raw!r} is not a whole number of bytes") from None
    if not RCVBUF_MIN <= value <= RCVBUF_MAX:
        raise BusError(f"{RCVBUF_ENV}={raw!r} is outside [{RCVBUF_MIN}, {RCVBUF_MAX}] bytes")
    if sep and target != part:
        return None
    return value


def size_receive_buffer(
    bus: can.BusABC, nbytes: int | None = None, *, part: str | None = None
) -> int | None:
    """Give ``bus``'s kernel socket a receive buffer of ``nbytes``; return what it got.

    ``SO_RCVBUFFORCE`` (needs CAP_NET_ADMIN, which a UML guest and a private namespace
    have) goes past ``net.core.rmem_max``; otherwise ``SO_RCVBUF`` is capped by it.  The
    result is the kernel's figure (Linux doubles the request for its bookkeeping).
    None for a bus without a kernel socket.
    """
    sock = kernel_socket(bus)
    if sock is None:
        return None
    if nbytes is None:
        nbytes = requested_buffer_bytes(part)
    explicit = nbytes is not None
    want = WINDOW_BUFFER_BYTES if nbytes is None else nbytes
    if explicit:  # exactly this size (capped by rmem_max), small ones included
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, want)
    else:
        try:
            sock.setsockopt(socket.SOL_SOCKET, _SO_RCVBUFFORCE, want)
        except OSError:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, want)
    got = int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
    if not explicit and got < WINDOW_BUFFER_BYTES:
        log.warning(
            "receive buffer %d B is smaller than the lock-step window needs (%d B): "
            "raise net.core.rmem_max or run with CAP_NET_ADMIN; lost frames are counted",
            got,
            WINDOW_BUFFER_BYTES,
        )
    return got


def kernel_drops(bus: can.BusABC) -> int:
    """Frames the kernel dropped for ``bus``'s socket so far (0 where there is none)."""
    sock = kernel_socket(bus)
    if sock is None or sock.fileno() < 0:
        return 0
    try:
        raw = sock.getsockopt(socket.SOL_SOCKET, _SO_MEMINFO, 9 * 4)
    except OSError as err:
        log.debug("SO_MEMINFO unavailable: %s", err)
        return 0
    # SO_MEMINFO is an array of native u32 (linux/sock_diag.h); drops is one of them
    i = 4 * _SK_MEMINFO_DROPS
    return int.from_bytes(raw[i : i + 4], sys.byteorder)


def loss_of(stats: dict[str, Any]) -> int:
    """Frames a part's statistics say it lost (kernel drops; the recorder's missed steps)."""
    return int(stats.get("rx_dropped") or 0)
