"""The writers' side of the live view: a bounded, drop-oldest queue that never blocks."""

from __future__ import annotations

import io
import socket
from collections.abc import Iterator
from pathlib import Path

import msgpack
import pytest

from dbc.runtime.mcapwriter import LogWriter
from tools.live.address import LiveAddress
from tools.live.feed import OP_CHANNEL, OP_MESSAGE, OP_SCHEMA, LiveFeed
from tools.live.server import LiveServer, LiveServerError
from tools.logs import mcap_io


@pytest.fixture
def view_socket(tmp_path: Path) -> Iterator[tuple[str, socket.socket]]:
    """A Unix datagram socket standing in for the view process."""
    path = str(tmp_path / "feed.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(2.0)
    yield path, sock
    sock.close()


def _ops(sock: socket.socket) -> tuple[int, list[list[object]]]:
    """Every op the feed sent (until the socket is quiet), and the last drop count it reported."""
    ops: list[list[object]] = []
    dropped = 0
    sock.settimeout(0.5)
    while True:
        try:
            packet = sock.recv(1 << 20)
        except TimeoutError:
            return dropped, ops
        _token, dropped, batch = msgpack.unpackb(packet, raw=False)
        ops.extend(batch)


def test_full_queue_drops_the_oldest_messages_and_counts_them(
    view_socket: tuple[str, socket.socket],
) -> None:
    path, sock = view_socket
    # the sender thread never wakes before close: the queue alone decides what is kept
    feed = LiveFeed(path, queue_size=3, interval_s=3600.0)
    feed.schema(1, "S", "jsonschema", b"{}")
    feed.channel(1, "/a", "json", 1)
    for t in range(5):
        feed.message(1, t, b'{"t":%d}' % t)
    assert feed.dropped_full == 2
    feed.close()
    dropped, ops = _ops(sock)
    assert ops[0] == [OP_SCHEMA, 1, "S", "jsonschema", b"{}"]
    assert ops[1] == [OP_CHANNEL, 1, "/a", "json", 1]
    assert [op for op in ops if op[0] == OP_MESSAGE] == [
        [OP_MESSAGE, 1, t, b'{"t":%d}' % t] for t in (2, 3, 4)
    ]
    assert dropped == 2
    assert feed.sent == 3


def test_schemas_and_channels_are_never_dropped(view_socket: tuple[str, socket.socket]) -> None:
    path, sock = view_socket
    feed = LiveFeed(path, queue_size=1, interval_s=3600.0)
    for i in range(1, 6):
        feed.schema(i, f"S{i}", "jsonschema", b"{}")
        feed.channel(i, f"/c{i}", "json", i)
        feed.message(i, i, b"{}")
    feed.close()
    _, ops = _ops(sock)
    assert [op[2] for op in ops if op[0] == OP_CHANNEL] == [f"/c{i}" for i in range(1, 6)]
    assert [op[1] for op in ops if op[0] == OP_MESSAGE] == [5]
    assert feed.dropped_full == 4


def test_a_missing_view_costs_the_writer_nothing_but_a_count(tmp_path: Path) -> None:
    feed = LiveFeed(str(tmp_path / "nobody.sock"), interval_s=3600.0)
    feed.schema(1, "S", "jsonschema", b"{}")
    feed.channel(1, "/a", "json", 1)
    for t in range(10):
        feed.message(1, t, b"{}")
    feed.close()  # no exception: the batch is counted as dropped
    assert feed.dropped_send == 10
    assert feed.sent == 0


def test_messages_before_any_channel_or_after_close_are_ignored(tmp_path: Path) -> None:
    feed = LiveFeed(str(tmp_path / "x.sock"))
    feed.message(1, 0, b"{}")  # not started: nothing to do, nothing raised
    feed.close()
    feed.message(1, 0, b"{}")
    assert feed.dropped == 0


def test_queue_size_must_be_positive(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="queue_size=0"):
        LiveFeed(str(tmp_path / "x.sock"), queue_size=0)


def test_log_writer_mirror_gets_the_files_channels_and_bytes(
    view_socket: tuple[str, socket.socket],
) -> None:
    path, sock = view_socket
    buf = io.BytesIO()
    feed = LiveFeed(path, interval_s=3600.0)
    w = LogWriter(buf, mirror=feed)
    sid = w.register_schema("T", "jsonschema", b'{"type":"object"}')
    cid = w.register_channel("/topic", "json", sid)
    for t in range(3):
        w.add_message(cid, 1000 + t, 0, b'{"v":%d}' % t)
    w.close()  # closes the mirror too
    _, ops = _ops(sock)
    buf.seek(0)
    logged = [(ch.topic, m.log_time, bytes(m.data)) for ch, m in mcap_io.iter_messages(buf)]
    channels = {op[1]: op[2] for op in ops if op[0] == OP_CHANNEL}
    mirrored = [(channels[op[1]], op[2], op[3]) for op in ops if op[0] == OP_MESSAGE]
    assert mirrored == logged
    assert [op for op in ops if op[0] == OP_SCHEMA] == [
        [OP_SCHEMA, sid, "T", "jsonschema", b'{"type":"object"}']
    ]


@pytest.mark.parametrize(
    ("text", "host", "port"),
    [
        ("8765", "127.0.0.1", 8765),
        ("0", "127.0.0.1", 0),
        ("0.0.0.0:9000", "0.0.0.0", 9000),
        ("localhost:1", "localhost", 1),
        ("[::1]:9000", "::1", 9000),
        (":9000", "127.0.0.1", 9000),
    ],
)
def test_live_address_binds_localhost_unless_told(text: str, host: str, port: int) -> None:
    assert LiveAddress.parse(text) == LiveAddress(host, port)


@pytest.mark.parametrize(
    ("text", "why"), [("abc", "must be an integer"), ("1.2.3.4:70000", "outside 0..65535")]
)
def test_live_address_errors_name_the_text_and_the_rule(text: str, why: str) -> None:
    with pytest.raises(ValueError, match=why) as err:
        LiveAddress.parse(text)
    assert repr(text) in str(err.value)


def test_an_attached_view_needs_a_socket_path() -> None:
    with pytest.raises(LiveServerError, match="--live-feed: no socket path"):
        LiveServer.attached("")
    assert LiveServer.attached("/x/feed.sock").feed().socket_path == "/x/feed.sock"
