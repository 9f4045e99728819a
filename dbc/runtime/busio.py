"""Receiving from a python-can bus: against the monotonic clock, and without dying on a bad frame.

Used by the controller's loop, the bench, the bus-fault wrapper and the tools.  A receive
path must survive any input: a datagram that does not unpack into a CAN frame (python-can's
udp_multicast raises ``CanOperationError("could not unpack received message")`` for a DLC 0
frame with 8 data bytes, a 12-byte classic frame or bytes that are not msgpack), or any
other error of the interface, is dropped and counted by reason (:func:`rx_reason`), and
the caller goes on.
"""

from __future__ import annotations

import errno
import time
from collections.abc import MutableMapping

import can

#: Reasons a receive was dropped (keys of the counters the callers keep).
RX_INVALID_FRAME = "rx_invalid_frame"  # unpacked, but python-can's Message check refused it
RX_BAD_FIELDS = "rx_bad_fields"  # unpacked to fields that are no Message's
RX_UNDECODABLE = "rx_undecodable"  # not a python-can datagram at all (not msgpack, not a map)
RX_BUS_ERROR = "rx_bus_error"  # any other python-can error of the interface
#: A bus-level failure (not a bad frame): the caller backs off this long before retrying.
_BACKOFF_S = 0.005

_new = object.__new__


def bare_message(
    timestamp: float,
    arbitration_id: int,
    is_extended_id: bool,
    is_remote_frame: bool,
    is_error_frame: bool,
    channel: can.typechecking.Channel | None,
    dlc: int,
    data: bytearray,
    is_fd: bool,
    is_rx: bool,
    bitrate_switch: bool,
    error_state_indicator: bool,
) -> can.Message:
    """``can.Message(...)`` of these values (the constructor's parameters, in its order), its
    slots set directly: a third of the constructor's time, for frames that are frames already
    (built from the DBC's own ID and length, or copies of a sent one), so nothing to check.
    ``data`` is kept as given (the constructor keeps a ``bytearray`` too; a remote frame's
    must be empty)."""
    msg: can.Message = _new(can.Message)
    msg.timestamp = timestamp
    msg.arbitration_id = arbitration_id
    msg.is_extended_id = is_extended_id
    msg.is_remote_frame = is_remote_frame
    msg.is_error_frame = is_error_frame
    msg.channel = channel
    msg.is_fd = is_fd
    msg.is_rx = is_rx
    msg.bitrate_switch = bitrate_switch
    msg.error_state_indicator = error_state_indicator
    msg.data = data
    msg.dlc = dlc
    return msg


def receive_ns(msg: can.Message | None) -> int:
    """A received frame's receive time in ns of the wall clock (0: none known)."""
    if msg is None or not msg.timestamp:
        return 0
    return round(msg.timestamp * 1e9)


def os_errno(err: BaseException) -> int | None:
    """The errno behind a bus error: an OSError's, the OSError python-can wrapped (SocketCAN
    raises ``CanOperationError(..., errno) from OSError``), or a CanError's ``error_code``."""
    if isinstance(err, OSError):
        return err.errno
    if isinstance(err.__cause__, OSError):
        return err.__cause__.errno
    code = getattr(err, "error_code", None) if isinstance(err, can.CanError) else None
    return code if isinstance(code, int) else None


def _os_reason(code: int | None) -> str:
    return f"rx_os_error_{errno.errorcode.get(code or 0, 'unknown')}"


def rx_reason(err: BaseException) -> str:
    """The counter key for a receive that failed with ``err``.

    An interface error that carries an OS error (SocketCAN's ``Error receiving: Network is
    down`` when the interface went down) is named by its errno, ``rx_os_error_ENETDOWN``:
    it is the bus failing, not a bad frame.
    """
    if isinstance(err, can.CanError):
        cause = err.__cause__
        if isinstance(cause, OSError):
            return _os_reason(os_errno(err))
        if "unpack" in str(err) or cause is not None:
            if cause is not None and type(cause).__module__.startswith("msgpack"):
                return RX_UNDECODABLE  # msgpack's errors are ValueErrors too
            if isinstance(cause, ValueError):
                return RX_INVALID_FRAME
            if isinstance(cause, TypeError):
                return RX_BAD_FIELDS
            return RX_UNDECODABLE
        return RX_BUS_ERROR
    if isinstance(err, OSError):
        return _os_reason(os_errno(err))
    if isinstance(err, (ValueError, TypeError, KeyError)):  # an interface that did not wrap it
        return RX_INVALID_FRAME
    return "rx_internal"


def _frame_level(reason: str) -> bool:
    return reason in (RX_INVALID_FRAME, RX_BAD_FIELDS, RX_UNDECODABLE)


def recv_monotonic(bus: can.BusABC, timeout: float | None) -> can.Message | None:
    """One receive that waits at most ``timeout`` seconds of the monotonic clock.

    python-can's ``BusABC.recv`` re-computes its remaining timeout from ``time.time()``,
    so a backward wall-clock step (NTP, an operator) during a wait on a silent bus
    stretches the wait by the size of the step.  Every interface implements
    ``_recv_internal`` against its own (monotonic) wait, so the loop calls it directly
    and applies the bus filters itself.  A frame the filters reject returns ``None``
    early; the caller's loop is driven by its own deadline anyway.  Errors propagate
    (see :func:`recv_dropping`).
    """
    msg, already_filtered = bus._recv_internal(timeout)
    if msg is None or already_filtered or bus._matches_filters(msg):
        return msg
    return None


def recv_dropping(
    bus: can.BusABC,
    timeout: float | None,
    dropped: MutableMapping[str, int],
    *,
    monotonic: bool = False,
) -> can.Message | None:
    """A receive that never raises: what fails to be a frame is counted in ``dropped``.

    ``monotonic=True`` waits against the monotonic clock (see :func:`recv_monotonic`).
    A bad frame, or one the bus filters reject, is dropped and the receive goes on
    within what is left of ``timeout``
    (with ``timeout=0``: on to the next datagram already queued), so a caller sees the
    good frames behind it exactly as if the bad one had never been sent.  A failure of
    the bus itself (an OS error, a closed socket) returns None after waiting a few
    milliseconds within ``timeout``, so that a broken bus does not spin a core.
    """
    # no clock read for a poll (timeout 0: nothing to wait out) or an endless wait
    deadline = time.monotonic() + timeout if timeout else None
    left = timeout
    while True:
        try:
            if not monotonic:
                return bus.recv(left)
            msg, already_filtered = bus._recv_internal(left)
            if msg is None or already_filtered or bus._matches_filters(msg):
                return msg
            # a frame the filters reject: go on receiving within the timeout
        except Exception as err:  # any input or interface failure: count it, go on
            reason = rx_reason(err)
            dropped[reason] = dropped.get(reason, 0) + 1
            if not _frame_level(reason):
                if left:
                    time.sleep(min(left, _BACKOFF_S))
                return None
        if deadline is not None:
            left = max(0.0, deadline - time.monotonic())
