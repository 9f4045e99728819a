"""The recorder of a one-process run, writing from a process of its own.

On ``--bus virtual`` the bench, the controller and the recorder share one interpreter
and its lock, so whatever the recorder spends on a frame (decoding it, formatting the
raw and decoded JSON, compressing chunks) is time the lock-step loop waits for, although
the machine has a second core.  :class:`ChannelTap` moves that work there:

* it joins the virtual channel as a listener: python-can's virtual buses hand every
  frame to each listener's ``put`` (ours to its ``take``, without copying the frame
  first), so the tap sees every frame in the order it was sent, from any thread, and
  never receives or wakes a thread;
* it keeps only the frame's fields and ships them in batches through a pipe to a writer
  process forked when the tap starts (:class:`dbc.runtime.forked.ForkedWriter`);
* the writer rebuilds each frame and gives it to :class:`~tools.logs.recorder.FrameLog`,
  the same code the recorder thread runs, so the log has the same channels, stamps and
  sequence numbers (the one difference: no ``Bench_Record_Ack`` frames, which only
  exist for a recorder that can fall behind a lock-step bench; here the pipe is the
  flow control, a full pipe blocks the sender until the writer has caught up).

Nothing raises in a sender's thread: if the writer dies, frames are counted as lost
and :meth:`ChannelTap.stop` reports it.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import can
from can.interfaces.virtual import channels as virtual_channels
from can.interfaces.virtual import channels_lock as virtual_channels_lock

from dbc.codec import BenchEnd, Codec
from dbc.runtime.forked import ForkedWriter, ForkedWriterError
from dbc.runtime.mcapwriter import Mirror
from tools.logs.recorder import BusRecorder, RecorderStats

log = logging.getLogger(__name__)

#: How long :meth:`ChannelTap.stop` waits for the writer to write the rest and close the log.
_CLOSE_TIMEOUT_S = 120.0

#: A frame as shipped: timestamp, id, extended, remote, error, FD, DLC, payload.
Frame = tuple[float, int, bool, bool, bool, bool, int, bytes]

#: The tap's writer process failed or could not be started.
TapError = ForkedWriterError


def join_channel(channel: str, listener: Any) -> None:
    """Make ``listener`` (with a ``take(msg, timestamp)``) a member of virtual channel
    ``channel``: every frame sent there from now on reaches its ``take``."""
    with virtual_channels_lock:
        members: list[Any] = virtual_channels.setdefault(channel, [])
        members.append(listener)


def leave_channel(channel: str, listener: Any) -> None:
    """Undo :func:`join_channel` (the channel goes when its last member leaves)."""
    with virtual_channels_lock:
        members: list[Any] = virtual_channels.get(channel, [])
        if listener in members:
            members.remove(listener)
        if not members:
            virtual_channels.pop(channel, None)


class ChannelTap:
    """Record every frame of virtual channel ``channel`` into ``path`` from a forked writer.

    ``attachments`` and ``metadata`` go into the log as :class:`~tools.logs.recorder.BusRecorder`
    writes them.  Call :meth:`start` before the first frame and :meth:`stop` after the last.
    """

    def __init__(
        self,
        channel: str,
        path: str | Path,
        *,
        lockstep: bool,
        codec: Codec | None = None,
        attachments: Mapping[str, bytes] | None = None,
        metadata: Mapping[str, Mapping[str, str]] | None = None,
        batch: int = 256,
        mirror: Mirror | None = None,
    ) -> None:
        self.channel = channel
        #: sees every message of the log, in the writer process (a live view's feed)
        self.mirror = mirror
        self.path = Path(path)
        self.lockstep = lockstep
        self.codec = codec or Codec.default()
        self.attachments = dict(attachments or {})
        self.metadata = {k: dict(v) for k, v in (metadata or {}).items()}
        self.writer = ForkedWriter(
            f"recording {self.path}",
            self._open_sink,
            batch=batch,
            close_timeout_s=_CLOSE_TIMEOUT_S,
        )
        self._put = self.writer.put

    @property
    def lost(self) -> int:
        """Frames not recorded because the writer died."""
        return self.writer.lost

    def _open_sink(self) -> _TapSink:  # runs in the writer process
        return _TapSink(self)

    # ----------------------------------------------------------------- control

    def start(self) -> None:
        """Fork the writer and join the channel; :class:`TapError` if that fails."""
        self.writer.start()
        join_channel(self.channel, self)

    def stop(self) -> RecorderStats:
        """Leave the channel, write the rest and close the log; returns the recorder's statistics.

        Raises :class:`TapError` if the writer failed (the log ends where it stopped).
        """
        leave_channel(self.channel, self)
        stats = self.writer.stop()
        if not isinstance(stats, RecorderStats):
            raise TapError(f"recording {self.path} failed: no statistics")
        return stats

    # ------------------------------------------------------- the channel's side

    def put(self, msg: can.Message, block: bool = True, timeout: float | None = None) -> None:
        """Take one frame (a plain python-can virtual bus sends its copy here)."""
        self.take(msg, msg.timestamp)

    def take(self, msg: can.Message, timestamp: float) -> None:
        """Take one frame as sent at ``timestamp`` (our virtual bus calls this; no copy made)."""
        self._put(
            (
                timestamp,
                msg.arbitration_id,
                msg.is_extended_id,
                msg.is_remote_frame,
                msg.is_error_frame,
                msg.is_fd,
                msg.dlc,
                bytes(msg.data),
            )
        )


class _TapSink:
    """The writer process's side: shipped frames into :class:`~tools.logs.recorder.FrameLog`."""

    def __init__(self, tap: ChannelTap) -> None:
        self.rec = BusRecorder(
            None,  # type: ignore[arg-type]  # frames come through the pipe, not from a bus
            tap.path,
            lockstep=tap.lockstep,
            codec=tap.codec,
            attachments=tap.attachments,
            metadata=tap.metadata,
            mirror=tap.mirror,
        )
        self.channel = tap.channel
        self.end_id = tap.codec.frame_id(BenchEnd)

    def take(self, frames: list[Frame]) -> None:
        record = self.rec.frames.record
        stats = self.rec.stats
        message = can.Message
        for ts, aid, ext, rtr, error, fd, dlc, data in frames:
            record(
                message(
                    timestamp=ts,
                    arbitration_id=aid,
                    is_extended_id=ext,
                    is_remote_frame=rtr,
                    is_error_frame=error,
                    is_fd=fd,
                    dlc=dlc,
                    data=data,
                    channel=self.channel,
                    is_rx=True,
                )
            )
            if ext and aid == self.end_id and not stats.ended_by:
                stats.ended_by = "Bench_End"

    def close(self) -> RecorderStats:
        stats = self.rec.stats
        stats.ended_by = stats.ended_by or "stopped"
        self.rec.close()
        return stats
