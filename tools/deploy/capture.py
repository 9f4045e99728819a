"""What the doctor hears on the bus: it asks the drives what they answer without acting, and listens.

:func:`listen` sends only requests a drive answers without acting on them: RTRs (Get_Error,
and Get_Version where the wire contract has that frame) and RxSdo *reads* (opcode 0) of the
wire-contract hash, which a drive answers without authentication; no setpoint, no state
request, no configuration, no Host_Heartbeat.  For the window it listens to everything: the
drives' heartbeats and encoder estimates, other hosts, and every frame for the bus load
(:class:`Capture`).  :mod:`tools.deploy.bus_checks` judges what was heard.
"""

from __future__ import annotations

import contextlib
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import can

from dbc.codec import (
    DRIVES,
    Cmd,
    Codec,
    EncoderEstimates,
    GetError,
    Heartbeat,
    HostHeartbeat,
    Node,
    RxSdo,
    SdoEndpoint,
    SdoOpcode,
    TxSdo,
)
from dbc.errors import CodecError, DecodeError
from dbc.nodemap import NodeMap
from dbc.runtime.busio import recv_dropping
from tools.bus import busload
from tools.deploy.host_checks import clocks


@dataclass
class Capture:
    """What the doctor heard in its window."""

    seconds: float = 0.0
    frames: int = 0
    bits: int = 0
    #: node ID -> heartbeats: a drive's by its contract ID (the configured node IDs
    #: translated), others by the ID they came with (also IDs the contract does not know)
    heartbeats: dict[int, list[Heartbeat]] = field(default_factory=dict)
    #: heartbeats on a drive's contract ID where the configuration puts that drive on another
    #: (wire node ID -> count): a drive the configuration does not expect there
    stranger_heartbeats: Counter[int] = field(default_factory=Counter)
    encoder: Counter[int] = field(default_factory=Counter)
    sdo: dict[tuple[int, int], int] = field(default_factory=dict)
    errors: dict[int, GetError] = field(default_factory=dict)
    versions: dict[int, dict[str, Any]] = field(default_factory=dict)
    host_heartbeats: int = 0
    bench_frames: int = 0
    bench_bits: int = 0
    rx_dropped: dict[str, int] = field(default_factory=dict)
    send_failed: list[str] = field(default_factory=list)
    #: (monotonic, monotonic raw) ns at the window's start and end
    clocks: list[tuple[int, int]] = field(default_factory=list)


def listen(
    bus: can.BusABC,
    codec: Codec,
    window_s: float,
    *,
    check_version: bool,
    nodes: NodeMap | None = None,
) -> Capture:
    """Ask the drives for what they answer without acting, and listen for ``window_s``;
    ``nodes``: the drives' configured node IDs (frames translated as the controller does)."""
    nodes = nodes or NodeMap()
    cap = Capture()
    cap.clocks.append(clocks())
    requests = [(n, nodes.to_wire(m)) for n, m in _requests(codec, check_version)]
    _send_all(bus, requests, cap)
    t0 = time.monotonic()
    end = t0 + window_s
    resent = False
    while (now := time.monotonic()) < end:
        if not resent and now - t0 >= window_s / 2:
            resent = True  # once more for a drive that was still booting
            unanswered = [(n, m) for n, m in requests if not _answered(cap, n, m, codec, nodes)]
            _send_all(bus, unanswered, cap)
        msg = recv_dropping(bus, min(0.05, end - now), cap.rx_dropped)
        if msg is not None:
            _take(cap, msg, codec, nodes)
    cap.seconds = time.monotonic() - t0
    cap.clocks.append(clocks())
    return cap


def _requests(codec: Codec, check_version: bool) -> list[tuple[Node, can.Message]]:
    out: list[tuple[Node, can.Message]] = []
    for n in DRIVES:
        out.append((n, codec.encode(RxSdo(SdoOpcode.READ, SdoEndpoint.CONTRACT_HASH), n)))
        out.append((n, codec.request(GetError, n)))
        vid = version_id(codec, n)
        if check_version and vid is not None:
            out.append(
                (
                    n,
                    can.Message(
                        arbitration_id=vid, is_remote_frame=True, dlc=8, is_extended_id=False
                    ),
                )
            )
    return out


def _answered(cap: Capture, node: Node, msg: can.Message, codec: Codec, nodes: NodeMap) -> bool:
    if msg.is_remote_frame:
        vid = version_id(codec, node)
        if vid is not None and msg.arbitration_id == nodes.wire_frame_id(vid):
            return int(node) in cap.versions
        return int(node) in cap.errors
    return (int(node), int(SdoEndpoint.CONTRACT_HASH)) in cap.sdo


def _send_all(bus: can.BusABC, msgs: list[tuple[Node, can.Message]], cap: Capture) -> None:
    for _n, m in msgs:
        try:
            bus.send(m)
        except (can.CanError, OSError) as err:
            cap.send_failed.append(f"0x{m.arbitration_id:03X}: {err}")


def version_id(codec: Codec, node: Node) -> int | None:
    """The Get_Version frame's ID for ``node`` if the wire contract has one (ODrive cmd 0x00)."""
    prefix = codec.message_name(Heartbeat, node).split("_", 1)[0]
    try:
        frame_id, _ext = codec.frame_key(f"{prefix}_Get_Version")
    except CodecError:
        return None
    return frame_id


def _take(cap: Capture, msg: can.Message, codec: Codec, nodes: NodeMap | None = None) -> None:
    cap.frames += 1
    n_bytes = 0 if msg.is_remote_frame else len(msg.data)
    cap.bits += busload.frame_bits(n_bytes, msg.is_extended_id)
    if msg.is_extended_id:
        cap.bench_frames += 1
        cap.bench_bits += busload.frame_bits(n_bytes, True)
        return
    if msg.is_remote_frame or msg.is_error_frame:
        return
    if nodes:
        seen = nodes.from_wire(msg)
        if seen is None:  # a drive's contract ID, where the configuration puts it elsewhere
            if msg.arbitration_id & 0x1F == Cmd.HEARTBEAT:
                cap.stranger_heartbeats[msg.arbitration_id >> 5] += 1
            return
        msg = seen
    node_id, cmd = msg.arbitration_id >> 5, msg.arbitration_id & 0x1F
    for n in DRIVES:
        if msg.arbitration_id == version_id(codec, n):
            with contextlib.suppress(DecodeError):
                cap.versions[int(n)] = dict(codec.decode_signals(msg)[1])
            return
    try:
        frame = codec.decode(msg)
    except DecodeError:
        if cmd == Cmd.HEARTBEAT and node_id not in (int(n) for n in Node):
            # a node the contract does not know: read its heartbeat as a drive's would be
            hb = _as_drive_frame(msg, codec)
            if isinstance(hb, Heartbeat):
                cap.heartbeats.setdefault(node_id, []).append(hb)
        return
    p = frame.payload
    if isinstance(p, Heartbeat) and frame.node is not None:
        cap.heartbeats.setdefault(int(frame.node), []).append(p)
    elif isinstance(p, EncoderEstimates) and frame.node is not None:
        cap.encoder[int(frame.node)] += 1
    elif isinstance(p, TxSdo) and frame.node is not None:
        cap.sdo[(int(frame.node), p.endpoint_id)] = p.value
    elif isinstance(p, GetError) and frame.node is not None:
        cap.errors[int(frame.node)] = p
    elif isinstance(p, HostHeartbeat):
        cap.host_heartbeats += 1


def _as_drive_frame(msg: can.Message, codec: Codec) -> object:
    """Decode a frame of an unknown node as if the left drive had sent it."""
    alias = can.Message(
        arbitration_id=(int(Node.LEFT) << 5) | (msg.arbitration_id & 0x1F),
        data=msg.data,
        dlc=msg.dlc,
        is_extended_id=False,
    )
    try:
        return codec.decode(alias).payload
    except DecodeError:
        return None
