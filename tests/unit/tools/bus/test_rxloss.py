"""Receive-buffer sizing and the kernel's drop counter (tools.bus.rxloss), on plain UDP sockets."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from dbc.runtime.errors import BusError
from tools.bus import rxloss


class _SocketBus:
    """The one attribute :func:`rxloss.kernel_socket` looks for on a SocketCAN bus."""

    def __init__(self, sock: socket.socket) -> None:
        self.socket = sock


@pytest.fixture
def pair() -> Iterator[tuple[socket.socket, socket.socket]]:
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx.connect(rx.getsockname())
    yield rx, tx
    rx.close()
    tx.close()


def test_a_full_receive_queue_is_counted_as_kernel_drops(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    rx, tx = pair
    bus = _SocketBus(rx)
    got = rxloss.size_receive_buffer(bus, 2048)  # type: ignore[arg-type]
    assert got is not None and got <= 8192
    assert rxloss.kernel_drops(bus) == 0  # type: ignore[arg-type]
    for _ in range(200):
        tx.send(b"x" * 64)
    dropped = rxloss.kernel_drops(bus)  # type: ignore[arg-type]
    rx.setblocking(False)
    received = 0
    while True:
        try:
            rx.recv(128)
        except BlockingIOError:
            break
        received += 1
    assert dropped > 0
    assert received + dropped == 200


def test_the_default_buffer_holds_the_lock_step_window(
    pair: tuple[socket.socket, socket.socket], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(rxloss.RCVBUF_ENV, raising=False)
    got = rxloss.size_receive_buffer(_SocketBus(pair[0]))  # type: ignore[arg-type]
    # SO_RCVBUFFORCE where permitted; otherwise net.core.rmem_max caps it (and a warning says so)
    rmem_max = int(Path("/proc/sys/net/core/rmem_max").read_text())
    assert got is not None
    assert got >= rxloss.WINDOW_BUFFER_BYTES or got >= 2 * rmem_max


def test_a_bus_without_a_kernel_socket_drops_nothing() -> None:
    assert rxloss.kernel_socket(object()) is None  # type: ignore[arg-type]
    assert rxloss.kernel_drops(object()) == 0  # type: ignore[arg-type]
    assert rxloss.size_receive_buffer(object()) is None  # type: ignore[arg-type]


@pytest.mark.parametrize("value", ["12", "lots", str(2 << 30), "recorder=4096"])
def test_a_bad_buffer_override_names_the_variable_and_the_limit(
    value: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(rxloss.RCVBUF_ENV, value)
    with pytest.raises(BusError, match=rxloss.RCVBUF_ENV):
        rxloss.requested_buffer_bytes()


def test_a_buffer_override_can_name_one_part(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(rxloss.RCVBUF_ENV, "record=4096")
    assert rxloss.requested_buffer_bytes("record") == 4096
    assert rxloss.requested_buffer_bytes("sim") is None
    monkeypatch.setenv(rxloss.RCVBUF_ENV, "8192")
    assert rxloss.requested_buffer_bytes("control") == 8192
