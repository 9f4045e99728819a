"""The live view's server: foxglove-sdk's WebSocket server, fed the log's channels.

:class:`LiveView` owns one Foxglove WebSocket server (``foxglove.start_server``, in a
:class:`foxglove.Context` of its own) and creates a channel per log topic with the log's
schema and message encoding, so that a Foxglove client sees the same channels as the MCAP
and receives the same bytes.  foxglove-sdk serves from threads of its own and keeps a
bounded backlog per client (the oldest message is dropped when a client is slow).

Run as a process (``python -m tools.live.view``, started by
:class:`tools.live.server.LiveServer`), it binds a Unix datagram socket, reads the
feeds' batches (:mod:`tools.live.feed`) and logs them to the view; it prints
``READY <port>`` once both listen, and ends on SIGTERM, on SIGINT or when its standard
input closes (the process that started it is gone), writing what it served as JSON
(``--stats``).  It runs niced: on a busy machine the run's parts come first, and a view
that falls behind makes its feeds drop their oldest messages.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import os
import socket
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import foxglove
import msgpack
from foxglove import Capability, Channel, Schema

from dbc.runtime import stopping
from dbc.runtime.errors import WheelchairError
from tools.live.appschema import foxglove_refusal
from tools.live.feed import OP_CHANNEL, OP_MESSAGE, OP_SCHEMA

log = logging.getLogger(__name__)

#: Messages foxglove-sdk buffers per client before it drops the oldest.
CLIENT_BACKLOG = 4096
#: A new channel's messages are held this long after it is advertised: a client
#: subscribes when it sees the advertisement, and foxglove-sdk sends a channel's messages
#: only to the subscriptions it already has (a channel created with its first message,
#: as the log's are, would lose that message and any burst with it: the drives'
#: configuration at start-up, Host_Auth).
NEW_CHANNEL_HOLD_S = 0.5
#: The view process serves this long after its last feed message before it closes.
_LINGER_S = 0.5
#: At the end, the longest the view waits for a connected client to subscribe to the channels
#: advertised last (:meth:`FeedReceiver.serve`).
FINAL_HOLD_S = 5.0


class LiveViewError(WheelchairError):
    """The live view could not start (the message names the address and the reason)."""


class LiveView:
    """A Foxglove WebSocket server on ``host:port`` (port 0: any free port)."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        name: str = "wheelchair-hil",
        backlog: int = CLIENT_BACKLOG,
        playback_range: tuple[int, int] | None = None,
    ) -> None:
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(
                name=name,
                host=host,
                port=port,
                capabilities=[Capability.Time],
                context=self.context,
                message_backlog_size=backlog,
                playback_time_range=playback_range,
            )
        except Exception as err:  # foxglove-sdk raises its own error types
            raise LiveViewError(f"live view on {host}:{port}: cannot listen: {err}") from err
        self.host = host
        self._channels: dict[str, Channel] = {}
        self._time_ns = -1  # the last time the clients were told
        #: messages logged per topic
        self.counts: Counter[str] = Counter()
        self._closed = False

    @property
    def port(self) -> int:
        return int(self.server.port)

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def channel(
        self,
        topic: str,
        message_encoding: str,
        schema_name: str,
        schema_encoding: str,
        schema_data: bytes,
    ) -> Channel:
        """The view's channel for ``topic`` (created with this schema the first time)."""
        ch = self._channels.get(topic)
        if ch is None:
            why = foxglove_refusal(message_encoding, schema_encoding, schema_data)
            if why is not None:  # served all the same: other clients may read it
                log.warning("live view: Foxglove will not show %s: %s", topic, why)
            schema = Schema(name=schema_name, encoding=schema_encoding, data=bytes(schema_data))
            ch = Channel(
                topic, schema=schema, message_encoding=message_encoding, context=self.context
            )
            self._channels[topic] = ch
        return ch

    def has(self, topic: str) -> bool:
        """Whether the view has a channel for ``topic``."""
        return topic in self._channels

    @property
    def topics(self) -> list[str]:
        return sorted(self._channels)

    def subscribed_to(self, topic: str) -> bool:
        """Whether any client subscribes to ``topic``."""
        ch = self._channels.get(topic)
        return ch is not None and ch.has_sinks()

    def subscribed(self) -> bool:
        """Whether any client subscribes to any channel."""
        return any(ch.has_sinks() for ch in self._channels.values())

    def log(self, channel: Channel, data: bytes, log_time: int) -> None:
        channel.log(data, log_time=log_time)
        self.counts[channel.topic()] += 1

    def time(self, t_ns: int) -> None:
        """Tell the clients the current time, if it is later than the last they were told.

        Foxglove's clock follows it and stamps each message it receives with it; a time
        earlier than the last is a seek to Foxglove, which then drops the messages it
        has not shown yet and restarts its plots.  The feeds' batches (the recorder's,
        the controller's) reach the view in any order, so the clock only moves forward.
        """
        t = max(0, int(t_ns))
        if t <= self._time_ns:
            return
        self._time_ns = t
        self.server.broadcast_time(t)

    @property
    def time_ns(self) -> int:
        """The last time the clients were told (-1: none yet)."""
        return self._time_ns

    def close(self) -> None:
        """Stop the server (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for ch in self._channels.values():
            ch.close()
        self.server.stop()


# ------------------------------------------------------------------------ feeds


@dataclass
class _Feed:
    schemas: dict[int, tuple[str, str, bytes]] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    dropped: int = 0


@dataclass
class FeedStats:
    """What the view process took from its feeds."""

    feeds: int = 0
    messages: int = 0
    #: messages whose channel the view did not know (never expected: channels are never dropped)
    unknown_channel: int = 0
    #: datagrams that were not a feed's batch
    bad_datagrams: int = 0
    #: messages the feeds dropped before they reached the view (their own counts)
    feed_dropped: int = 0
    by_topic: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "feeds": self.feeds,
            "messages": self.messages,
            "unknown_channel": self.unknown_channel,
            "bad_datagrams": self.bad_datagrams,
            "feed_dropped": self.feed_dropped,
            "by_topic": dict(sorted(self.by_topic.items())),
        }


class FeedReceiver:
    """Reads the feeds' datagrams from ``sock`` into ``view`` (see :mod:`tools.live.feed`)."""

    def __init__(
        self, sock: socket.socket, view: LiveView, *, hold_s: float = NEW_CHANNEL_HOLD_S
    ) -> None:
        self.sock = sock
        self.view = view
        self.stats = FeedStats()
        self.hold_s = hold_s
        self._feeds: dict[str, _Feed] = {}
        #: topic -> (when its messages may go, [(channel, payload, log time)]) of new channels
        self._held: dict[str, tuple[float, list[tuple[Channel, bytes, int]]]] = {}

    def serve(self, stop: threading.Event, timeout_s: float = 0.1) -> FeedStats:
        """Take datagrams until ``stop`` is set."""
        self.sock.settimeout(timeout_s)
        while not stop.is_set():
            try:
                packet = self.sock.recv(1 << 20)
            except TimeoutError:
                self.release(time.monotonic())
                continue
            except OSError as err:
                log.warning("live view: feed socket: %s", err)
                break
            self.take(packet)
        self.sock.setblocking(False)  # what the feeds sent before the end is served too
        while True:
            try:
                self.take(self.sock.recv(1 << 20))
            except OSError:
                break
        # A channel created at the very end (the controller's loop record, written as its log
        # closes) is advertised as the view is about to close: a client busy with a backlog
        # subscribed to it after the server had closed it ("Unknown channel ID") and never got
        # its messages.  Where a client is subscribed, the view waits for it to subscribe to
        # the channels still held, up to FINAL_HOLD_S, then serves them.
        deadline = time.monotonic() + FINAL_HOLD_S
        while self._held and self.view.subscribed() and time.monotonic() < deadline:
            self.release(-math.inf)  # the subscribed ones only
            if self._held:
                time.sleep(0.02)
        self.release(math.inf)
        self.stats.by_topic = dict(self.view.counts)
        self.stats.feed_dropped = sum(f.dropped for f in self._feeds.values())
        return self.stats

    def holding(self) -> bool:
        """Whether messages of new channels wait to be served."""
        return bool(self._held)

    def release(self, now: float) -> None:
        """Serve the held messages of the channels a client has subscribed to, and of those
        advertised at least ``hold_s`` before ``now``.  (Holding a subscribed channel longer
        only makes its burst larger: a burst beyond a client's backlog loses its oldest.)"""
        view = self.view
        due_now = [t for t, (due, _) in self._held.items() if due <= now or view.subscribed_to(t)]
        for topic in due_now:
            _, msgs = self._held.pop(topic)
            for ch, data, t in msgs:
                self.view.log(ch, data, t)

    def take(self, packet: bytes) -> None:
        """One datagram: ``[token, dropped, ops]``.

        The clients' clock is set to the batch's latest log time before its messages
        are served, so that none reaches Foxglove before the first time (it would be
        stamped 1970) or later than the clock that stamps it."""
        now = time.monotonic()
        self.release(now)
        st = self.stats
        try:
            token, dropped, ops = msgpack.unpackb(packet, raw=False)
        except (ValueError, TypeError, msgpack.UnpackException):
            st.bad_datagrams += 1
            return
        feed = self._feeds.get(token)
        if feed is None:
            feed = self._feeds[token] = _Feed()
            st.feeds += 1
        feed.dropped = max(feed.dropped, int(dropped))
        view = self.view
        last_t = max((op[2] for op in ops if op[0] == OP_MESSAGE), default=0)
        if last_t:
            view.time(last_t)
        held = self._held
        for op in ops:
            kind = op[0]
            if kind == OP_MESSAGE:
                ch = feed.channels.get(op[1])
                if ch is None:
                    st.unknown_channel += 1
                    continue
                st.messages += 1
                waiting = held.get(ch.topic())
                if waiting is None:
                    view.log(ch, op[3], op[2])
                else:
                    waiting[1].append((ch, op[3], op[2]))
            elif kind == OP_CHANNEL:
                _, cid, topic, encoding, sid = op
                name, schema_encoding, data = feed.schemas.get(sid, ("", "", b""))
                is_new = not view.has(topic)
                ch = feed.channels[cid] = view.channel(topic, encoding, name, schema_encoding, data)
                if is_new and self.hold_s > 0:
                    held[topic] = (now + self.hold_s, [])
            elif kind == OP_SCHEMA:
                _, sid, name, encoding, data = op
                feed.schemas[sid] = (name, encoding, data)


# ------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.live.view", description=__doc__)
    ap.add_argument("--socket", required=True, help="Unix datagram socket the feeds send to")
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=8765)
    ap.add_argument("--stats", default=None, help="write what was served here (JSON)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="live view: %(levelname)s: %(message)s")
    with contextlib.suppress(OSError):
        os.nice(10)  # the run's parts come first; a view that falls behind drops the oldest
    stop = stopping.stop_event()
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        sock.bind(args.socket)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        view = LiveView(args.host, args.port)
    except (OSError, LiveViewError) as err:
        print(f"ERROR {err}", flush=True)
        return 2
    threading.Thread(target=_watch_stdin, args=(stop,), daemon=True).start()
    print(f"READY {view.port}", flush=True)
    stopping.at("ready")
    try:
        stats = FeedReceiver(sock, view).serve(stop)
        if args.stats:
            Path(args.stats).write_text(json.dumps(stats.as_dict(), indent=2) + "\n")
        time.sleep(_LINGER_S)  # the clients' backlogs drain before the server closes
    finally:
        view.close()
        sock.close()
    return 0


def _watch_stdin(stop: threading.Event) -> None:
    """Stop when standard input closes: whoever started the view is gone."""
    # os.read, not sys.stdin: a daemon thread blocked in a buffered read holds the buffer's
    # lock, and the interpreter aborts (SIGABRT) when it finalizes while the read is pending
    try:
        while os.read(0, 4096):
            pass
    except OSError:
        pass
    stop.set()


def _main() -> int:
    """``python -m tools.live.view``: a stop signal ends the view with its status, at any
    moment of its life (:mod:`dbc.runtime.stopping`)."""
    stopping.install()
    stopping.at("start")
    try:
        return main()
    finally:
        stopping.seal()


if __name__ == "__main__":
    sys.exit(_main())
