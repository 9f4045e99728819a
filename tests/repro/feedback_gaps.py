"""Real-time staleness (docs/safety.md "Staleness is the drives', not the host's"): did the drives' feedback really stop, or was the host late?

    python -m tests.repro.feedback_gaps RUNDIR [RUNDIR ...]

For each run directory: the controller's stop, the bench's late steps, and the three
longest gaps between the left drive's Get_Encoder_Estimates frames as the recorder's
socket received them (kernel receive timestamps, independent of any process's lateness).
"""

from __future__ import annotations

import itertools
import json
import sys
import warnings
from pathlib import Path

from dbc.codec import Codec, EncoderEstimates, Node
from tools.logs.mcap_io import iter_frames


def main() -> int:
    lid = Codec.default().frame_id(EncoderEstimates, Node.LEFT)
    for d in sys.argv[1:]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ts = [
                m.timestamp
                for _t, m in iter_frames(d + "/run.mcap", timestamps="receive")
                if m.arbitration_id == lid and not m.is_extended_id
            ]
        gaps = sorted((b - a) * 1e3 for a, b in itertools.pairwise(ts))
        ctl = json.loads(Path(d, "controller_stats.json").read_text())
        bench = json.loads(Path(d, "bench_stats.json").read_text())
        print(
            d, ctl["stop_reason"], ctl["stop_detail"][:48], "| bench late steps", bench.get("overruns"),
            "| longest encoder gaps at the recorder (ms):", [round(g, 1) for g in gaps[-3:]],
        )  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
