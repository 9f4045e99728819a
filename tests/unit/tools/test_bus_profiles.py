"""One profile per transport the stack treats apart (tools.bus.transport.PROFILES): what
each module asks of a bus it asks of the profile, not of the interface's name."""

from __future__ import annotations

import pytest

from dbc.runtime.errors import BusError
from tools.bus import transport
from tools.deploy import interface_checks
from tools.deploy.check import Status


def test_each_transport_has_one_profile_and_any_other_interface_is_an_adapter() -> None:
    assert set(transport.PROFILES) == {"virtual", "udp_multicast", "socketcan"}
    assert transport.profile("pcan") is transport.ADAPTER and transport.ADAPTER.has_bitrate
    assert not transport.profile("virtual").between_processes
    assert transport.profile("udp_multicast").private_namespace
    assert transport.profile("socketcan").network_device


def test_the_default_channel_comes_from_the_profile_and_an_adapter_needs_one() -> None:
    assert transport.resolve("socketcan", None).channel == "can0"
    assert transport.resolve("virtual", None).channel == "wheelchair"
    with pytest.raises(BusError, match="needs a channel"):
        transport.resolve("pcan", None)


def test_the_doctor_checks_each_profile_and_an_adapter_honestly() -> None:
    virtual = transport.resolve("virtual", None)
    assert interface_checks.check_interface(virtual).status is Status.NA
    pcan = transport.resolve("pcan", "PCAN_USBBUS1")
    check = interface_checks.check_interface(pcan)
    assert check.status is Status.NA and "500000 bit/s" in check.detail
    assert interface_checks.bus_fix(pcan) == "check the adapter and its driver"
