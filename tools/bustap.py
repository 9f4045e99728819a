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
  process forked when the tap starts;
* the writer rebuilds each frame and gives it to :class:`~tools.recorder.FrameLog`,
  the same code the recorder thread runs, so the log has the same channels, stamps and
  sequence numbers (the one difference: no ``Bench_Record_Ack`` frames, which only
  exist for a recorder that can fall behind a lock-step bench; here the pipe is the
  flow control, a full pipe blocks the sender until the writer has caught up).

Nothing raises in a sender's thread: if the writer dies, frames are counted as lost
and :meth:`ChannelTap.stop` reports it.
"""

from __future__ import annotations

import logging
import multiprocessing
import threading
from collections.abc import Mapping
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import can
from can.interfaces.virtual import channels as virtual_channels
from can.interfaces.virtual import channels_lock as virtual_channels_lock

from dbc.codec import BenchEnd, Codec
from tools.recorder import BusRecorder, RecorderStats

log = logging.getLogger(__name__)

#: How long :meth:`ChannelTap.stop` waits for the writer to write the rest and close the log.
_CLOSE_TIMEOUT_S = 120.0

#: A frame as shipped: timestamp, id, extended, remote, error, FD, DLC, payload.
Frame = tuple[float, int, bool, bool, bool, bool, int, bytes]


class TapError(RuntimeError):
    """The tap's writer process failed or could not be started."""


class ChannelTap:
    """Record every frame of virtual channel ``channel`` into ``path`` from a forked writer.

    ``attachments`` and ``metadata`` go into the log as :class:`~tools.recorder.BusRecorder`
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
    ) -> None:
        self.channel = channel
        self.path = Path(path)
        self.lockstep = lockstep
        self.codec = codec or Codec.default()
        self.attachments = dict(attachments or {})
        self.metadata = {k: dict(v) for k, v in (metadata or {}).items()}
        self.batch = max(1, int(batch))
        self.lost = 0
        self._frames: list[Frame] = []
        self._lock = threading.Lock()
        self._conn: Connection | None = None
        self._proc: Any = None
        self._failed = ""

    # ----------------------------------------------------------------- control

    def start(self) -> None:
        """Fork the writer and join the channel; :class:`TapError` if fork is unavailable."""
        try:
            ctx = multiprocessing.get_context("fork")
        except ValueError as err:
            raise TapError(f"cannot fork a log writer on this platform: {err}") from err
        parent, child = ctx.Pipe(duplex=True)
        proc = ctx.Process(
            target=_writer_main,
            name="record",
            args=(
                child,
                self.path,
                self.channel,
                self.lockstep,
                self.codec,
                self.attachments,
                self.metadata,
            ),
            daemon=True,
        )
        try:
            proc.start()
        except (OSError, AssertionError) as err:  # AssertionError: a daemonic parent
            parent.close()
            child.close()
            raise TapError(f"cannot start the log writer process: {err}") from err
        child.close()
        try:
            ready = parent.recv()
        except (EOFError, OSError) as err:
            proc.join(5)
            raise TapError(f"the log writer process ended at start (exit {proc.exitcode})") from err
        if ready != "ready":
            proc.join(5)
            raise TapError(f"the log writer could not open {self.path}: {ready}")
        self._conn, self._proc = parent, proc
        with virtual_channels_lock:
            members: list[Any] = virtual_channels.setdefault(self.channel, [])
            members.append(self)

    def stop(self) -> RecorderStats:
        """Leave the channel, write the rest and close the log; returns the recorder's statistics.

        Raises :class:`TapError` if the writer failed (the log ends where it stopped).
        """
        with virtual_channels_lock:
            members: list[Any] = virtual_channels.get(self.channel, [])
            if self in members:
                members.remove(self)
            if not members:
                virtual_channels.pop(self.channel, None)
        with self._lock:
            self._ship()
            conn, self._conn = self._conn, None
        if conn is None:
            raise TapError(f"log writer for {self.path} was not running")
        stats: Any = None
        try:
            if not self._failed:
                conn.send(None)
                if conn.poll(_CLOSE_TIMEOUT_S):
                    stats = conn.recv()
                else:
                    self._failed = f"log writer did not finish within {_CLOSE_TIMEOUT_S:g} s"
                    self._proc.kill()
        except (EOFError, OSError) as err:
            self._failed = self._failed or f"log writer lost: {err!r}"
        finally:
            conn.close()
            self._proc.join(30)
        if isinstance(stats, str):
            self._failed = stats
        if self._failed or not isinstance(stats, RecorderStats):
            raise TapError(
                f"recording {self.path} failed: {self._failed or 'no statistics'}"
                + (f"; {self.lost} frame(s) not recorded" if self.lost else "")
            )
        return stats

    # ------------------------------------------------------- the channel's side

    def put(self, msg: can.Message, block: bool = True, timeout: float | None = None) -> None:
        """Take one frame (a plain python-can virtual bus sends its copy here)."""
        self.take(msg, msg.timestamp)

    def take(self, msg: can.Message, timestamp: float) -> None:
        """Take one frame as sent at ``timestamp`` (our virtual bus calls this; no copy made)."""
        frame = (
            timestamp,
            msg.arbitration_id,
            msg.is_extended_id,
            msg.is_remote_frame,
            msg.is_error_frame,
            msg.is_fd,
            msg.dlc,
            bytes(msg.data),
        )
        with self._lock:
            self._frames.append(frame)
            if len(self._frames) >= self.batch:
                self._ship()

    def _ship(self) -> None:
        frames, self._frames = self._frames, []
        if not frames:
            return
        if self._conn is None or self._failed:
            self.lost += len(frames)
            return
        try:
            self._conn.send(frames)
        except (OSError, ValueError) as err:  # the writer died: count, never raise here
            self._failed = f"log writer lost: {err!r}"
            self.lost += len(frames)
            log.error("recorder: %s; frames are no longer recorded", self._failed)


def _writer_main(
    conn: Connection,
    path: Path,
    channel: str,
    lockstep: bool,
    codec: Codec,
    attachments: dict[str, bytes],
    metadata: dict[str, dict[str, str]],
) -> None:
    """The writer process: frames from ``conn`` into the log until ``None``."""
    try:
        rec = BusRecorder(
            None,  # type: ignore[arg-type]  # frames come through the pipe, not from a bus
            path,
            lockstep=lockstep,
            codec=codec,
            attachments=attachments,
            metadata=metadata,
        )
    except Exception as err:
        conn.send(f"{type(err).__name__}: {err}")
        return
    conn.send("ready")
    record = rec.frames.record
    stats = rec.stats
    end_id = codec.frame_id(BenchEnd)
    message = can.Message
    try:
        while True:
            frames = conn.recv()
            if frames is None:
                break
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
                        channel=channel,
                        is_rx=True,
                    )
                )
                if ext and aid == end_id and not stats.ended_by:
                    stats.ended_by = "Bench_End"
        stats.ended_by = stats.ended_by or "stopped"
    except Exception as err:  # report it; what was written stays readable
        rec.close()
        conn.send(f"{type(err).__name__}: {err}")
        return
    rec.close()
    conn.send(stats)
