"""The stack's SocketCAN bus (``tools.bus.lean_socketcan``) against python-can's, on vcan0.

Every kind of frame the stack, a drive or a foreign node can put on a CAN bus (standard and
extended IDs, remote frames, error frames, every length, CAN FD with and without bit-rate
switch and error-state flag) is sent by one bus and received by both a lean and a python-can
bus with the same filters: the two receive the same frames with every field the same,
receive times included.  What the lean bus sends, python-can receives unchanged.  With the
interface down both fail with the same errno (what ``controller.link`` names the interface
by), and a receive on an empty queue returns None at once.
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import can
import pytest
from can.interfaces.socketcan.socketcan import SocketcanBus

from tools.bus.lean_socketcan import LeanSocketcanBus

pytestmark = pytest.mark.hil

FIELDS = (
    "timestamp",
    "arbitration_id",
    "is_extended_id",
    "is_remote_frame",
    "is_error_frame",
    "channel",
    "dlc",
    "data",
    "is_fd",
    "is_rx",
    "bitrate_switch",
    "error_state_indicator",
)


def _frames(fd: bool) -> list[can.Message]:
    out = []
    for n in range(9):
        out.append(
            can.Message(arbitration_id=0x100 + n, data=bytes(range(n)), is_extended_id=False)
        )
        out.append(can.Message(arbitration_id=0x1ABC0000 + n, data=bytes([0xFF] * n)))
    out.append(can.Message(arbitration_id=0x7FF, is_remote_frame=True, dlc=8, is_extended_id=False))
    out.append(can.Message(arbitration_id=0x1FFFFFFF, is_remote_frame=True, dlc=3))
    out.append(
        can.Message(arbitration_id=0x4, is_error_frame=True, data=bytes(8), is_extended_id=False)
    )
    if fd:
        for n in (12, 16, 20, 24, 32, 48, 64):
            for brs, esi in ((False, False), (True, False), (True, True)):
                out.append(
                    can.Message(
                        arbitration_id=0x18FF0000 + n,
                        data=bytes(range(n)),
                        is_fd=True,
                        bitrate_switch=brs,
                        error_state_indicator=esi,
                    )
                )
    return out


def _view(m: can.Message) -> tuple[object, ...]:
    return tuple(getattr(m, f) for f in FIELDS)


def _drain(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (m := bus.recv(0.5)) is not None:
        out.append(m)
    return out


def _fd_capable() -> bool:
    return int(Path("/sys/class/net/vcan0/mtu").read_text()) == 72  # CANFD_MTU


@pytest.mark.parametrize("sender", ["python-can", "lean"])
def test_the_lean_bus_receives_and_sends_what_python_cans_does(sender: str) -> None:
    fd = _fd_capable()
    opts = {"channel": "vcan0", "fd": fd, "receive_own_messages": False}
    filters = [
        {"can_id": 0, "can_mask": 0, "extended": False},
        {"can_id": 0, "can_mask": 0, "extended": True},
    ]
    tx_cls = SocketcanBus if sender == "python-can" else LeanSocketcanBus
    with (
        tx_cls(**opts) as tx,
        LeanSocketcanBus(**opts, can_filters=filters) as lean,
        SocketcanBus(**opts, can_filters=filters) as ref,
    ):
        # error frames are delivered only to sockets that ask for them
        for b in (lean, ref):
            b.socket.setsockopt(
                can.interfaces.socketcan.constants.SOL_CAN_RAW,
                can.interfaces.socketcan.constants.CAN_RAW_ERR_FILTER,
                0x1FFFFFFF,  # CAN_ERR_MASK: every error class
            )
        sent = _frames(fd)
        for m in sent:
            tx.send(m)
        got_lean, got_ref = _drain(lean), _drain(ref)
    assert len(got_ref) == len(sent), "python-can's bus did not receive every frame"
    assert [_view(m) for m in got_lean] == [_view(m) for m in got_ref]
    for m, s in zip(got_ref, sent, strict=True):  # and they are the frames sent
        assert (m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.is_fd) == (
            s.arbitration_id,
            s.is_extended_id,
            s.is_remote_frame,
            s.is_fd,
        )
        assert m.data == s.data and m.bitrate_switch == s.bitrate_switch


def test_an_empty_queue_returns_none_at_once_and_a_wait_waits() -> None:
    with LeanSocketcanBus(channel="vcan0") as bus:
        t0 = time.monotonic()
        assert bus.recv(0.0) is None
        assert bus.recv(0.2) is None
        assert time.monotonic() - t0 >= 0.2


def test_with_the_interface_down_both_buses_fail_with_the_same_errno() -> None:
    lean, ref = LeanSocketcanBus(channel="vcan0"), SocketcanBus(channel="vcan0")
    msg = can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False)
    errs: dict[str, list[int | None]] = {"lean": [], "ref": []}
    try:
        subprocess.run(["ip", "link", "set", "vcan0", "down"], check=True)
        for name, bus in (("lean", lean), ("ref", ref)):
            with pytest.raises(can.CanOperationError) as info:
                bus.send(msg)
            errs[name].append(info.value.error_code)
            assert "Failed to transmit" in str(info.value)
    finally:
        subprocess.run(["ip", "link", "set", "vcan0", "up"], check=True)
        lean.shutdown()
        ref.shutdown()
    assert errs["lean"] == errs["ref"] and errs["lean"][0] is not None
