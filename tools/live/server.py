"""The live view as the run sees it: a process that serves, and the feeds that fill it.

``run``, ``control`` (and ``record`` when ``run`` starts it) take ``--live [HOST:]PORT``.
:class:`LiveServer` starts the view process (:mod:`tools.live.view`, foxglove-sdk's
WebSocket server) with a private Unix socket in a directory only this user can enter,
and hands out :class:`~tools.live.feed.LiveFeed` mirrors for the run's log writers.  The
parts of the run keep writing their MCAP as before; each writer also copies its messages
into its feed's bounded queue, and the view process serves them.  Nothing of it runs in
a control loop's thread but the writers' own appends (the controller's telemetry and the
recorder of a one-process run already write from forked processes).

The view binds 127.0.0.1 unless a host is given.  Port 0 takes any free port
(:attr:`LiveServer.port` says which).
"""

from __future__ import annotations

import contextlib
import json
import logging
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import TracebackType
from typing import Any

from dbc.runtime import stopping
from dbc.runtime.errors import WheelchairError
from tools import extras
from tools.live.address import LiveAddress
from tools.live.feed import DEFAULT_QUEUE, LiveFeed

log = logging.getLogger(__name__)


class LiveServerError(WheelchairError):
    """The live view process could not start (the message says why)."""


class LiveServer:
    """The view process on ``address``; :meth:`feed` gives each log writer its mirror.

    Use as a context manager, or call :meth:`start` and :meth:`stop` (idempotent).
    """

    def __init__(
        self,
        address: LiveAddress,
        *,
        queue_size: int = DEFAULT_QUEUE,
        start_timeout_s: float = 20.0,
    ) -> None:
        self.address = address
        self.queue_size = queue_size
        self.start_timeout_s = start_timeout_s
        self.port = address.port
        #: what the view served (``tools.live.view.FeedStats.as_dict``), after :meth:`stop`
        self.stats: dict[str, Any] = {}
        self._dir: Path | None = None
        self._proc: subprocess.Popen[bytes] | None = None
        self._attached: str | None = None

    @classmethod
    def attached(cls, socket_path: str, *, queue_size: int = DEFAULT_QUEUE) -> LiveServer:
        """A handle on a view another process started (``run`` passes its view's socket to
        its parts, and into the private network namespace it re-executes itself in: a
        view started inside that namespace could not be reached from the machine)."""
        if not socket_path:
            raise LiveServerError("--live-feed: no socket path given")
        server = cls(LiveAddress(), queue_size=queue_size)
        server._attached = socket_path
        return server

    @property
    def socket_path(self) -> str:
        if self._attached is not None:
            return self._attached
        if self._dir is None:
            raise LiveServerError("the live view is not started")
        return str(self._dir / "feed.sock")

    @property
    def url(self) -> str:
        host = f"[{self.address.host}]" if ":" in self.address.host else self.address.host
        return f"ws://{host}:{self.port}"

    def start(self) -> LiveServer:
        """Start the view process and wait until it listens (:class:`LiveServerError` if not)."""
        if self._proc is not None or self._attached is not None:
            return self
        extras.require("the live view", "live")
        self._dir = Path(tempfile.mkdtemp(prefix="whil-live-"))  # mode 0700: ours alone
        cmd = [
            sys.executable,
            "-m",
            "tools.live.view",
            "--socket",
            self.socket_path,
            "--host",
            self.address.host,
            "--port",
            str(self.address.port),
            "--stats",
            str(self._dir / "stats.json"),
        ]
        with stopping.blocked():  # the view unblocks them once its handlers are in place
            self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        line = self._first_line()
        if not line.startswith("READY "):
            self.stop()
            why = line.removeprefix("ERROR ").strip() or "it exited without saying why"
            raise LiveServerError(f"live view on {self.address}: {why}")
        self.port = int(line.split()[1])
        return self

    def _first_line(self) -> str:
        proc = self._proc
        assert proc is not None and proc.stdout is not None
        deadline = time.monotonic() + self.start_timeout_s
        while time.monotonic() < deadline:
            ready, _, _ = select.select([proc.stdout], [], [], 0.1)
            if ready:
                return proc.stdout.readline().decode(errors="replace").strip()
            if proc.poll() is not None:
                return ""
        return f"ERROR no answer within {self.start_timeout_s:g} s"

    def feed(self) -> LiveFeed:
        """A mirror for one log writer (starts in the process that writes with it)."""
        return LiveFeed(self.socket_path, queue_size=self.queue_size)

    def stop(self) -> dict[str, Any]:
        """Stop the view process and return what it served (idempotent)."""
        proc, self._proc = self._proc, None
        if proc is not None:
            if proc.stdin is not None:
                with contextlib.suppress(OSError):
                    proc.stdin.close()  # the view ends when its standard input closes
            try:
                proc.wait(30.0)  # niced: on a busy machine it may take a while
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            if proc.stdout is not None:
                proc.stdout.close()
        if self._dir is not None:
            with contextlib.suppress(OSError, ValueError):
                self.stats = json.loads((self._dir / "stats.json").read_text())
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None
        return self.stats

    def __enter__(self) -> LiveServer:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


def format_live_stats(stats: dict[str, Any]) -> str:
    """One line: what the view served, and what the feeds dropped."""
    if not stats:
        return "no figures from the view process"
    topics = stats.get("by_topic") or {}
    return (
        f"served {stats.get('messages', 0)} messages on {len(topics)} channels from "
        f"{stats.get('feeds', 0)} feeds; the feeds dropped {stats.get('feed_dropped', 0)} "
        "(queue full or view busy)"
    )
