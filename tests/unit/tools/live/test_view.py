"""The view process's side: feeds' datagrams into foxglove-sdk's server, for a real client."""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Iterator

import msgpack
import pytest
from websockets.sync.client import connect

from tools.live.client import SUBPROTOCOL, LiveClient
from tools.live.feed import OP_CHANNEL, OP_MESSAGE, OP_SCHEMA
from tools.live.view import FeedReceiver, LiveView, LiveViewError


@pytest.fixture
def view() -> Iterator[LiveView]:
    v = LiveView("127.0.0.1", 0)
    yield v
    v.close()


def _packet(token: str, dropped: int, ops: list[list[object]]) -> bytes:
    return msgpack.packb([token, dropped, ops], use_bin_type=True)


def test_feeds_channels_reach_a_client_with_their_schema_and_bytes(view: LiveView) -> None:
    a, _ = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    rx = FeedReceiver(a, view)
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
    deadline = time.monotonic() + 10.0
    while not view.subscribed() and time.monotonic() < deadline:
        time.sleep(0.01)  # until the server has taken the subscription
    assert view.subscribed()
    rx.take(_packet("f1", 3, [[OP_MESSAGE, 4, 1_000 + i, b'{"i":%d}' % i] for i in range(5)]))
    rx.take(b"not msgpack at all \xc1")
    rx.take(_packet("f1", 3, [[OP_MESSAGE, 99, 0, b"{}"]]))  # a channel never announced
    deadline = time.monotonic() + 10.0
    while len(client.received.messages) < 5 and time.monotonic() < deadline:
        time.sleep(0.01)
    view.close()  # the client sees the connection close
    received = client.join(10.0)
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
    rx = FeedReceiver(a, view)
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
            deadline = time.monotonic() + 10.0
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
