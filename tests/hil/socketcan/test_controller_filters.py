"""The controller's socket is given kernel filters: no bench frame ever reaches it."""

from __future__ import annotations

import can
import pytest

from controller.link import host_filters
from dbc.codec import BenchStep, Codec, TruthPose

pytestmark = pytest.mark.hil


@pytest.mark.parametrize("lockstep", [True, False])
def test_the_kernel_keeps_ground_truth_from_the_controllers_socket(lockstep: bool) -> None:
    codec = Codec.default()
    filters = host_filters(codec, lockstep=lockstep)
    with (
        can.Bus(interface="socketcan", channel="vcan0", can_filters=filters) as ctl,
        can.Bus(interface="socketcan", channel="vcan0") as bench,
    ):
        bench.send(codec.encode(TruthPose(1.0, 2.0, 0.5)))
        bench.send(codec.encode(BenchStep(10_000_000)))
        got = []
        while (msg := ctl.recv(0.5)) is not None:
            got.append((msg.arbitration_id, msg.is_extended_id))
    step = (codec.frame_id(BenchStep), True)
    assert (codec.frame_id(TruthPose), True) not in got
    assert got == ([step] if lockstep else [])
