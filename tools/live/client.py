"""A minimal Foxglove WebSocket client: what the tests and the benchmark connect with.

It speaks the protocol foxglove-sdk serves (subprotocol ``foxglove.sdk.v1``): it reads
the server's ``serverInfo`` and ``advertise`` messages, subscribes to every channel it is
told about (channels advertised later too; 50 ms after the advertisement, and again if a
subscription stays silent, because foxglove-sdk now and then refuses a subscription sent
the instant a channel is advertised), and keeps each message it receives (binary opcode
1: subscription id, log time in ns, payload).  It needs the ``websockets``
package (the ``dev`` extra).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

SUBPROTOCOL = "foxglove.sdk.v1"
_MESSAGE_DATA = 0x01
#: a new channel is subscribed to this long after its advertisement
_SUBSCRIBE_AFTER_S = 0.05
#: a subscription without a message this long is made again, at most _RETRIES times
_QUIET_S = 1.0
_RETRIES = 3
_HEAD_SIZE = 13  # opcode u8, subscription id u32, log time u64, little-endian


@dataclass
class Received:
    """What a client got: the server's info, the channels advertised, the messages."""

    server_info: dict[str, Any] = field(default_factory=dict)
    #: advertised channels by id (``topic``, ``encoding``, ``schemaName``, ``schema`` ...)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)
    #: (topic, log time ns, payload) in arrival order
    messages: list[tuple[str, int, bytes]] = field(default_factory=list)
    #: binary messages of a subscription it did not make (never expected)
    unknown: int = 0
    #: the server's status messages (errors it reports to this client)
    status: list[str] = field(default_factory=list)
    #: seconds from connecting to the first message
    first_message_s: float | None = None

    def counts(self) -> Counter[str]:
        return Counter(topic for topic, _, _ in self.messages)


class LiveClient:
    """Connect to ``url``, subscribe to everything, collect until :meth:`stop` or the server ends.

    ``delay_s`` sleeps that long after each message (a slow client, for the benchmark).
    """

    def __init__(self, url: str, *, delay_s: float = 0.0, open_timeout_s: float = 10.0) -> None:
        self.url = url
        self.delay_s = delay_s
        self.open_timeout_s = open_timeout_s
        self.received = Received()
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._subscribed = threading.Event()
        self._thread: threading.Thread | None = None
        self._subs: dict[int, str] = {}  # subscription id -> topic (old ones kept)
        self._live_subs: dict[int, list[Any]] = {}  # id -> [channel id, when, got a message]
        self._pending: dict[int, float] = {}  # channel id -> when advertised
        self._tries: Counter[int] = Counter()
        self._next_sub = 1
        self._ws: Any = None

    def start(self) -> LiveClient:
        """Connect in a thread of its own; returns once the connection is open."""
        opened = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(opened,), daemon=True)
        self._thread.start()
        opened.wait(self.open_timeout_s + 1.0)
        if self.error is not None:
            raise self.error
        return self

    def wait_subscribed(self, timeout_s: float = 10.0) -> bool:
        """Wait until the client subscribed to the first channels advertised."""
        return self._subscribed.wait(timeout_s)

    def stop(self, timeout_s: float = 10.0) -> Received:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        return self.received

    def join(self, timeout_s: float) -> Received:
        """Wait for the server to close the connection (or ``timeout_s``)."""
        if self._thread is not None:
            self._thread.join(timeout_s)
        return self.stop()

    def _run(self, opened: threading.Event) -> None:
        from websockets.exceptions import ConnectionClosed  # lazy: the [live] extra
        from websockets.sync.client import connect  # lazy: the [live] extra

        try:
            ws = connect(self.url, subprotocols=[SUBPROTOCOL], open_timeout=self.open_timeout_s)  # type: ignore[list-item]
        except BaseException as err:
            self.error = err
            opened.set()
            return
        opened.set()
        t0 = time.monotonic()
        rec = self.received
        self._ws = ws
        try:
            with ws:
                while not self._stop.is_set():
                    now = time.monotonic()
                    self._subscribe_due(now)
                    self._recheck(now)
                    try:
                        frame = ws.recv(timeout=0.02)
                    except TimeoutError:
                        continue
                    except ConnectionClosed:
                        return
                    if isinstance(frame, str):
                        msg = json.loads(frame)
                        op = msg.get("op")
                        if op == "serverInfo":
                            rec.server_info = msg
                        elif op == "advertise":
                            for ch in msg.get("channels", []):
                                rec.channels[int(ch["id"])] = ch
                                self._pending[int(ch["id"])] = time.monotonic()
                        elif op == "status":
                            rec.status.append(str(msg.get("message", "")))
                        continue
                    if len(frame) < _HEAD_SIZE or frame[0] != _MESSAGE_DATA:
                        continue
                    sub = int.from_bytes(frame[1:5], "little")
                    log_time = int.from_bytes(frame[5:13], "little")
                    topic = self._subs.get(sub)
                    if topic is None:
                        rec.unknown += 1
                        continue
                    state = self._live_subs.get(sub)
                    if state is not None:
                        state[2] = True
                    if rec.first_message_s is None:
                        rec.first_message_s = time.monotonic() - t0
                    rec.messages.append((topic, log_time, bytes(frame[_HEAD_SIZE:])))
                    if self.delay_s:
                        time.sleep(self.delay_s)
        except BaseException as err:
            self.error = err

    def _subscribe_due(self, now: float) -> None:
        """Subscribe to the channels advertised at least ``_SUBSCRIBE_AFTER_S`` ago.

        foxglove-sdk advertises a new channel to its clients a moment before it accepts
        subscriptions to it; a subscription sent at once is sometimes refused (logged by the
        server, not told to the client), so the client waits a little, as a person does.
        """
        due = [cid for cid, t in self._pending.items() if now - t >= _SUBSCRIBE_AFTER_S]
        if not due:
            return
        batch = []
        for cid in due:
            del self._pending[cid]
            sid = self._next_sub
            self._next_sub += 1
            self._subs[sid] = self.received.channels[cid]["topic"]
            self._live_subs[sid] = [cid, now, False]
            batch.append({"id": sid, "channelId": cid})
        self._ws.send(json.dumps({"op": "subscribe", "subscriptions": batch}))
        self._subscribed.set()

    def _recheck(self, now: float) -> None:
        """Subscribe again to a channel silent since its subscription (it may have been
        refused, see :meth:`_subscribe_due`); a few times, for channels that are just quiet."""
        for sid, (cid, t, got) in list(self._live_subs.items()):
            if got or now - t < _QUIET_S or self._tries[cid] >= _RETRIES:
                continue
            self._tries[cid] += 1
            del self._live_subs[sid]
            self._ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [sid]}))
            self._pending[cid] = now - _SUBSCRIBE_AFTER_S


def main(argv: list[str] | None = None) -> int:
    """``python -m tools.live.client URL``: collect until the server ends, print the counts as JSON.

    The benchmark runs it as a process of its own, so that the client's work is not
    measured as the run's.
    """
    ap = argparse.ArgumentParser(prog="python -m tools.live.client", description=main.__doc__)
    ap.add_argument("url")
    ap.add_argument("--connect-s", type=float, default=30.0, help="keep trying this long")
    ap.add_argument("--seconds", type=float, default=3600.0, help="collect at most this long")
    ap.add_argument("--delay-s", type=float, default=0.0, help="sleep after each message")
    ap.add_argument("--json", default=None, help="write the counts here")
    args = ap.parse_args(argv)
    deadline = time.monotonic() + args.connect_s
    while True:
        client = LiveClient(args.url, delay_s=args.delay_s)
        try:
            client.start()
            break
        except OSError as err:
            if time.monotonic() > deadline:
                print(f"cannot connect to {args.url}: {err}", file=sys.stderr)
                return 1
            time.sleep(0.1)
    rec = client.join(args.seconds)
    out = {
        "channels": len(rec.channels),
        "messages": len(rec.messages),
        "unknown": rec.unknown,
        "first_message_s": rec.first_message_s,
        "by_topic": dict(sorted(rec.counts().items())),
    }
    text = json.dumps(out, indent=2)
    if args.json:
        Path(args.json).write_text(text + "\n")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
