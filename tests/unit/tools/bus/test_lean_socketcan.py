"""The stack's SocketCAN bus without a kernel: one system call a frame, python-can's errors.

A fake socket stands for the kernel's CAN_RAW socket (this host has no AF_CAN); the frames and
errors against the real kernel are ``tests/hil/socketcan/test_lean_bus.py``'s, in the guest.
"""

from __future__ import annotations

import errno
import socket
import struct
from typing import Any

import can
import pytest
from can.interfaces.socketcan import constants
from can.interfaces.socketcan.socketcan import capture_message

from tools.bus.lean_socketcan import LeanSocketcanBus, frame_message
from tools.bus.transport import profile

TS = struct.Struct("@ll")


class FakeSocket:
    """Records the calls; ``recv`` holds what each ``recvmsg`` returns (or raises)."""

    def __init__(self, recv: list[Any] | None = None, send: Any = None) -> None:
        self.calls: list[tuple[str, Any]] = []
        self.recv = list(recv or [])
        self.send_result = send

    def recvmsg(self, *args: Any) -> Any:
        self.calls.append(("recvmsg", args))
        r = self.recv.pop(0) if self.recv else BlockingIOError(errno.EAGAIN, "again")
        if isinstance(r, BaseException):
            raise r
        return r

    def send(self, data: bytes, *flags: int) -> int:
        self.calls.append(("send", flags))
        if isinstance(self.send_result, BaseException):
            raise self.send_result
        return len(data)


def _bus(sock: FakeSocket, channel: str = "vcan0") -> LeanSocketcanBus:
    bus: LeanSocketcanBus = object.__new__(LeanSocketcanBus)
    bus.socket = sock  # type: ignore[assignment]
    bus.channel = channel
    bus._is_filtered = True
    return bus


def _raw(can_id: int, data: bytes, fd: bool = False, flags: int = 0, sec: int = 1_700_000_000):
    size = constants.CANFD_MTU if fd else 16  # struct canfd_frame, struct can_frame
    cf = struct.pack("=IBBBB", can_id, len(data), flags, 0, 0) + data.ljust(size - 8, b"\0")
    anc = [(socket.SOL_SOCKET, constants.SO_TIMESTAMPNS, TS.pack(sec, 123_456_789))]
    return cf, anc, 0, ("vcan0",)


CASES = [
    _raw(0x123, b"\x01\x02"),
    _raw(0x1ABCDEF | constants.CAN_EFF_FLAG, bytes(8)),
    _raw(0x7FF | constants.CAN_RTR_FLAG, bytes(8)),
    _raw(0x4 | constants.CAN_ERR_FLAG, bytes(8)),
    _raw(0x18FF00 | constants.CAN_EFF_FLAG, bytes(range(64)), fd=True, flags=constants.CANFD_BRS),
    _raw(0x100, bytes(range(12)), fd=True, flags=constants.CANFD_BRS | constants.CANFD_ESI),
]


@pytest.mark.parametrize("raw", CASES, ids=["std", "ext", "rtr", "err", "fd-brs", "fd-esi"])
def test_a_received_frame_is_the_message_python_can_makes_of_it(raw: Any) -> None:
    ref = capture_message(FakeSocket([raw]), get_channel=True)  # type: ignore[arg-type]
    assert ref is not None
    mine = frame_message(raw[0], raw[1], raw[2], "vcan0")
    fields = [f for f in ref.__slots__ if not f.startswith("_")]
    assert [getattr(mine, f) for f in fields] == [getattr(ref, f) for f in fields]


def test_a_receive_takes_one_call_when_a_frame_is_queued_and_none_when_the_queue_is_empty() -> None:
    sock = FakeSocket([CASES[0]])
    bus = _bus(sock)
    assert bus.recv(0.0) is not None and [c[0] for c in sock.calls] == ["recvmsg"]
    assert sock.calls[0][1][2] == socket.MSG_DONTWAIT
    assert bus.recv(0.0) is None and len(sock.calls) == 2


def test_a_frame_without_its_receive_time_is_an_error_not_a_guess() -> None:
    cf, _anc, flags, addr = CASES[0]
    with pytest.raises(can.CanOperationError, match="SO_TIMESTAMPNS"):
        _bus(FakeSocket([(cf, [], flags, addr)])).recv(0.0)


def test_send_is_one_non_blocking_call_and_fails_with_python_cans_words() -> None:
    msg = can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False)
    sock = FakeSocket()
    _bus(sock).send(msg)
    assert sock.calls == [("send", (socket.MSG_DONTWAIT,))]
    with pytest.raises(can.CanOperationError, match="Transmit buffer full"):
        _bus(FakeSocket(send=BlockingIOError(errno.EAGAIN, "again"))).send(msg)
    down = OSError(errno.ENETDOWN, "Network is down")
    with pytest.raises(can.CanOperationError, match="Failed to transmit: Network is down") as info:
        _bus(FakeSocket(send=down)).send(msg)
    assert info.value.error_code == errno.ENETDOWN
    with pytest.raises(can.CanOperationError, match="Error receiving: Network is down") as info:
        _bus(FakeSocket([down])).recv(0.0)
    assert info.value.error_code == errno.ENETDOWN


def test_the_stack_opens_socketcan_with_the_lean_bus() -> None:
    assert profile("socketcan").opener is LeanSocketcanBus
