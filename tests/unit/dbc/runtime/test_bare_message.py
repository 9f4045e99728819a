"""dbc.runtime.busio.bare_message: python-can's constructor without its checks, every slot
alike; the codec's frames and the virtual bus's received copies are made with it."""

from __future__ import annotations

import can
import pytest

from dbc.codec import Codec, Node, SetInputVelAuth
from dbc.runtime.busio import bare_message
from tools.bus.transport import LightVirtualBus

SLOTS = [s for s in can.Message.__slots__ if s != "__weakref__"]


def _slots(msg: can.Message) -> dict[str, object]:
    return {s: getattr(msg, s) for s in SLOTS}


@pytest.mark.parametrize("remote", [False, True])
def test_every_slot_is_what_the_constructor_sets(remote: bool) -> None:
    data = bytearray() if remote else bytearray(b"\x01\x02\x03")
    args = (1.5, 0x29, True, remote, False, "vcan0", 3, data, False, False, True, True)
    names = ("timestamp", "arbitration_id", "is_extended_id", "is_remote_frame")
    names += ("is_error_frame", "channel", "dlc", "data", "is_fd", "is_rx", "bitrate_switch")
    names += ("error_state_indicator",)
    ours = bare_message(*args)
    theirs = can.Message(**dict(zip(names, args, strict=True)))
    assert set(names) == set(SLOTS)  # a slot python-can adds must be set here too
    assert _slots(ours) == _slots(theirs)
    assert ours.data is data  # kept, as the constructor keeps a bytearray


def test_the_codecs_frame_and_the_buses_copy_are_the_constructors() -> None:
    codec = Codec.default()
    sent = codec.encode(SetInputVelAuth(1.0, 1.0, 3, 12345), Node.LEFT)
    made = can.Message(
        arbitration_id=sent.arbitration_id, data=bytearray(sent.data), is_extended_id=False
    )
    assert _slots(sent) == _slots(made)
    a = LightVirtualBus("bare-message-test", preserve_timestamps=True)
    b = LightVirtualBus("bare-message-test")
    try:
        sent.timestamp = 7.25
        a.send(sent)
        got = b.recv(0)
        assert got is not None and got is not sent and got.data is not sent.data
        want = can.Message(
            timestamp=7.25, arbitration_id=sent.arbitration_id, is_extended_id=False,
            channel=b.channel_id, dlc=sent.dlc, data=bytearray(sent.data), is_rx=True,
        )  # fmt: skip
        assert _slots(got) == _slots(want)
    finally:
        a.shutdown()
        b.shutdown()
