"""python-can's SocketCAN bus, one system call a frame.

python-can's ``SocketcanBus`` reads the clock and polls the socket around every frame: a
send is ``time.time()``, a ``select()`` for writability (with its own clock read) and the
``send()``; a receive is ``BusABC.recv``'s two ``time.time()``, a ``select()`` and the
``recvmsg()``.  On a chair's kernel each costs well under a microsecond.  Where a system
call is expensive, it decides whether a part keeps real time: in the user-mode Linux guest
of the socketcan lane (``wheelchair-hil sandbox --socketcan``) one costs about 90 us, and
the bench's 10 ms step spent some 35 of them on its six frames, so that it ran at half of
real time and the controller's reference ran away from the chair.

:class:`LeanSocketcanBus` is the same bus with the same frames and errors, sending and
receiving with one call each:

* ``send``: ``send(frame, MSG_DONTWAIT)``.  A full transmit queue raises what python-can
  raises ("Transmit buffer full") when no timeout is given; with a timeout, python-can's
  own wait takes over.
* a receive: ``recvmsg(..., MSG_DONTWAIT)`` first; only when nothing is queued and the
  caller waits does it ``select()`` for the rest of its timeout.  The frame is python-can's
  (its ``dissect_can_frame``, the kernel's ``SO_TIMESTAMPNS`` receive time, ``is_rx`` from
  ``MSG_DONTROUTE``, the channel from the address on an any-interface bus).

The kernel filters, error frames, CAN FD, BCM periodic sends, receive-buffer sizing and
drop counting (:mod:`tools.bus.rxloss`: the socket is python-can's ``bus.socket``) are
python-can's, untouched.  ``tests/hil/socketcan/test_lean_bus.py`` holds it to python-can's
bus frame for frame on ``vcan0``.
"""

from __future__ import annotations

import select
import socket
import time
from typing import Any

import can
from can.interfaces.socketcan import constants
from can.interfaces.socketcan.socketcan import (
    RECEIVED_ANCILLARY_BUFFER_SIZE,
    RECEIVED_TIMESTAMP_STRUCT,
    SocketcanBus,
    build_can_frame,
    dissect_can_frame,
)

from dbc.runtime.busio import bare_message

_DONTWAIT = socket.MSG_DONTWAIT
_DONTROUTE = socket.MSG_DONTROUTE
_SOL_SOCKET = socket.SOL_SOCKET
_SO_TIMESTAMPNS = constants.SO_TIMESTAMPNS
_CANFD_MTU = constants.CANFD_MTU
_EFF, _RTR, _ERR = constants.CAN_EFF_FLAG, constants.CAN_RTR_FLAG, constants.CAN_ERR_FLAG
_BRS, _ESI = constants.CANFD_BRS, constants.CANFD_ESI
_unpack_ts = RECEIVED_TIMESTAMP_STRUCT.unpack_from


def frame_message(
    cf: bytes, ancillary: list[tuple[int, int, bytes]], msg_flags: int, channel: Any
) -> can.Message:
    """The python-can message of one ``recvmsg()`` result on a CAN_RAW socket.

    The fields python-can's ``capture_message`` gives it: the ID and flags from the frame
    (python-can's ``dissect_can_frame``), the kernel's receive time from ``SO_TIMESTAMPNS``,
    ``is_rx`` False for a frame this host sent (``MSG_DONTROUTE``).  Raises
    ``CanOperationError`` where the kernel gave no receive time (the socket was not
    python-can's) or an impossible one.
    """
    can_id, dlc, flags, data = dissect_can_frame(cf)
    for level, kind, cmsg in ancillary:
        if level == _SOL_SOCKET and kind == _SO_TIMESTAMPNS:
            sec, nsec = _unpack_ts(cmsg)
            if not 0 <= nsec < 1_000_000_000:
                raise can.CanOperationError(f"receive time's nanoseconds out of range: {nsec}")
            timestamp = sec + nsec * 1e-9
            break
    else:
        raise can.CanOperationError("a received frame without its SO_TIMESTAMPNS receive time")
    ext = bool(can_id & _EFF)
    remote = bool(can_id & _RTR)
    return bare_message(
        timestamp,
        can_id & (0x1FFFFFFF if ext else 0x7FF),
        ext,
        remote,
        bool(can_id & _ERR),
        channel,
        dlc,
        bytearray() if remote else bytearray(data),  # a remote frame carries none (python-can)
        len(cf) == _CANFD_MTU,
        not msg_flags & _DONTROUTE,
        bool(flags & _BRS),
        bool(flags & _ESI),
    )


class LeanSocketcanBus(SocketcanBus):
    """``SocketcanBus`` sending and receiving a frame with one system call (module doc)."""

    def _take(self) -> can.Message | None:
        """The frame at the head of the receive queue, or None if it is empty."""
        try:
            cf, anc, msg_flags, addr = self.socket.recvmsg(
                _CANFD_MTU, RECEIVED_ANCILLARY_BUFFER_SIZE, _DONTWAIT
            )
        except BlockingIOError:
            return None
        except OSError as error:
            raise can.CanOperationError(
                f"Error receiving: {error.strerror}", error.errno
            ) from error
        if self.channel == "":
            channel = addr[0] if isinstance(addr, tuple) else addr
        else:
            channel = self.channel
        return frame_message(cf, anc, msg_flags, channel)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        msg = self._take()
        if msg is not None or timeout == 0:
            return msg, self._is_filtered
        deadline = None if timeout is None else time.monotonic() + timeout
        left = timeout
        while True:
            try:
                ready = select.select([self.socket], [], [], left)[0]
            except OSError as error:  # python-can's words for a failed wait
                raise can.CanOperationError(
                    f"Failed to receive: {error.strerror}", error.errno
                ) from error
            if not ready:
                return None, self._is_filtered
            msg = self._take()
            if msg is not None:
                return msg, self._is_filtered
            if deadline is not None:  # readable, yet nothing queued: wait out the rest
                left = deadline - time.monotonic()
                if left <= 0.0:
                    return None, self._is_filtered

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """``BusABC.recv`` without its clock reads where the kernel filters (always, unless
        it refused the filters): one wait of ``timeout`` at most, as there."""
        if not self._is_filtered:
            return super().recv(timeout)
        msg, _ = self._recv_internal(timeout)
        return msg

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if timeout or (self.channel == "" and msg.channel):
            super().send(msg, timeout)  # a wait for room, or a frame addressed to a channel
            return
        data = build_can_frame(msg)
        try:
            sent = self.socket.send(data, _DONTWAIT)
        except BlockingIOError:  # no room in the socket's send buffer: python-can's words
            raise can.CanOperationError("Transmit buffer full") from None
        except OSError as error:
            raise can.CanOperationError(
                f"Failed to transmit: {error.strerror}", error.errno
            ) from error
        if sent != len(data):  # a CAN_RAW socket sends a frame whole or not at all
            raise can.CanOperationError(f"Failed to transmit: {sent} of {len(data)} bytes sent")
