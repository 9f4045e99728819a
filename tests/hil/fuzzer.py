"""Sends random and mutated datagrams onto a udp_multicast bus while a run is going on.

    python -m tests.hil.fuzzer --count 100000 --report fuzz.json   (inside a sandbox)

Refuses to run outside a private network namespace.  It waits until it has seen the
bench's traffic (``--wait-for`` datagrams), then sends ``--count`` datagrams in bursts,
each of one kind:

* ``transport``: no CAN frame python-can can unpack (random bytes, truncated msgpack, a
  map that is no frame, a DLC 0 frame carrying 8 bytes, a 12-byte classic frame, an
  11-bit ID beyond 0x7FF, a field python-can's Message does not have, a bad type);
* ``unknown_id``: a well-formed standard frame on an ID the DBC does not define;
* ``length``: a well-formed frame on a drive-command ID with a length the DBC refuses.

Each is unpacked the way python-can will before it is sent, so its kind is certain (an
FD frame, which a classic bus cannot carry, or one whose flag is no boolean (``is_fd =
66``, which python-can accepts), counts as ``transport`` and in ``fd_or_flag``).  When
the namespace's UDP receive-buffer drops grow, the fuzzer slows down; and before each burst
it waits while any socket on the bus's port holds more than ``--max-backlog`` bytes unread
(``/proc/net/udp``), so that a receiver the scheduler leaves waiting is not flooded past its
receive buffer (a real frame lost with the fuzz would make the recorder's log partial).

None of them may reach a drive: the run's tracking figures must equal a clean run's.
The report says how many of each kind were sent, and whether the bench was still
running (no ``Bench_End`` seen) when the last one went out.
"""

from __future__ import annotations

import argparse
import json
import random
import socket
import struct
import time
from pathlib import Path
from typing import Any

import can
import msgpack
from can.interfaces.udp_multicast.utils import unpack_message

from dbc.codec import BenchEnd, Codec, Node, SetInputVel
from tools.bus import transport

PORT = 43113  # python-can's udp_multicast default
_FLAGS = (
    "is_extended_id",
    "is_remote_frame",
    "is_error_frame",
    "is_fd",
    "bitrate_switch",
    "error_state_indicator",
)


def _frame(**fields: Any) -> dict[str, Any]:
    base: dict[str, Any] = {
        "timestamp": time.time(),
        "arbitration_id": 0x7E0,
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
    return base


def _pack(d: Any) -> bytes:
    return msgpack.packb(d, use_bin_type=True)


class Fuzz:
    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)
        codec = Codec.default()
        self.unknown_std = [
            i
            for i in range(0x7FF + 1)
            if not codec.is_known(can.Message(arbitration_id=i, is_extended_id=False))
        ]
        self.cmd_ids = [codec.frame_id(SetInputVel, n) for n in (Node.LEFT, Node.RIGHT)]
        self.sent: dict[str, int] = {"transport": 0, "unknown_id": 0, "length": 0}

    def transport(self) -> bytes:
        r = self.rng
        k = r.randrange(9)
        if k == 0:
            return r.randbytes(r.randrange(0, 64))
        if k == 1:
            good = _pack(_frame())
            return good[: r.randrange(1, len(good))]  # truncated msgpack
        if k == 2:
            return _pack([r.random() for _ in range(r.randrange(5))])
        if k == 3:
            return _pack(_frame(dlc=0, data=r.randbytes(8)))
        if k == 4:
            return _pack(_frame(dlc=12, data=r.randbytes(12)))
        if k == 5:
            return _pack(_frame(arbitration_id=r.randrange(0x800, 0x10000)))
        if k == 6:
            return _pack(_frame(colour="red"))
        if k == 7:
            return _pack(_frame(dlc="eight"))
        # one byte of a good datagram flipped until it no longer unpacks into a frame
        good = bytearray(_pack(_frame(dlc=9, data=bytes(9))))
        good[r.randrange(len(good))] ^= 1 << r.randrange(8)
        return bytes(good)

    def unknown_id(self) -> bytes:
        r = self.rng
        n = r.randrange(9)
        return _pack(_frame(arbitration_id=r.choice(self.unknown_std), dlc=n, data=r.randbytes(n)))

    def length(self) -> bytes:
        r = self.rng
        n = r.choice([0, 1, 2, 3, 5, 7])  # Set_Input_Vel is 8 bytes
        return _pack(_frame(arbitration_id=r.choice(self.cmd_ids), dlc=n, data=r.randbytes(n)))

    def next(self) -> bytes:
        """One datagram, of a kind checked the way every receiver will see it."""
        while True:
            kind = self.rng.choices(("transport", "unknown_id", "length"), (8, 1, 1))[0]
            data: bytes = getattr(self, kind)()
            try:
                # as a receiver does: it replaces the timestamp with its receive time first
                msg = unpack_message(data, replace={"timestamp": 1.0}, check=True)
            except Exception:  # python-can cannot unpack it: what "transport" means
                if kind != "transport":
                    continue
            else:
                flags_ok = all(type(getattr(msg, f)) is bool for f in _FLAGS)
                if kind == "transport" and not msg.is_fd and flags_ok:
                    continue  # a mutation that happens to be a valid classic frame: redraw
                if msg.is_fd or not flags_ok:  # FD on a classic bus, is_fd = 66: no frame
                    self.sent["fd_or_flag"] = self.sent.get("fd_or_flag", 0) + 1
            self.sent[kind] += 1
            return data


def _listener(group: str) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
    s.bind(("", PORT))
    mreq = struct.pack("4s4s", socket.inet_aton(group), socket.inet_aton("0.0.0.0"))
    s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
    s.setblocking(False)
    return s


def rcvbuf_errors() -> int:
    """The namespace's UDP receive-buffer drops so far (``/proc/net/snmp``)."""
    lines = [ln.split() for ln in Path("/proc/net/snmp").read_text().splitlines()]
    udp = [ln for ln in lines if ln and ln[0] == "Udp:"]
    return int(udp[1][udp[0].index("RcvbufErrors")])


def backlog(port: int = PORT) -> int:
    """The most bytes any UDP socket bound to ``port`` holds unread (``/proc/net/udp``)."""
    worst = 0
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            f = row.split()
            if len(f) > 4 and int(f[1].rsplit(":", 1)[1], 16) == port:
                worst = max(worst, int(f[4].split(":")[1], 16))
    return worst


def _bench_ended(sock: socket.socket, end_id: int) -> bool:
    """Drain the listener; True if a Bench_End went by."""
    ended = False
    while True:
        try:
            data = sock.recv(4096)
        except BlockingIOError:
            return ended
        try:
            d = msgpack.unpackb(data, raw=False)
        except Exception:  # our own fuzz comes back too
            continue
        if isinstance(d, dict) and d.get("arbitration_id") == end_id and d.get("is_extended_id"):
            ended = True


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=100_000)
    ap.add_argument("--group", default=transport.DEFAULT_MULTICAST_GROUP)
    ap.add_argument("--seed", type=int, default=17)
    ap.add_argument("--burst", type=int, default=16)
    ap.add_argument("--pause-s", type=float, default=0.002)
    ap.add_argument(
        "--max-backlog",
        type=int,
        default=2 * 1024 * 1024,
        help="bytes a receiver may hold unread before the next burst (the parts ask for 7.2 MB)",
    )
    ap.add_argument("--wait-for", type=int, default=2000, help="bus datagrams seen before fuzzing")
    ap.add_argument("--report", type=Path, required=True)
    a = ap.parse_args()
    if not transport.in_private_namespace():
        raise SystemExit("fuzzer: refusing to send multicast outside a private network namespace")
    end_id = Codec.default().frame_id(BenchEnd)
    listen = _listener(a.group)
    seen = 0
    give_up = time.monotonic() + 120
    while seen < a.wait_for and time.monotonic() < give_up:
        try:
            listen.recv(4096)
            seen += 1
        except BlockingIOError:
            time.sleep(0.001)
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
    fuzz = Fuzz(a.seed)
    ended_before_last = False
    t0 = time.monotonic()
    sent = 0
    drops0 = drops = rcvbuf_errors()
    pause = a.pause_s
    calm = 0
    waits = 0
    while sent < a.count:
        while backlog() > a.max_backlog and not ended_before_last:
            waits += 1
            ended_before_last = _bench_ended(listen, end_id)
            time.sleep(0.0005)
        if ended_before_last:
            break
        for _ in range(min(a.burst, a.count - sent)):
            out.sendto(fuzz.next(), (a.group, PORT))
            sent += 1
        if _bench_ended(listen, end_id):
            ended_before_last = True
            break
        now = rcvbuf_errors()
        if now != drops:  # a receiver fell behind: slow down (the counts must add up)
            drops, pause, calm = now, min(pause * 2, 0.02), 0
        else:
            calm += 1
            if calm >= 50 and pause > a.pause_s:  # caught up: speed up again
                pause, calm = max(a.pause_s, pause / 2), 0
        time.sleep(pause)
    report = {
        "sent": sent,
        "by_kind": fuzz.sent,
        "wall_s": time.monotonic() - t0,
        "bus_datagrams_seen_before": seen,
        "bench_running_at_last": not ended_before_last,
        "kernel_drops_while_fuzzing": rcvbuf_errors() - drops0,
        "final_pause_s": pause,
        "backlog_waits": waits,
    }
    a.report.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
