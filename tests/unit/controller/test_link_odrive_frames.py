"""Every ODrive 0.6 frame a real drive sends reaches the controller's link as a valid frame:
what the controller reads updates its drive state, the rest is ignored and counted by name."""

from __future__ import annotations

from collections.abc import Iterator

import can
import pytest

from controller.link import DriveLink, host_filters
from dbc.codec import (
    Address,
    AxisError,
    AxisState,
    Codec,
    EncoderCount,
    GetError,
    Heartbeat,
    Node,
    Powers,
    Temperature,
    Torques,
    Version,
)

CODEC = Codec.default()
L, R = Node.LEFT, Node.RIGHT


@pytest.fixture
def link() -> Iterator[DriveLink]:
    bus = can.Bus(interface="virtual", channel="link-odrive", receive_own_messages=False)
    yield DriveLink(bus, CODEC)
    bus.shutdown()


def test_frames_the_host_does_not_use_are_ignored_and_counted_by_name(link: DriveLink) -> None:
    unused = [
        (Version(2, 4, 4, 58, 0, 6, 10, 0), L),
        (Address(2, 0x3A5E00000002), R),
        (Torques(0.5, 0.4), L),
        (Powers(120.0, 95.5), R),
        (Temperature(40.0, 35.0), L),
        (EncoderCount(1000, 200), R),
    ]
    for payload, node in unused:
        link.on_frame(CODEC.encode(payload, node))
    link.on_frame(CODEC.request(Torques, R))  # another tool polling a drive
    c = link.counters
    assert c.rejected == {}
    assert c.ignored == len(unused) + 1
    assert c.unused == {
        "Left_Get_Version": 1,
        "Right_Address": 1,
        "Left_Get_Torques": 1,
        "Right_Get_Powers": 1,
        "Left_Get_Temperature": 1,
        "Right_Get_Encoder_Count": 1,
        "RTR Right_Get_Torques": 1,
    }


def test_a_heartbeat_in_any_odrive_06_state_with_several_error_bits_is_read(
    link: DriveLink,
) -> None:
    bits = int(AxisError.WATCHDOG_TIMER_EXPIRED | AxisError.MISSING_INPUT)
    for state in (AxisState.SENSORLESS_CONTROL, AxisState.ANTICOGGING_CALIBRATION):
        link.on_frame(CODEC.encode(Heartbeat(bits, state), L))
        assert link.drives[L].axis_state == state
    link.on_frame(CODEC.encode(GetError(bits, bits), L))
    assert (link.drives[L].axis_error, link.drives[L].active_errors) == (bits, bits)
    assert link.counters.rejected == {} and link.counters.unused == {}


def test_the_host_receive_filters_pass_the_odrive_answers() -> None:
    passed = {f["can_id"] for f in host_filters(CODEC, lockstep=False)}
    for cls in (Version, Address, Torques, Powers):
        assert {CODEC.frame_id(cls, n) for n in (L, R)} <= passed
