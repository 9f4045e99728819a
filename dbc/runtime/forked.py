"""A log written by a forked process: the loop ships items, the child writes them.

A one-process lock-step run has one interpreter lock; whatever its logs cost to format
and compress is time the loop waits for, although the machine has a second core.  The
recorder of such a run (:class:`tools.logs.bustap.ChannelTap`) and the controller's telemetry
(:class:`controller.telemetry.ForkedTelemetry`) hand that work to a :class:`ForkedWriter`:

* :meth:`~ForkedWriter.start` forks; the child builds its sink with ``open_sink()`` and
  says it is ready, or why not (the parent raises :class:`ForkedWriterError` with that);
* :meth:`~ForkedWriter.put` appends an item to a batch and ships full batches through a
  pipe.  A full pipe blocks the caller until the child has caught up: that is the flow
  control, nothing is dropped while the child lives;
* in real time (:meth:`~ForkedWriter.ship_from_thread`) the caller never waits for the
  child: full batches queue for a thread of the parent that ships them, and beyond
  :data:`QUEUED_BATCHES_MAX` queued batches the newest are dropped and counted in
  :attr:`~ForkedWriter.dropped` (``stop`` then raises, naming the count: the log is partial).  A control loop on SCHED_FIFO whose writer (an ordinary
  process) is starved by the other real-time parts must not stop with it: a blocked tick
  let the drives' setpoint watchdog expire (a one-CPU guest, a recorder catching up);
* if the child dies, items are counted in :attr:`~ForkedWriter.lost` and ``put`` goes
  on without raising: a log must never stop the loop that writes it;
* :meth:`~ForkedWriter.stop` ships the rest, waits a bounded time for the child to close
  its sink and returns what the sink's ``close`` returned.  If the parent dies instead,
  the child sees the pipe close and closes the sink, so the log is complete up to there.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import logging
import multiprocessing
import signal
import threading
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any, Protocol

from dbc.runtime.errors import WheelchairError

log = logging.getLogger(__name__)


#: Batches a real-time writer queues for its shipping thread before it drops (module doc):
#: 256 batches of 64 ticks' records are 2.7 minutes of a 100 Hz loop.
QUEUED_BATCHES_MAX = 256


class ForkedWriterError(WheelchairError):
    """A forked log writer could not be started, or failed (the message says which log)."""


class Sink(Protocol):
    """What the child writes into: ``take`` each shipped batch, ``close`` once at the end."""

    def take(self, items: list[Any]) -> None:
        """Write one shipped batch of items."""

    def close(self) -> Any:
        """Close the sink; what it returns is what :meth:`ForkedWriter.stop` returns."""


class ForkedWriter:
    """Ship items to ``open_sink()``'s sink in a forked process (see the module doc).

    ``name`` names the log in errors and the process.  ``put`` may be called from any
    thread.
    """

    def __init__(
        self,
        name: str,
        open_sink: Callable[[], Sink],
        *,
        batch: int = 256,
        close_timeout_s: float = 120.0,
    ) -> None:
        self.name = name
        self.batch = max(1, int(batch))
        self.close_timeout_s = close_timeout_s
        self.lost = 0
        #: items dropped because the real-time queue was full (ship_from_thread)
        self.dropped = 0
        self.failed = ""
        self._open_sink = open_sink
        self._items: list[Any] = []
        self._lock = threading.Lock()
        self._conn: Connection | None = None
        self._proc: Any = None
        # real time: full batches wait here for the shipping thread
        self._queue: collections.deque[list[Any]] | None = None
        self._wake = threading.Condition(self._lock)
        self._shipper: threading.Thread | None = None
        self._stopping = False

    @property
    def pid(self) -> int | None:
        """The child's process ID, None before :meth:`start`."""
        return None if self._proc is None else self._proc.pid

    def start(self) -> None:
        """Fork the child and wait until its sink is open."""
        try:
            ctx = multiprocessing.get_context("fork")
        except ValueError as err:
            raise ForkedWriterError(f"{self.name}: cannot fork a writer here: {err}") from err
        parent, child = ctx.Pipe(duplex=True)
        proc = ctx.Process(
            target=_child, name=self.name, args=(child, parent, self._open_sink), daemon=True
        )
        try:
            proc.start()
        except (OSError, AssertionError) as err:  # AssertionError: a daemonic parent
            parent.close()
            child.close()
            raise ForkedWriterError(f"{self.name}: cannot start the writer: {err}") from err
        child.close()
        try:
            ready = parent.recv()
        except (EOFError, OSError) as err:
            proc.join(5)
            raise ForkedWriterError(
                f"{self.name}: the writer ended at start (exit {proc.exitcode})"
            ) from err
        if ready != "ready":
            proc.join(5)
            raise ForkedWriterError(f"{self.name}: {ready}")
        self._conn, self._proc = parent, proc

    def put(self, item: Any) -> None:
        """Queue one item; ships the batch when it is full (never raises)."""
        with self._lock:
            self._items.append(item)
            if len(self._items) >= self.batch:
                self._ship()

    def flush(self) -> None:
        """Ship what is queued now."""
        with self._lock:
            self._ship()

    def ship_from_thread(self) -> None:
        """From now on :meth:`put` never waits for the child (module doc: real time)."""
        with self._lock:
            if self._queue is not None or self._conn is None:
                return
            self._queue = collections.deque()
            self._shipper = threading.Thread(
                target=self._ship_queued, name=f"{self.name} shipper", daemon=True
            )
            self._shipper.start()

    def _ship(self) -> None:
        """Ship the batch in progress (called with the lock held)."""
        items, self._items = self._items, []
        if not items:
            return
        queue = self._queue
        if queue is not None:
            if len(queue) >= QUEUED_BATCHES_MAX:
                self.dropped += len(items)
                if self.dropped == len(items):
                    log.warning("%s: the writer is behind; dropping records", self.name)
                return
            queue.append(items)
            self._wake.notify()
            return
        self._send(items)

    def _send(self, items: list[Any]) -> None:
        conn = self._conn
        if conn is None or self.failed:
            self.lost += len(items)
            return
        try:
            conn.send(items)
        except (OSError, ValueError) as err:  # the child died: count, never raise here
            self.failed = self._childs_error() or f"writer lost: {err!r}"
            self.lost += len(items)
            log.error("%s: %s; items are no longer written", self.name, self.failed)

    def _ship_queued(self) -> None:
        """The shipping thread: queued batches to the child, in order, outside the lock."""
        queue = self._queue
        assert queue is not None
        while True:
            with self._wake:
                while not queue and not self._stopping:
                    self._wake.wait()
                if not queue:
                    return
                items = queue.popleft()
            self._send(items)

    def _childs_error(self) -> str | None:
        """The error the writer reported before it stopped (e.g. the disk is full), if any."""
        conn = self._conn
        try:
            if conn is not None and conn.poll(0):
                reply = conn.recv()
                if isinstance(reply, tuple) and reply[:1] == ("error",):
                    return str(reply[1])
        except (EOFError, OSError, ValueError):
            pass
        return None

    def stop(self) -> Any:
        """Ship the rest, let the child close its sink; returns the sink's ``close`` result.

        Raises :class:`ForkedWriterError` if the child failed or did not finish within
        ``close_timeout_s`` (then it is killed; the log ends where it stopped).
        """
        with self._lock:
            self._ship()
            self._stopping = True
            self._wake.notify()
            shipper = self._shipper
        if shipper is not None:  # what is queued goes out first, in order
            shipper.join(self.close_timeout_s)
            if shipper.is_alive():  # a child that takes nothing: end it, the send then fails
                self._proc.kill()
                shipper.join(30)
                # the cause, not its consequence (the shipper's "writer lost")
                self.failed = f"the writer took nothing for {self.close_timeout_s:g} s"
        with self._lock:
            conn, self._conn = self._conn, None
        if conn is None:
            raise ForkedWriterError(f"{self.name}: the writer was not running")
        reply: Any = None
        try:
            if not self.failed:
                conn.send(None)
                if conn.poll(self.close_timeout_s):
                    reply = conn.recv()
                else:
                    self.failed = f"the writer did not finish within {self.close_timeout_s:g} s"
                    self._proc.kill()
        except (EOFError, OSError) as err:
            self.failed = self.failed or f"writer lost: {err!r}"
        finally:
            conn.close()
            self._proc.join(30)
        if isinstance(reply, tuple) and reply[:1] == ("error",):
            self.failed = reply[1]
        if self.dropped and not self.failed:  # the log is partial: said as a lost writer's is
            self.failed = (
                f"{self.dropped} item(s) dropped while the writer was behind (in real time "
                "the loop never waits for it)"
            )
        if self.failed or not (isinstance(reply, tuple) and reply[:1] == ("ok",)):
            raise ForkedWriterError(
                f"{self.name} failed: {self.failed or 'no answer'}"
                + (f"; {self.lost} item(s) not written" if self.lost else "")
            )
        return reply[1]


def _child(conn: Connection, parents_end: Connection, open_sink: Callable[[], Sink]) -> None:
    """The writer process: batches from ``conn`` into the sink until ``None`` (or EOF)."""
    parents_end.close()  # else the pipe stays open here and a dead parent is never noticed
    # a stop signal is the parent's to act on (a service's stop reaches every process of its
    # group): the parent ends this writer by closing the pipe, after the last items
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, signal.SIG_IGN)
    try:
        sink = open_sink()
    except Exception as err:
        conn.send(f"{type(err).__name__}: {err}")
        return
    conn.send("ready")
    try:
        while True:
            try:
                items = conn.recv()
            except EOFError:  # the parent is gone: keep what was written
                sink.close()
                return
            if items is None:
                break
            sink.take(items)
        result = sink.close()
    except Exception as err:  # report it; what was written stays readable
        with contextlib.suppress(Exception):
            sink.close()
        conn.send(("error", _reason(err)))
        return
    conn.send(("ok", result))


def _reason(err: BaseException) -> str:
    """``ENOSPC (No space left on device)`` for an OS error, else the exception's text."""
    if isinstance(err, OSError) and err.errno:
        name = errno.errorcode.get(err.errno, str(err.errno))
        where = f" on {err.filename}" if err.filename else ""
        return f"{name} ({err.strerror}){where}"
    return f"{type(err).__name__}: {err}"
