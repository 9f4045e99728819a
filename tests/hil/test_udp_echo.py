"""udp_multicast without the echo of a bus's own frames (tools.bus.transport.EchoFreeUdpMulticastBus),
checked in a private network namespace against python-can's own udp_multicast bus."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tools.bus import transport

pytestmark = pytest.mark.hil

SANDBOX_OK, SANDBOX_WHY = transport.sandbox_supported()

_SCRIPT = """
import json, time, can
from tools.bus.transport import EchoFreeUdpMulticastBus, open_bus, resolve
ch = "239.74.163.9"
a = open_bus(resolve("udp_multicast", ch))
b = EchoFreeUdpMulticastBus(ch)
plain = can.Bus(interface="udp_multicast", channel=ch)
def drain(bus):
    out, wait = [], 0.3
    while (m := bus.recv(wait)) is not None:
        out.append([m.arbitration_id, bytes(m.data).hex()])
        wait = 0.05
    return out
same = can.Message(arbitration_id=0x21, data=b"\\x01", is_extended_id=False)
a.send(same)
a.send(same)  # the same frame twice, without a timestamp
a.send(can.Message(arbitration_id=0x22, data=b"\\x02", is_extended_id=False))
a._awaited.appendleft(b"an echo lost on the way back")
plain.send(can.Message(arbitration_id=0x30, data=b"\\x03", is_extended_id=False))
time.sleep(0.2)
first = a.recv(0.0)  # a poll: behind a's three echoes, plain's frame
first = [first.arbitration_id, bytes(first.data).hex()] if first else None
b.send(can.Message(arbitration_id=0x40, data=b"\\x04", is_extended_id=False))
print(json.dumps({
    "type": type(a).__name__, "first": first, "a": drain(a), "b": drain(b), "plain": drain(plain),
    "a_dropped": a.echoes_dropped, "b_dropped": b.echoes_dropped, "a_awaited": len(a._awaited),
}))
for bus in (a, b, plain):
    bus.shutdown()
"""


@pytest.mark.skipif(not SANDBOX_OK, reason=f"no private network namespace: {SANDBOX_WHY}")
def test_a_udp_multicast_bus_gets_every_frame_but_its_own() -> None:
    res = subprocess.run(
        [sys.executable, "-m", "tools.cli", "sandbox", "--", sys.executable, "-c", _SCRIPT],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert res.returncode == 0, res.stderr
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert got["type"] == "EchoFreeUdpMulticastBus"  # what open_bus gives every part of a run
    a_sent = [[0x21, "01"], [0x21, "01"], [0x22, "02"]]
    assert got["first"] == [0x30, "03"]  # a poll passes over the echoes to the next frame
    assert got["a"] == [[0x40, "04"]]  # the others' frames, none of its own
    assert got["b"] == [*a_sent, [0x30, "03"]]
    assert got["plain"] == [*a_sent, [0x30, "03"], [0x40, "04"]]  # python-can's bus: all
    assert (got["a_dropped"], got["b_dropped"]) == (3, 1)
    assert got["a_awaited"] == 0  # the lost echo was given up when a later one came back
