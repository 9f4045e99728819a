"""Replay of a recorded log: offline verification of a controller against the recorded frames
(:mod:`~tools.replay.verify`), re-transmission on a bus (:mod:`~tools.replay.retransmit`),
what-if runs (:mod:`~tools.replay.whatif`), the summary recomputed from the log alone
(:mod:`~tools.replay.summarize`) and the log served to a live view (:mod:`~tools.replay.serve`).
``wheelchair-hil replay`` and ``summarize`` (tools/cli/) are their commands."""

from dbc.runtime.errors import WheelchairError


class ReplayError(WheelchairError):
    """The log cannot be replayed as asked."""
