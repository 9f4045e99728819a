"""The controller's receive filters come from the DBC: no bench frame but its clock passes."""

from __future__ import annotations

import pytest

from controller.link import host_filters
from dbc.codec import BenchStep, Codec, EncoderEstimates, Node, TruthPose
from tools.bus.transport import open_bus, resolve


@pytest.mark.parametrize("lockstep", [True, False])
def test_ground_truth_never_reaches_a_filtered_controller_bus(lockstep: bool) -> None:
    codec = Codec.default()
    spec = resolve("virtual", f"host-filters-{lockstep}")
    with (
        open_bus(spec, can_filters=host_filters(codec, lockstep=lockstep)) as ctl,
        open_bus(spec) as bench,
    ):
        bench.send(codec.encode(TruthPose(1.0, 2.0, 0.5)))
        bench.send(codec.encode(BenchStep(10_000_000)))
        bench.send(codec.encode(EncoderEstimates(1.0, 0.5), Node.LEFT))
        got = []
        while (msg := ctl.recv(0.05)) is not None:
            got.append(codec.db.get_message_by_frame_id(msg.arbitration_id).name)
    assert got == (
        ["Bench_Step", "Left_Get_Encoder_Estimates"] if lockstep else ["Left_Get_Encoder_Estimates"]
    )


def test_the_filters_pass_every_frame_the_dbc_has_the_host_receive() -> None:
    codec = Codec.default()
    names = {
        codec.db.get_message_by_frame_id(f["can_id"]).name
        for f in host_filters(codec, lockstep=True)
    }
    wanted = {m.name for m in codec.db.messages if "Host" in m.receivers}
    assert names == wanted
    assert not any(n.startswith("Bench_Truth") for n in names)
