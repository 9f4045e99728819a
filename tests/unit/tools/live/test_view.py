"""The view process's side: feeds' datagrams into foxglove-sdk's server, for a real client."""

from __future__ import annotations

import json
import math
import re
import socket
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, cast

import msgpack
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from tools.live.client import SUBPROTOCOL, LiveClient
from tools.live.feed import OP_CHANNEL, OP_MESSAGE, OP_SCHEMA
from tools.live.view import FeedReceiver, LiveView, LiveViewError

#: How long a wait may take before the test gives up: a guard against a hang, never a
#: criterion (each wait ends as soon as what it waits for has happened).
GUARD_S = 60.0


@pytest.fixture
def view() -> Iterator[LiveView]:
    v = LiveView("127.0.0.1", 0)
    yield v
    v.close()


def _packet(token: str, dropped: int, ops: list[list[object]]) -> bytes:
    return msgpack.packb([token, dropped, ops], use_bin_type=True)


def test_feeds_channels_reach_a_client_with_their_schema_and_bytes(view: LiveView) -> None:
    a, _ = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    rx = FeedReceiver(a, view, hold_s=0)  # the client subscribes before the messages come
    rx.take(
        _packet(
            "f1",
            0,
            [
                [OP_SCHEMA, 1, "T", "jsonschema", b'{"type":"object"}'],
                [OP_CHANNEL, 4, "/t", "json", 1],
            ],
        )
    )
    client = LiveClient(view.url).start()
    assert client.wait_subscribed()
    deadline = time.monotonic() + GUARD_S
    while not view.subscribed() and time.monotonic() < deadline:
        time.sleep(0.01)  # until the server has taken the subscription
    assert view.subscribed()
    rx.take(_packet("f1", 3, [[OP_MESSAGE, 4, 1_000 + i, b'{"i":%d}' % i] for i in range(5)]))
    rx.take(b"not msgpack at all \xc1")
    rx.take(_packet("f1", 3, [[OP_MESSAGE, 99, 0, b"{}"]]))  # a channel never announced
    deadline = time.monotonic() + GUARD_S
    while len(client.received.messages) < 5 and time.monotonic() < deadline:
        time.sleep(0.01)
    view.close()  # the client sees the connection close
    received = client.join(GUARD_S)
    a.close()
    _.close()
    (ch,) = received.channels.values()
    assert (ch["topic"], ch["encoding"], ch["schemaName"], ch["schema"]) == (
        "/t",
        "json",
        "T",
        '{"type":"object"}',
    )
    assert received.messages == [("/t", 1_000 + i, b'{"i":%d}' % i) for i in range(5)]
    assert rx.stats.bad_datagrams == 1
    assert rx.stats.unknown_channel == 1
    assert rx.stats.messages == 5


def test_two_feeds_with_the_same_ids_keep_their_own_channels(view: LiveView) -> None:
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    rx = FeedReceiver(a, view, hold_s=0)
    for token, topic in (("rec", "/can/raw"), ("ctl", "/controller/tick")):
        rx.take(
            _packet(
                token,
                0,
                [[OP_SCHEMA, 1, topic, "jsonschema", b"{}"], [OP_CHANNEL, 1, topic, "json", 1]],
            )
        )
        rx.take(_packet(token, 0, [[OP_MESSAGE, 1, 5, b"{}"]]))
    a.close()
    b.close()
    assert view.topics == ["/can/raw", "/controller/tick"]
    assert dict(view.counts) == {"/can/raw": 1, "/controller/tick": 1}
    assert rx.stats.feeds == 2


def test_a_port_in_use_is_an_error_naming_the_address(view: LiveView) -> None:
    with pytest.raises(LiveViewError, match=f"127.0.0.1:{view.port}: cannot listen"):
        LiveView("127.0.0.1", view.port)


def test_a_client_that_stops_reading_costs_the_server_nothing_and_loses_the_oldest() -> None:
    view = LiveView("127.0.0.1", 0, backlog=64)
    ch = view.channel("/t", "json", "T", "jsonschema", b"{}")
    try:
        with connect(view.url, subprotocols=[SUBPROTOCOL], max_queue=1) as ws:  # type: ignore[list-item]
            json.loads(ws.recv(timeout=5))  # serverInfo
            ad = json.loads(ws.recv(timeout=5))
            cid = ad["channels"][0]["id"]
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": cid}]}))
            deadline = time.monotonic() + GUARD_S
            while not view.subscribed() and time.monotonic() < deadline:
                time.sleep(0.01)
            assert view.subscribed()
            # the client reads nothing while 20 MB are logged: every log() returns at once
            payload = b'{"pad":"' + b"x" * 1000 + b'","i":%d}'
            n = 20_000
            for i in range(n):
                ch.log(payload % i, log_time=i)
            got = []
            while True:
                try:
                    frame = ws.recv(timeout=1.0)
                except TimeoutError:
                    break
                if isinstance(frame, bytes):
                    got.append(int.from_bytes(frame[5:13], "little"))
    finally:
        view.close()
    assert got, "the client received nothing"
    assert len(got) < n  # the backlog dropped messages ...
    assert got[-1] == n - 1  # ... the oldest ones: the newest arrived
    assert got == sorted(got)


#: what Foxglove and Lichtblick (1.22.1 on) offer, in their order
APP_SUBPROTOCOLS = ["foxglove.websocket.v1", "foxglove.sdk.v1"]
_TIME_OP = 0x02  # server binary opcode: time (u64 ns)
_SCHEMA = json.dumps({"type": "object", "properties": {"i": {"type": "integer"}}}).encode()


def _app_like_client(
    view: LiveView,
    connected: threading.Event,
    want: int,
    stop: float = GUARD_S,
    until_time: int | None = None,
) -> tuple[list[tuple[int, int]], list[str]]:
    """Connect as Foxglove does, subscribe to each channel the moment it is advertised, and
    collect binary frames ``(opcode, time or log time)`` until ``want`` messages came."""
    frames: list[tuple[int, int]] = []
    topics: list[str] = []
    subs: dict[int, str] = {}
    topic_ids: dict[int, int] = {}  # channel id -> subscription id
    deadline = time.monotonic() + stop
    with connect(view.url, subprotocols=APP_SUBPROTOCOLS) as ws:  # type: ignore[arg-type]

        def done() -> bool:  # time and data are separate queues in foxglove-sdk: wait for both
            got = sum(op == 1 for op, _ in frames) >= want
            return got and (until_time is None or (_TIME_OP, until_time) in frames)

        while time.monotonic() < deadline and not done():
            try:
                frame = ws.recv(timeout=0.05)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                msg = json.loads(frame)
                connected.set()  # serverInfo: the server knows this client
                if msg["op"] == "advertise":
                    batch = []
                    for ch in msg["channels"]:
                        subs[len(subs) + 1] = ch["topic"]
                        topic_ids[ch["id"]] = len(subs)
                        batch.append({"id": len(subs), "channelId": ch["id"]})
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": batch}))
                refused = re.fullmatch(r"Unknown channel ID: (\d+)", msg.get("message", ""))
                if msg["op"] == "status" and refused and int(refused[1]) in topic_ids:
                    # foxglove-sdk 0.30 can refuse a subscription that follows the advertise
                    # at once, before its client's channel map has the channel (5 in 100
                    # beside four spinning processes): subscribe again, as on a re-open
                    cid = int(refused[1])
                    batch = [{"id": topic_ids[cid], "channelId": cid}]
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": batch}))
                continue
            if frame[0] == _TIME_OP:
                frames.append((_TIME_OP, int.from_bytes(frame[1:9], "little")))
            elif frame[0] == 1:
                frames.append((1, int.from_bytes(frame[5:13], "little")))
                topics.append(subs[int.from_bytes(frame[1:5], "little")])
    return frames, topics


def _new_channel_with_a_burst(token: str, topic: str, t0: int, n: int) -> bytes:
    """What a log writer's feed sends when a frame of a new kind arrives: the schema, the
    channel and its first messages in one datagram (the recorder creates a decoded channel
    with its first frame)."""
    return _packet(
        token,
        0,
        [
            [OP_SCHEMA, 1, "T", "jsonschema", _SCHEMA],
            [OP_CHANNEL, 1, topic, "json", 1],
            *([OP_MESSAGE, 1, t0 + i, b'{"i":%d}' % i] for i in range(n)),
        ],
    )


def _serve_in_thread(
    rx: FeedReceiver, packets: list[bytes], ready: Callable[[], bool]
) -> threading.Thread:
    def run() -> None:
        deadline = time.monotonic() + GUARD_S
        while not ready() and time.monotonic() < deadline:
            time.sleep(0.01)  # a client is connected (Foxglove was opened before the run)
        for p in packets:
            rx.take(p)
        while rx.holding() and time.monotonic() < deadline:
            rx.release(time.monotonic())
            time.sleep(0.01)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def test_a_new_channels_first_messages_reach_a_client_that_subscribes_when_it_sees_it(
    view: LiveView,
) -> None:
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    rx = FeedReceiver(a, view)  # holds a new channel's messages NEW_CHANNEL_HOLD_S
    connected = threading.Event()

    def serve() -> None:
        connected.wait(GUARD_S)  # Foxglove was open before the run
        rx.take(_new_channel_with_a_burst("rec", "/can/Host_Auth", 1000, 12))
        assert rx.holding()
        deadline = time.monotonic() + GUARD_S
        while not view.subscribed() and time.monotonic() < deadline:
            time.sleep(0.01)  # the hold is what lets the subscription arrive first ...
        rx.release(math.inf)  # ... (synthetic time: however long this machine took)

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    frames, topics = _app_like_client(view, connected, want=12)
    th.join(GUARD_S)
    a.close()
    b.close()
    assert topics == ["/can/Host_Auth"] * 12  # the start-up burst, all of it
    assert [t for op, t in frames if op == 1] == [1000 + i for i in range(12)]


def test_the_clients_clock_only_moves_forward(
    view: LiveView,
) -> None:
    # two feeds (the recorder's and the controller's telemetry, which reaches the view
    # later) send batches whose log times interleave; Foxglove takes a time earlier than
    # the last as a seek and drops what it had not shown
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    rx = FeedReceiver(a, view, hold_s=0)
    for token in ("rec", "ctl"):
        rx.take(_packet(token, 0, [[OP_SCHEMA, 1, "T", "jsonschema", _SCHEMA],
                                   [OP_CHANNEL, 1, f"/{token}", "json", 1]]))  # fmt: skip
    times = [("rec", 1_000), ("ctl", 700), ("rec", 1_100), ("ctl", 800), ("rec", 1_200)]
    packets = [_packet(tok, 0, [[OP_MESSAGE, 1, t, b'{"i":1}']]) for tok, t in times]
    connected = threading.Event()
    channels = [
        view.channel(f"/{tok}", "json", "T", "jsonschema", _SCHEMA) for tok in ("rec", "ctl")
    ]

    def subscribed() -> bool:  # the batches come once the client has both channels
        return connected.is_set() and all(ch.has_sinks() for ch in channels)

    th = _serve_in_thread(rx, packets, subscribed)
    frames, _ = _app_like_client(view, connected, want=len(times), until_time=1_200)
    th.join(GUARD_S)
    a.close()
    b.close()
    clock = [t for op, t in frames if op == _TIME_OP]
    assert clock == [1_000, 1_100, 1_200]  # never back to 700 or 800
    assert sorted(t for op, t in frames if op == 1) == [700, 800, 1_000, 1_100, 1_200]
    assert view.time_ns == 1_200


def test_the_app_gets_foxglove_sdk_v1_and_an_app_offering_only_the_old_subprotocol_is_refused(
    view: LiveView,
) -> None:
    # foxglove-sdk 0.30.3 speaks foxglove.sdk.v1 only; docs/logs.md names the app versions
    with connect(view.url, subprotocols=APP_SUBPROTOCOLS) as ws:  # type: ignore[arg-type]
        assert ws.subprotocol == "foxglove.sdk.v1"
        info = json.loads(ws.recv(timeout=5))
        assert info["op"] == "serverInfo" and info["capabilities"] == ["time"]
    with pytest.raises(InvalidStatus, match="400"):
        connect(view.url, subprotocols=["foxglove.websocket.v1"], open_timeout=5)  # type: ignore[list-item]


class _CallLog:
    """Stands in for a LiveView: records what a FeedReceiver asks of it, in order."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, int]] = []
        self._topics: set[str] = set()
        #: topics a client subscribes to (none unless a test says so)
        self.subscribed: set[str] = set()

    def has(self, topic: str) -> bool:
        return topic in self._topics

    def subscribed_to(self, topic: str) -> bool:
        return topic in self.subscribed

    def channel(self, topic: str, *_: Any) -> Any:
        self._topics.add(topic)
        return _FakeChannel(topic)

    def log(self, _ch: Any, _data: bytes, t: int) -> None:
        self.calls.append(("log", t))

    def time(self, t: int) -> None:
        self.calls.append(("time", t))


class _FakeChannel:
    def __init__(self, topic: str) -> None:
        self._topic = topic

    def topic(self) -> str:
        return self._topic


def test_a_batch_sets_the_clock_to_its_latest_log_time_before_its_messages() -> None:
    # Foxglove stamps a message with the last time it was told: before the first one, 1970
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    view = _CallLog()
    rx = FeedReceiver(a, cast(LiveView, view), hold_s=0)
    rx.take(_new_channel_with_a_burst("rec", "/t", 5_000, 3))
    a.close()
    b.close()
    assert view.calls == [("time", 5_002), ("log", 5_000), ("log", 5_001), ("log", 5_002)]


def test_a_new_channels_messages_are_held_then_served_in_order() -> None:
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    view = _CallLog()
    rx = FeedReceiver(a, cast(LiveView, view), hold_s=0.5)
    rx.take(_new_channel_with_a_burst("rec", "/t", 5_000, 3))
    assert view.calls == [("time", 5_002)] and rx.holding()
    rx.release(time.monotonic())  # synthetic time: not yet due
    assert rx.holding()
    rx.release(time.monotonic() + 1.0)
    assert view.calls[1:] == [("log", 5_000), ("log", 5_001), ("log", 5_002)]
    assert not rx.holding() and rx.stats.messages == 3
    a.close()
    b.close()


def test_a_held_channel_goes_out_as_soon_as_a_client_subscribes_to_it() -> None:
    """Holding it longer would only grow its burst past a client's backlog."""
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    view = _CallLog()
    rx = FeedReceiver(a, cast(LiveView, view), hold_s=60.0)
    rx.take(_new_channel_with_a_burst("rec", "/t", 5_000, 3))
    rx.release(time.monotonic())
    assert rx.holding()  # nobody subscribed, a minute to go
    view.subscribed.add("/t")
    rx.release(time.monotonic())
    assert view.calls[1:] == [("log", 5_000), ("log", 5_001), ("log", 5_002)]
    assert not rx.holding()
    a.close()
    b.close()
