"""A run's bus frames for its summary, collected in the run's own process, with no log.

An evaluation's Monte-Carlo replicates need a run's figures, not its log: writing every frame
to MCAP (in a forked writer), merging the controller's log into it and reading it all back
took a third of such a run's time.  :class:`FrameCollector` joins the run's virtual channel
as a listener (python-can's virtual bus hands it every frame in bus order, as it does the
recorder's :class:`~tools.logs.bustap.ChannelTap`), stamps each frame with the log time the
recorder would give it (:class:`~tools.logs.recorder.LogClock`), counts what the recorder
counts (frames, bits, missed steps) and decodes, through the DBC codec, only the messages a
summary reads (:data:`tools.metrics.tracking.SUMMARY_MESSAGES`) into a
:class:`~tools.metrics.tracking.BusCollector`, as the summary would read them from the log.
Those frames are kept as bytes while the run goes and decoded as whole columns when it ends
(:meth:`~dbc.codec.Codec.decode_columns`, the same values as frame by frame).  Nothing raises
in the sender's thread: a frame that does not decode is counted by reason.
"""

from __future__ import annotations

from collections.abc import Iterable

import can
import numpy as np

from dbc.codec import BenchEnd, Codec
from dbc.runtime import jsonsafe
from tools.bus.busload import frame_bits
from tools.logs.bustap import join_channel, leave_channel
from tools.logs.recorder import LogClock, RecorderStats
from tools.metrics.tracking import SUMMARY_MESSAGES, BusCollector


class FrameCollector:
    """Collect virtual channel ``channel``'s frames for a summary (see the module doc).

    Call :meth:`start` before the first frame and :meth:`stop` after the last; then
    :attr:`series` holds the decoded messages and :attr:`stats` the recorder's counts.
    """

    def __init__(
        self,
        channel: str,
        *,
        lockstep: bool,
        codec: Codec | None = None,
        names: Iterable[str] = SUMMARY_MESSAGES,
    ) -> None:
        self.channel = channel
        self.codec = codec or Codec.default()
        self.stats = RecorderStats()
        self.clock = LogClock(self.codec, lockstep, on_missed=self._missed)
        self.series = BusCollector()
        self._end_id = self.codec.frame_id(BenchEnd)
        wanted = set(names)
        #: (arbitration id, extended) -> (payload length, log times, payloads back to back) of
        #: the messages to decode, each decoded as one column when the run ends
        self._kept: dict[tuple[int, bool], tuple[int, list[int], bytearray]] = {}
        for m in self.codec.db.messages:
            if m.name in wanted:
                self._kept[(m.frame_id, bool(m.is_extended_frame))] = (m.length, [], bytearray())
        self._bits: dict[tuple[int, bool], int] = {}

    def start(self) -> None:
        join_channel(self.channel, self)

    def stop(self) -> RecorderStats:
        """Leave the channel and decode what was kept into :attr:`series`; returns the
        counts (as the recorder's statistics)."""
        leave_channel(self.channel, self)
        st = self.stats
        st.ended_by = st.ended_by or "stopped"
        for key, (_length, times, payloads) in self._kept.items():
            if not times:
                continue
            name, cols, ok, rejected = self.codec.decode_columns(key, bytes(payloads), len(times))
            st.rejected.update(rejected)
            t = np.asarray(times, dtype=np.int64)
            self.series.columns[name] = {"t": t if ok.all() else t[ok], **cols}
            st.decoded += len(times) - sum(rejected.values())
            st.by_name[name] += len(times) - sum(rejected.values())
            times.clear()
            payloads.clear()
        return st

    def _missed(self, missed: int, event_ns: int, step_ns: int) -> None:
        self.stats.missed_steps += missed

    def put(self, msg: can.Message, block: bool = True, timeout: float | None = None) -> None:
        """Take one frame (a plain python-can virtual bus sends its copy here)."""
        self.take(msg, msg.timestamp)

    def take(self, msg: can.Message, timestamp: float) -> None:
        """Take one frame as sent at ``timestamp`` (our virtual bus calls this; no copy made)."""
        st = self.stats
        ext = msg.is_extended_id
        aid = msg.arbitration_id
        clock = self.clock
        special = ext and aid in clock.clock_ids  # a step, an ack, the ground truth
        if special:
            log_ns = clock.stamp(msg, int(timestamp * 1e9))
        else:
            log_ns = clock.sim_ns if clock.lockstep else int(timestamp * 1e9)
        st.frames += 1
        size = (len(msg.data), ext)
        bits = self._bits.get(size)
        if bits is None:
            bits = self._bits[size] = frame_bits(*size)
        st.bits += bits
        if st.first_ns is None:
            st.first_ns = log_ns
        st.last_ns = log_ns
        kept = self._kept.get((aid, ext))
        if kept is not None and not msg.is_remote_frame:
            length, times, payloads = kept
            data = msg.data
            if msg.is_error_frame:
                st.rejected["error_frame"] += 1
            elif len(data) != length or msg.dlc != length:
                st.rejected["length"] += 1
            else:
                times.append(log_ns)
                payloads += data
        if special:
            clock.acked(msg)
        if ext and aid == self._end_id and not st.ended_by:
            st.ended_by = "Bench_End"

    def metadata(self) -> dict[str, str]:
        """The ``recorder`` metadata record of these counts (``decoded`` and ``by_name``
        count the collected messages only)."""
        md = {k: jsonsafe.dumps(v) for k, v in self.stats.as_dict().items()}
        md["lockstep"] = str(self.clock.lockstep)
        return md
