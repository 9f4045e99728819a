"""The writers' side of the live view: copy a log's messages to the view without waiting.

A :class:`LiveFeed` is a :class:`dbc.runtime.mcapwriter.Mirror`: given to a log's
:class:`~dbc.runtime.mcapwriter.LogWriter` (the recorder's :class:`~tools.logs.recorder.FrameLog`,
the controller's telemetry), it sees every schema, channel and message as the file gets it,
with the same names, schemas and bytes.  What it costs the writer is one append to a
bounded queue per message:

* the queue holds ``queue_size`` messages; when it is full the oldest is dropped and
  counted (:attr:`LiveFeed.dropped`): a slow or absent view loses old messages, never
  the writer's time;
* schemas and channels are never dropped (a handful per run), and always reach the view
  before the first message that uses them;
* a thread of the feed's own wakes every ``interval_s``, takes what is queued and sends it
  to the view process (:mod:`tools.live.view`) as msgpack datagrams on a Unix socket.
  If the view is slow the send waits at most ``send_timeout_s`` (the queue keeps dropping
  the oldest meanwhile); if it is gone, the batch is counted as dropped.

The feed starts its thread and opens its socket at its first schema, in the process that
writes the log: a feed handed to a forked writer (:class:`dbc.runtime.forked.ForkedWriter`)
runs there, not in the loop that forked it.  Nothing raises in the writer's thread.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading
from collections import deque
from typing import Any

import msgpack

log = logging.getLogger(__name__)

#: Datagram ops: a schema, a channel, a message (the first items of each op list).
OP_SCHEMA, OP_CHANNEL, OP_MESSAGE = 0, 1, 2
#: A datagram holds at most about this many bytes of payloads (Unix datagrams are
#: limited by the socket's send buffer, ~200 KiB by default).
DATAGRAM_BYTES = 48 * 1024
DEFAULT_QUEUE = 4096


class LiveFeed:
    """Mirror of one log writer into the view listening on ``socket_path`` (see the module doc)."""

    def __init__(
        self,
        socket_path: str,
        *,
        queue_size: int = DEFAULT_QUEUE,
        interval_s: float = 0.01,
        send_timeout_s: float = 0.25,
    ) -> None:
        if queue_size < 1:
            raise ValueError(f"live feed queue_size={queue_size}: must be at least 1")
        self.socket_path = socket_path
        self.queue_size = int(queue_size)
        self.interval_s = float(interval_s)
        self.send_timeout_s = float(send_timeout_s)
        #: messages pushed out of the full queue (oldest first), counted by the writer's thread
        self.dropped_full = 0
        #: messages the view could not take (too slow or gone), counted by the feed's thread
        self.dropped_send = 0
        #: messages handed to the view
        self.sent = 0
        self._queue: deque[tuple[int, int, bytes]] | None = None
        self._ctl: list[list[Any]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None
        self._pid = 0
        self._token = ""
        self._warned = False
        self._reported = 0  # the drop count the view last received

    @property
    def dropped(self) -> int:
        """Messages that did not reach the view (queue full, or the view did not take them)."""
        return self.dropped_full + self.dropped_send

    # ------------------------------------------------------------------ Mirror

    def schema(self, schema_id: int, name: str, encoding: str, data: bytes) -> None:
        self._started()
        with self._lock:
            self._ctl.append([OP_SCHEMA, schema_id, name, encoding, bytes(data)])

    def channel(self, channel_id: int, topic: str, message_encoding: str, schema_id: int) -> None:
        self._started()
        with self._lock:
            self._ctl.append([OP_CHANNEL, channel_id, topic, message_encoding, schema_id])

    def message(self, channel_id: int, log_time: int, data: bytes) -> None:
        q = self._queue
        if q is None:  # closed, or no channel yet
            return
        if len(q) >= self.queue_size:
            self.dropped_full += 1  # the append below pushes the oldest out
        q.append((channel_id, log_time, data))

    def close(self) -> None:
        """Send what is queued (waiting at most about a second) and stop; idempotent."""
        thread = self._thread
        if thread is None or self._pid != os.getpid():
            self._queue = None
            return
        self._stop.set()
        thread.join(2.0)
        self._thread = None
        self._queue = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    # ------------------------------------------------------------------ sender

    def _started(self) -> None:
        pid = os.getpid()
        if self._pid == pid:
            return
        # first use in this process (a feed made before a fork starts afresh in the child)
        self._pid = pid
        self._token = f"{pid}:{id(self):x}"
        self._queue = deque(maxlen=self.queue_size)
        self._ctl = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.settimeout(self.send_timeout_s)
        self._thread = threading.Thread(target=self._run, name="live-feed", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            stopping = self._stop.wait(self.interval_s)
            try:
                self._drain()
                if stopping and self.dropped != self._reported:
                    self._send([], 0)  # the final count, for the view's statistics
            except Exception as err:  # the feed must never take its writer down
                self._warn(f"live feed: {err}")
            if stopping:
                return

    def _drain(self) -> None:
        q = self._queue
        if q is None:
            return
        with self._lock:
            ctl, self._ctl = self._ctl, []
            msgs = [q.popleft() for _ in range(len(q))]
        if not ctl and not msgs:
            return
        batch: list[list[Any]] = list(ctl)
        size = 0
        count = 0
        for cid, t, data in msgs:
            batch.append([OP_MESSAGE, cid, t, data])
            size += len(data) + 16
            count += 1
            if size >= DATAGRAM_BYTES:
                self._send(batch, count)
                batch, size, count = [], 0, 0
        if batch:
            self._send(batch, count)

    def _send(self, ops: list[list[Any]], messages: int) -> None:
        sock = self._sock
        if sock is None:
            return
        dropped = self.dropped
        packet = msgpack.packb([self._token, dropped, ops], use_bin_type=True)
        try:
            sock.sendto(packet, self.socket_path)
        except (TimeoutError, OSError) as err:
            self.dropped_send += messages
            self._warn(f"live view at {self.socket_path} did not take {messages} messages: {err}")
            return
        self.sent += messages
        self._reported = dropped

    def _warn(self, text: str) -> None:
        if not self._warned:  # once per feed: the counts say the rest
            self._warned = True
            log.warning("%s", text)


def close_quietly(feed: LiveFeed | None) -> None:
    """Close ``feed`` if there is one, whatever happens."""
    if feed is not None:
        with contextlib.suppress(Exception):
            feed.close()
