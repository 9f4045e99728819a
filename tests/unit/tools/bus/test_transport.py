"""Transport selection and the udp_multicast namespace guard."""

from __future__ import annotations

from pathlib import Path

import can
import pytest

from dbc.runtime.errors import BusError, NamespaceError
from tools.bus import transport


def test_udp_multicast_is_refused_where_other_interfaces_exist(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(transport, "interfaces", lambda: ["eth0", "lo"])
    spec = transport.resolve("udp_multicast", None)
    with pytest.raises(
        NamespaceError, match=r"interfaces besides loopback \(eth0\).*--allow-network-multicast"
    ):
        transport.open_bus(spec)


def test_udp_multicast_override_skips_the_guard(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(transport, "interfaces", lambda: ["eth0", "lo"])
    spec = transport.resolve("udp_multicast", None, allow_network_multicast=True)
    transport.check_multicast_allowed(spec)  # no error


def test_loopback_only_namespace_is_private(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(transport, "interfaces", lambda: ["lo"])
    assert transport.in_private_namespace()
    transport.check_multicast_allowed(transport.resolve("udp_multicast", None))


def test_default_channels_follow_python_can(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CAN_INTERFACE", raising=False)
    monkeypatch.delenv("CAN_CHANNEL", raising=False)
    assert transport.resolve("udp_multicast", None).channel == "239.74.163.2"
    assert transport.resolve("socketcan", None).channel == "can0"


def test_environment_configures_the_bus_like_python_can(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", "bench7")
    spec = transport.resolve(None, None)
    assert (spec.interface, spec.channel) == ("virtual", "bench7")


def test_unknown_interface_is_a_clear_error() -> None:
    with pytest.raises(BusError, match=r"unknown bus 'pcann': python-can's interfaces are .*pcan"):
        transport.resolve("pcann", "PCAN_USBBUS1")


@pytest.mark.parametrize("name", ["pcan", "kvaser", "slcan", "gs_usb", "seeedstudio", "vector"])
def test_any_python_can_interface_is_accepted_with_bitrate_and_options(name: str) -> None:
    spec = transport.resolve(name, "ch0", bitrate=250_000, options={"fd": False, "serial": 7})
    assert (spec.interface, spec.channel, spec.bitrate) == (name, "ch0", 250_000)
    assert dict(spec.options) == {"fd": False, "serial": 7}


def test_a_hardware_interface_without_a_channel_or_with_a_bad_bitrate_is_a_clear_error() -> None:
    with pytest.raises(BusError, match="bus 'pcan' needs a channel"):
        transport.resolve("pcan", None)
    with pytest.raises(BusError, match=r"bitrate 5 bit/s is outside \[10000, 1000000\]"):
        transport.resolve("pcan", "PCAN_USBBUS1", bitrate=5)
    with pytest.raises(BusError, match="'channel' has its own flag"):
        transport.resolve("pcan", "PCAN_USBBUS1", options={"channel": "x"})


def test_bitrate_and_options_reach_python_can(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: dict[str, object] = {}

    def fake_bus(**kwargs: object) -> object:
        seen.update(kwargs)
        raise can.CanInterfaceNotImplementedError("no such hardware here")

    monkeypatch.setattr(can, "Bus", fake_bus)
    spec = transport.resolve("kvaser", "0", bitrate=500_000, options={"single_handle": True})
    with pytest.raises(BusError, match="cannot open kvaser channel 0: no such hardware here"):
        transport.open_bus(spec)
    assert seen == {
        "interface": "kvaser",
        "channel": "0",
        "bitrate": 500_000,
        "single_handle": True,
    }


def test_bus_options_are_cast_like_can_conf_and_reach_the_parts_unchanged() -> None:
    from tools.bus.transport import bus_argv, bus_options_of

    opts = bus_options_of(["fd=False", "data_bitrate=2000000", "serial=ABC"])
    assert opts == {"fd": False, "data_bitrate": 2_000_000, "serial": "ABC"}
    spec = transport.resolve("pcan", "PCAN_USBBUS1", bitrate=250_000, options=opts)
    argv = bus_argv(spec)
    assert argv[:6] == ["--bus", "pcan", "--channel", "PCAN_USBBUS1", "--bitrate", "250000"]
    with pytest.raises(BusError, match="expected KEY=VALUE"):
        bus_options_of(["fd"])


def test_socketcan_without_kernel_support_is_a_clear_error() -> None:
    ok, _why = transport.socketcan_available()
    if ok:
        pytest.skip("this kernel has SocketCAN; the error path cannot be exercised")
    with pytest.raises(
        BusError, match="cannot open socketcan channel vcan0: the kernel has no SocketCAN"
    ):
        transport.open_bus(transport.resolve("socketcan", "vcan0"))


def test_sandbox_command_prepares_loopback_multicast(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(transport.os, "geteuid", lambda: 1000)
    argv = transport.sandbox_argv(["echo", "hi"])
    assert argv[:5] == ["unshare", "--user", "--map-root-user", "--net", "--"]
    script = argv[argv.index("-c") + 1]
    assert "ip link set lo up" in script and "ip route add 224.0.0.0/4 dev lo" in script
    assert argv[-2:] == ["echo", "hi"]


def test_root_gets_a_network_namespace_without_a_user_namespace(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Root keeps its capabilities in the sandbox (a user namespace would drop SCHED_FIFO)."""
    monkeypatch.setattr(transport.os, "geteuid", lambda: 0)
    monkeypatch.setattr(transport, "_root_can_unshare", lambda: True)
    assert transport.sandbox_argv(["true"])[:3] == ["unshare", "--net", "--"]
    monkeypatch.setattr(transport, "_root_can_unshare", lambda: False)  # a container's root
    assert transport.sandbox_argv(["true"])[:4] == ["unshare", "--user", "--map-root-user", "--net"]


def test_the_virtual_bus_gives_every_receiver_its_own_copy_and_talks_to_plain_virtual_buses() -> (
    None
):
    import can

    spec = transport.resolve("virtual", "transport-test")
    sender = transport.open_bus(spec)
    ours = transport.open_bus(spec)
    plain = can.Bus(interface="virtual", channel="transport-test")
    try:
        assert isinstance(sender, transport.LightVirtualBus)
        sent = can.Message(arbitration_id=0x21, data=b"\x01\x02", is_extended_id=False)
        sender.send(sent)
        a, b = ours.recv(1.0), plain.recv(1.0)
        assert a is not None and b is not None
        for m in (a, b):
            assert (m.arbitration_id, bytes(m.data), m.dlc, m.is_extended_id, m.is_rx) == (
                0x21,
                b"\x01\x02",
                2,
                False,
                True,
            )
            assert m.channel == "transport-test" and m is not sent
        a.data[0] = 0xFF  # a receiver scribbling on its frame touches nobody else's
        assert b.data[0] == 1 and sent.data[0] == 1
        assert sender.recv(0.0) is None  # no own messages by default
        plain.send(can.Message(arbitration_id=0x41, data=b"\x05", is_extended_id=False))
        got = ours.recv(1.0)
        assert got is not None and got.arbitration_id == 0x41
    finally:
        for bus in (sender, ours, plain):
            bus.shutdown()


def test_virtual_bus_filters_apply_to_our_senders_and_to_plain_ones() -> None:
    import can

    spec = transport.resolve("virtual", "transport-filter-test")
    sender = transport.open_bus(spec)
    receiver = transport.open_bus(spec)
    plain = can.Bus(interface="virtual", channel="transport-filter-test")
    try:
        receiver.set_filters([{"can_id": 0x21, "can_mask": 0x7FF, "extended": False}])
        for bus in (sender, plain):
            for aid in (0x22, 0x21):
                bus.send(can.Message(arbitration_id=aid, data=b"\x01", is_extended_id=False))
            bus.send(can.Message(arbitration_id=0x21, data=b"\x02", is_extended_id=True))
        got = [receiver.recv(0.5), receiver.recv(0.5)]
        assert [(m.arbitration_id, m.is_extended_id) for m in got if m] == [(0x21, False)] * 2
        assert receiver.recv(0.0) is None and receiver.recv(0.02) is None
        # a mask filter (not an exact ID) is honoured too
        receiver.set_filters([{"can_id": 0x40, "can_mask": 0x7E0}])
        sender.send(can.Message(arbitration_id=0x21, data=b"", is_extended_id=False))
        sender.send(can.Message(arbitration_id=0x45, data=b"", is_extended_id=False))
        m = receiver.recv(0.5)
        assert m is not None and m.arbitration_id == 0x45
        receiver.set_filters(None)
        sender.send(can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False))
        m = receiver.recv(0.5)
        assert m is not None and m.arbitration_id == 0x7FF
    finally:
        for bus in (sender, receiver, plain):
            bus.shutdown()


def test_a_virtual_bus_listener_with_take_gets_every_frame_in_send_order() -> None:
    import can
    from can.interfaces.virtual import channels, channels_lock

    class Listener:
        def __init__(self) -> None:
            self.seen: list[tuple[int, bytes]] = []

        def take(self, msg: can.Message, timestamp: float) -> None:
            self.seen.append((msg.arbitration_id, bytes(msg.data)))

        def put(self, msg: can.Message, block: bool = True, timeout: float | None = None) -> None:
            self.take(msg, msg.timestamp)

    spec = transport.resolve("virtual", "transport-tap-test")
    a, b = transport.open_bus(spec), transport.open_bus(spec)
    plain = can.Bus(interface="virtual", channel="transport-tap-test")
    tap = Listener()
    with channels_lock:
        channels["transport-tap-test"].append(tap)
    try:
        a.send(can.Message(arbitration_id=1, data=b"a", is_extended_id=False))
        plain.send(can.Message(arbitration_id=2, data=b"p", is_extended_id=False))
        b.send(can.Message(arbitration_id=3, data=b"b", is_extended_id=False))
        assert tap.seen == [(1, b"a"), (2, b"p"), (3, b"b")]
        assert b.recv(0.5) is not None  # the other buses still get theirs
    finally:
        with channels_lock:
            channels["transport-tap-test"].remove(tap)
        for bus in (a, b, plain):
            bus.shutdown()


def test_the_virtual_bus_runs_its_idle_hook_only_where_recv_would_wait() -> None:
    import can

    spec = transport.resolve("virtual", "transport-idle-test")
    a, b = transport.open_bus(spec), transport.open_bus(spec)
    assert isinstance(a, transport.LightVirtualBus)
    calls: list[str] = []

    def answer() -> None:  # the other part of a one-thread run: it sends when it runs
        calls.append("idle")
        b.send(can.Message(arbitration_id=7, data=bytes([len(calls)]), is_extended_id=False))

    a.on_idle = answer
    try:
        b.send(can.Message(arbitration_id=1, data=b"q", is_extended_id=False))
        assert a.recv(1.0).arbitration_id == 1  # a frame was there: no hook
        assert calls == []
        assert a.recv(0.0) is None  # a poll never waits, so never runs the hook
        assert calls == []
        msg = a.recv(1.0)  # would wait: the hook runs first and its frame is returned
        assert (msg.arbitration_id, bytes(msg.data)) == (7, b"\x01")
        assert calls == ["idle"]
        a.on_idle = calls.clear  # a hook that sends nothing: recv waits out its timeout
        assert a.recv(0.05) is None
    finally:
        a.shutdown()
        b.shutdown()


def test_a_namespace_refused_by_apparmor_names_the_setting(tmp_path: Path) -> None:
    knob = tmp_path / "apparmor_restrict_unprivileged_userns"
    knob.write_text("1\n")
    hint = transport.userns_hint(knob)
    assert "AppArmor" in hint and "kernel.apparmor_restrict_unprivileged_userns=0" in hint
    knob.write_text("0\n")
    assert transport.userns_hint(knob) == ""
    assert transport.userns_hint(tmp_path / "absent") == ""
