"""What a frame costs the codec and a tick record the controller's log (``codec_us``,
``telemetry_log_us``)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

from controller.telemetry import TICK_TOPIC, ForkedTelemetry, McapTelemetry
from dbc.codec import (
    Codec,
    EncoderEstimates,
    Node,
    SetInputVelAuth,
    TruthPose,
)
from tools.perf.common import per_call_us


def loop_costs(calls: int) -> dict[str, Any]:
    """What a frame costs the codec, and what a tick's record costs the loop to log.

    ``codec_us[message]``: encode and decode of one frame (``Get_Encoder_Estimates`` takes
    the whole-byte ``struct`` path, the authenticated setpoint the same path, the
    ground-truth pose scaled 24-bit signals); ``telemetry_log_us``: the CPU time of
    ``log()`` of a tick record in the loop (``McapTelemetry``) and shipped to a forked
    writer (``ForkedTelemetry``), the mean over all calls, shipping included.  CPU time,
    because called back to back the writer cannot keep up and the pipe makes the loop
    wait (flow control); at one record per tick it keeps up.
    """

    codec = Codec.default()
    codec_us: dict[str, dict[str, float]] = {}
    for name, payload, node in (
        ("Get_Encoder_Estimates", EncoderEstimates(12.5, -0.75), Node.LEFT),
        ("Set_Input_Vel_Auth", SetInputVelAuth(1.25, 1.5, 3, 0xDEADBEEF), Node.LEFT),
        ("Bench_Truth_Pose", TruthPose(12.345, -6.789, 1.2345), None),
    ):
        msg = codec.encode(payload, node)
        codec_us[name] = {
            "encode": per_call_us(lambda p=payload, n=node: codec.encode(p, n), calls),
            "decode": per_call_us(lambda m=msg: codec.decode(m), calls),
        }
    record = {
        "route_time_s": 12.34,
        "ref": {k: 0.1 * i for i, k in enumerate(("x", "y", "heading", "v", "omega", "a"))},
        "est": {k: 0.2 * i for i, k in enumerate(("x", "y", "heading", "v", "omega"))},
        "err": {"x_e": 0.01, "y_e": -0.02, "phi_e": 0.003},
        "cmd_raw": {"v": 0.5, "omega": 0.1},
        "cmd": {"v": 0.45, "omega": 0.1, "wheel_left_radps": 1.4, "wheel_right_radps": 1.6},
        "step_us": 8.2,
        "internals": {"s1": 0.3, "bank.p_nominal": 0.9},
        "diagnosis": {"hypothesis": "NOMINAL", "probability": 0.97, "radius_left": 0.3},
    }
    tel_us: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="whil-bench-tel-") as tmp:
        for label, cls in (("in_loop", McapTelemetry), ("forked", ForkedTelemetry)):
            tel: Any = cls(Path(tmp) / f"{label}.mcap")
            k = iter(range(10**9))
            tel_us[label] = per_call_us(
                lambda t=tel, k=k: t.log(TICK_TOPIC, next(k) * 10_000_000, record),
                calls // 4,
                clock=time.thread_time_ns,
            )
            tel.close()
    return {"codec_us": codec_us, "telemetry_log_us": tel_us}
