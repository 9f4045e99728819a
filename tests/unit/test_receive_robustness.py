"""No input kills a receive path: what is no frame is dropped, counted, and the
path goes on; a late real-time tick takes what has arrived before it judges staleness."""

from __future__ import annotations

from collections import deque
from typing import Any

import can
import msgpack
import pytest
from can.interfaces.udp_multicast import UdpMulticastBus

from controller.clock import LockstepClock, RealtimeClock
from controller.config import load_config
from controller.link import DriveLink
from controller.safety import SafetyMonitor, StopReason
from dbc.codec import DRIVES, AxisState, BenchStep, Codec, EncoderEstimates, Heartbeat, Node
from dbc.runtime import busio

CODEC = Codec.default()


def _datagram(**fields: Any) -> bytes:
    """A python-can udp_multicast datagram (its msgpack map), fields as given."""
    base: dict[str, Any] = {
        "timestamp": 1.0,
        "arbitration_id": 0x29,
        "is_extended_id": False,
        "is_remote_frame": False,
        "is_error_frame": False,
        "channel": None,
        "dlc": 8,
        "data": bytes(8),
        "is_fd": False,
        "bitrate_switch": False,
        "error_state_indicator": False,
    }
    base.update(fields)
    return msgpack.packb(base, use_bin_type=True)


def _good(msg: can.Message) -> bytes:
    return _datagram(
        arbitration_id=msg.arbitration_id,
        is_extended_id=msg.is_extended_id,
        dlc=msg.dlc,
        data=bytes(msg.data),
    )


class _Multicast:
    """Stands in for python-can's multicast socket: hands out queued datagrams."""

    def __init__(self, datagrams: list[bytes]) -> None:
        self.queue = deque(datagrams)

    def recv(self, timeout: float | None) -> tuple[bytes, Any, float] | None:
        return (self.queue.popleft(), None, 1.0) if self.queue else None


class _UdpLike(can.BusABC):
    """python-can's own udp_multicast receive path (its ``_recv_internal``) on queued datagrams."""

    _recv_internal = UdpMulticastBus._recv_internal  # type: ignore[assignment]

    def __init__(self, datagrams: list[bytes]) -> None:
        self._multicast = _Multicast(datagrams)
        super().__init__(channel="udp-like")
        self._can_protocol = can.CanProtocol.CAN_20

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass


BAD = {
    "dlc0_with_8_bytes": _datagram(dlc=0),
    "classic_12_bytes": _datagram(dlc=12, data=bytes(12)),
    "not_msgpack": b"\xc1\xff\x00garbage",
    "unknown_field": _datagram(colour="red"),
    "not_a_map": msgpack.packb([1, 2, 3]),
    "extended_id_too_large": _datagram(is_extended_id=True, arbitration_id=1 << 30),
}


def test_python_cans_own_udp_receive_raises_on_each_bad_datagram() -> None:
    # the failure being guarded against: python-can raises, it does not drop
    for name, data in BAD.items():
        bus = _UdpLike([data])
        try:
            with pytest.raises(can.CanOperationError, match="could not unpack"):
                bus.recv(0)
        finally:
            bus.shutdown()
        assert name


def test_each_bad_datagram_is_dropped_by_reason_and_the_good_frame_behind_it_arrives() -> None:
    good = CODEC.encode(EncoderEstimates(1.0, 0.5), Node.LEFT)
    bus = _UdpLike([*BAD.values(), _good(good)])
    dropped: dict[str, int] = {}
    try:
        msg = busio.recv_dropping(bus, 0.0, dropped)
    finally:
        bus.shutdown()
    assert msg is not None and msg.arbitration_id == good.arbitration_id
    assert bytes(msg.data) == bytes(good.data)
    assert dropped == {
        busio.RX_INVALID_FRAME: 3,  # DLC 0 with 8 bytes, 12-byte classic frame, 30-bit ID
        busio.RX_UNDECODABLE: 2,  # not msgpack, not a map
        busio.RX_BAD_FIELDS: 1,  # a field python-can's Message does not have
    }


def test_a_broken_bus_is_counted_and_gives_none_without_raising() -> None:
    class _Broken(can.BusABC):
        def __init__(self) -> None:
            super().__init__(channel="broken")

        def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
            raise OSError(9, "Bad file descriptor")

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            pass

    bus = _Broken()
    dropped: dict[str, int] = {}
    try:
        assert busio.recv_dropping(bus, 0.0, dropped) is None
    finally:
        bus.shutdown()
    assert dropped == {"rx_os_error_EBADF": 1}


def test_an_interface_that_went_down_is_counted_as_a_bus_error_by_its_errno() -> None:
    """SocketCAN wraps the OSError of a receive on a downed interface in a CanOperationError."""

    class _Down(can.BusABC):
        def __init__(self) -> None:
            super().__init__(channel="vcan0")

        def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
            try:
                raise OSError(100, "Network is down")
            except OSError as error:
                raise can.CanOperationError("Error receiving: Network is down", 100) from error

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            pass

    bus = _Down()
    dropped: dict[str, int] = {}
    try:
        assert busio.recv_dropping(bus, 0.0, dropped, monotonic=True) is None
    finally:
        bus.shutdown()
    assert dropped == {"rx_os_error_ENETDOWN": 1}


def test_the_lockstep_clock_ticks_on_the_step_behind_a_flood_of_bad_datagrams() -> None:
    step = CODEC.encode(BenchStep(10_000_000))
    enc = CODEC.encode(EncoderEstimates(2.0, 0.0), Node.RIGHT)
    junk = list(BAD.values()) * 50
    bus = _UdpLike([*junk, _good(enc), *junk, _good(step)])
    frames: list[can.Message] = []
    try:
        clock = LockstepClock(bus, 10_000_000, codec=CODEC, wait=False)
        clock.start()
        t = clock.wait_tick(frames.append)
    finally:
        bus.shutdown()
    assert t == 10_000_000
    assert [m.arbitration_id for m in frames] == [enc.arbitration_id]
    assert sum(clock.stats.rx_invalid.values()) == 2 * len(junk)


# ----------------------------------------------------- staleness while the host is late


class _Time:
    def __init__(self) -> None:
        self.mono_ns = 5_000_000_000


class _DrivesBus(can.BusABC):
    """Both drives' encoder estimates every 10 ms (heartbeats every 100 ms) of synthetic time, queued as they are
    sent whether or not the host is reading (as a socket's receive buffer does)."""

    def __init__(self, clock: _Time) -> None:
        self._clock = clock
        self._next_ns = clock.mono_ns
        self._k = 0
        self._queue: deque[can.Message] = deque()
        super().__init__(channel="drives")

    def _produce(self) -> None:
        while self._next_ns <= self._clock.mono_ns:
            for n in DRIVES:
                self._queue.append(CODEC.encode(EncoderEstimates(0.0, 0.0), n))
                if self._k % 10 == 0:
                    hb = Heartbeat(0, AxisState.CLOSED_LOOP_CONTROL)
                    self._queue.append(CODEC.encode(hb, n))
            self._k += 1
            self._next_ns += 10_000_000

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self._produce()
        if not self._queue and timeout:
            self._clock.mono_ns = min(self._clock.mono_ns + round(timeout * 1e9), self._next_ns)
            self._produce()
        return (self._queue.popleft() if self._queue else None), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass


def _run_host(monkeypatch: Any, stall_ms: int) -> tuple[StopReason, SafetyMonitor, RealtimeClock]:
    """200 real-time ticks; at tick 100 the host is not scheduled for ``stall_ms``."""
    clock = _Time()
    monkeypatch.setattr("controller.clock.time.monotonic_ns", lambda: clock.mono_ns)
    bus = _DrivesBus(clock)
    link = DriveLink(bus, CODEC)
    cfg = load_config()
    safety = SafetyMonitor(cfg.safety, 10_000_000)
    first = StopReason.NONE
    try:
        rt = RealtimeClock(bus, 10_000_000)
        rt.start()
        for k in range(200):
            t = rt.wait_tick(link.on_frame)
            assert t is not None
            if k == 0:
                safety.reset_timers(t)
            safety.observe(link, t)
            reason = safety.check(link, t, tracking=False, commanded_radps={})
            if reason != StopReason.NONE and first == StopReason.NONE:
                first = reason
            if k == 100:
                clock.mono_ns += stall_ms * 1_000_000  # the host's tick ran long
    finally:
        bus.shutdown()
    return first, safety, rt


def test_a_host_that_was_late_does_not_judge_the_drives_stale(monkeypatch: Any) -> None:
    # 68 ms: the worst tick of the loaded real-time runs (tests/repro/realtime_loaded.py); the drives never stopped sending
    first, safety, rt = _run_host(monkeypatch, stall_ms=68)
    assert rt.stats.missed_ticks == 5  # the loop was late (58 ms past the next tick), and says so
    assert first == StopReason.NONE
    assert safety.encoder_age_max_ns is not None and safety.encoder_age_max_ns <= 10_000_000


def test_drives_that_stop_sending_are_still_judged_stale(monkeypatch: Any) -> None:
    clock = _Time()
    monkeypatch.setattr("controller.clock.time.monotonic_ns", lambda: clock.mono_ns)
    bus = _DrivesBus(clock)
    link = DriveLink(bus, CODEC)
    safety = SafetyMonitor(load_config().safety, 10_000_000)
    tripped_at = None
    try:
        rt = RealtimeClock(bus, 10_000_000)
        rt.start()
        for k in range(100):
            t = rt.wait_tick(link.on_frame)
            assert t is not None
            if k == 0:
                safety.reset_timers(t)
            if k == 50:
                bus._next_ns = 1 << 62  # the drives fall silent after tick 50
            safety.observe(link, t)
            if (
                safety.check(link, t, tracking=False, commanded_radps={})
                == StopReason.ENCODER_STALE
            ):
                tripped_at = k
                break
    finally:
        bus.shutdown()
    # the last estimate was taken at tick 50; stale after 3 periods, i.e. at tick 54
    assert tripped_at == 54
