"""The doctor's checks of what it heard on the bus (:class:`~tools.deploy.capture.Capture`).

``drive left`` / ``drive right`` (heartbeat, axis state, error bits, encoder estimates),
``nodes`` (no heartbeat from a node ID the contract does not know, no other host), ``version``
(Get_Version), ``contract`` (the drives' wire-contract hash equals the host's) and ``busload``.
"""

from __future__ import annotations

from controller.config import ControllerConfig
from dbc.codec import (
    DRIVES,
    AxisError,
    AxisState,
    Cmd,
    Codec,
    EncoderEstimates,
    Heartbeat,
    Node,
    SdoEndpoint,
)
from dbc.nodemap import NodeMap
from tools.bus import busload, transport
from tools.bus.transport import BusSpec
from tools.deploy.capture import Capture, version_id
from tools.deploy.check import Check, Status

#: The drives' nominal bitrate (docs/architecture.md, "The wire").
NOMINAL_BITRATE = 500_000
#: A bus busier than this (worst-case stuffing) leaves too little room for a burst.
BUSLOAD_WARN_PCT = 50.0
BUSLOAD_FAIL_PCT = 80.0
#: Error bits of a latched stop (a watchdog or host-timeout expiry, an Estop): what the
#: person who starts the controller again decides to clear.  Any other bit is a fault.
LATCHED_STOPS = (
    AxisError.WATCHDOG_TIMER_EXPIRED | AxisError.MISSING_INPUT | AxisError.ESTOP_REQUESTED
)
_SIDE = {Node.LEFT: "left", Node.RIGHT: "right"}


def check_drive(cap: Capture, node: Node, codec: Codec, nodes: NodeMap | None = None) -> Check:
    """One drive: heartbeats, axis state, error bits, encoder estimates, Get_Error
    (``nodes``: the drives' configured node IDs, which the messages name)."""
    side = _SIDE[node]
    name = f"drive {side}"
    nodes = nodes or NodeMap()
    wire = nodes.wire_id(node)
    hb_id = nodes.wire_frame_id(codec.frame_id(Heartbeat, node))
    beats = cap.heartbeats.get(int(node), [])
    if not beats:
        strangers = _unknown_nodes(cap)
        if strangers:
            ids = ", ".join(f"{n} (0x{(n << 5) | Cmd.HEARTBEAT:03X})" for n in strangers)
            return Check(
                name,
                Status.FAIL,
                f"no heartbeat from node {wire} (0x{hb_id:03X}) in {cap.seconds:.1f} s; "
                f"a drive sends heartbeats as node {ids}: the {side} drive with another node ID?",
                f"either set drives.{side}_node_id = {strangers[0]} in the chair's config, or "
                f"that drive's node ID to {wire}: odrv.axis0.config.can.node_id = {wire}; "
                "odrv.save_configuration()",
            )
        return Check(
            name,
            Status.FAIL,
            f"no heartbeat from node {wire} (0x{hb_id:03X}) in {cap.seconds:.1f} s: the "
            f"{side} drive is not on the bus",
            "check its power and CAN wiring, its bitrate (500 kbit/s) and node ID "
            f"({wire}); candump shows who talks",
        )
    last = beats[-1]
    state = AxisState(last.axis_state).name
    rate = len(beats) / cap.seconds if cap.seconds else 0.0
    enc = cap.encoder.get(int(node), 0)
    enc_rate = enc / cap.seconds if cap.seconds else 0.0
    detail = (
        f"node {wire}: {state}, axis error 0x{last.axis_error:X}, "
        f"{rate:.0f} heartbeats/s, {enc_rate:.0f} encoder estimates/s"
    )
    err = cap.errors.get(int(node))
    if err is not None:
        detail += f", Get_Error active 0x{err.active_errors:X} disarm 0x{err.disarm_reason:X}"
    if last.axis_error & ~LATCHED_STOPS:
        return Check(
            name,
            Status.FAIL,
            f"{detail}: drive error {_error_names(last.axis_error)}",
            "a fault of the drive, motor or supply: find and fix it (odrivetool: "
            "dump_errors(odrv)); the controller would clear it when arming",
        )
    if last.axis_error:
        return Check(
            name,
            Status.WARN,
            f"{detail}: latched stop {_error_names(last.axis_error)}",
            "starting the controller clears it (Clear_Errors) and arms: do so only once the "
            "cause of the stop is understood (the last run's logs)",
        )
    if last.axis_state == AxisState.CLOSED_LOOP_CONTROL:
        return Check(
            name,
            Status.FAIL,
            f"{detail}: already armed, another host is driving it",
            "stop the other controller (systemctl stop wheelchair-hil) and idle the drive",
        )
    if enc == 0:
        exp = codec.cycle_time_ms(EncoderEstimates, node) or 10
        return Check(
            name,
            Status.FAIL,
            f"{detail}: no Get_Encoder_Estimates, the controller needs them every {exp} ms",
            f"ODrive: odrv.axis0.config.can.encoder_msg_rate_ms = {exp}",
        )
    if last.axis_state != AxisState.IDLE:
        return Check(name, Status.WARN, f"{detail}: not IDLE", "wait for its start-up to end")
    return Check(name, Status.OK, detail)


def _error_names(bits: int) -> str:
    names = [f.name for f in AxisError if f.value and bits & f.value and f.name]
    unknown = bits & ~sum(f.value for f in AxisError)
    if unknown:
        names.append(f"0x{unknown:X}")
    return "|".join(str(n) for n in names)


def _unknown_nodes(cap: Capture) -> list[int]:
    known = {int(n) for n in Node}
    return sorted({n for n in cap.heartbeats if n not in known} | set(cap.stranger_heartbeats))


def check_nodes(cap: Capture, codec: Codec, nodes: NodeMap | None = None) -> Check:
    """Heartbeats from node IDs neither the contract nor the configuration gives a drive;
    another host on the bus."""
    strangers = _unknown_nodes(cap)
    nodes = nodes or NodeMap()
    if strangers:
        left, right = nodes.wire_id(Node.LEFT), nodes.wire_id(Node.RIGHT)
        return Check(
            "nodes",
            Status.FAIL,
            "heartbeats from node " + ", ".join(map(str, strangers)) + ", where no drive is "
            f"expected (left = {left}, right = {right}: drives.left_node_id, right_node_id)",
            "give each drive the node ID the config names (odrv.axis0.config.can.node_id; "
            "save_configuration), or name the drives' IDs in the config",
        )
    if cap.host_heartbeats:
        return Check(
            "nodes",
            Status.FAIL,
            f"{cap.host_heartbeats} Host_Heartbeat frames: another controller is on the bus",
            "stop it before this one arms (systemctl stop wheelchair-hil)",
        )
    seen = sorted(cap.heartbeats)
    extra = f"; {cap.bench_frames} bench frames (emulated drives)" if cap.bench_frames else ""
    heard = f"heartbeats from node {', '.join(map(str, seen))} only" if seen else "no heartbeat"
    return Check("nodes", Status.OK, f"{heard}, no other host{extra}")


def check_version(cap: Capture, codec: Codec) -> Check:
    """Get_Version, where the wire contract has that frame."""
    present = [n for n in DRIVES if int(n) in cap.heartbeats]
    if not any(version_id(codec, n) is not None for n in DRIVES):
        return Check(
            "version",
            Status.WARN,
            f"drive did not answer Get_Version: {codec.path.name} has no Get_Version frame, so the "
            "firmware version is not read; the contract hash below checks the protocol",
        )
    missing = [n for n in present if int(n) not in cap.versions]
    found = "; ".join(
        f"{_SIDE[Node(n)]}: " + " ".join(f"{k}={v}" for k, v in sorted(sig.items()))
        for n, sig in sorted(cap.versions.items())
    )
    if missing:
        who = ", ".join(_SIDE[n] for n in missing)
        return Check(
            "version",
            Status.WARN,
            f"drive did not answer Get_Version ({who}){'; ' + found if found else ''}",
            "ODrive answers Get_Version from firmware 0.6.9 on: update the firmware",
        )
    if not cap.versions:
        return Check("version", Status.WARN, "no drive on the bus to ask for Get_Version")
    return Check("version", Status.OK, found)


def check_contract(cap: Capture, cfg: ControllerConfig, codec: Codec) -> Check:
    """The drives' wire-contract hash (RxSdo read of CONTRACT_HASH) equals the host's."""
    host = codec.contract_hash
    ep = int(SdoEndpoint.CONTRACT_HASH)
    if not cfg.auth.check_contract:
        return Check(
            "contract",
            Status.NA,
            f"auth.check_contract = false (a stock ODrive): host {host:08x} ({codec.path.name}) "
            "is not compared",
        )
    got = {n: cap.sdo.get((int(n), ep)) for n in DRIVES if int(n) in cap.heartbeats}
    if not got:
        return Check("contract", Status.FAIL, "not checked: no drive on the bus")
    wrong = {n: h for n, h in got.items() if h is not None and h != host}
    if wrong:
        what = ", ".join(f"{_SIDE[n]} {h:08x}" for n, h in wrong.items())
        return Check(
            "contract",
            Status.FAIL,
            f"host {host:08x} ({codec.path}), drive {what}: the controller would refuse to arm "
            "(CONTRACT_MISMATCH)",
            "flash the drives built from this DBC, or run with the DBC they were built from (--dbc)",
        )
    silent = [n for n, h in got.items() if h is None]
    if silent:
        return Check(
            "contract",
            Status.FAIL,
            f"{', '.join(_SIDE[n] for n in silent)} did not answer the RxSdo read of endpoint "
            f"0x{ep:04X}: the controller would refuse to arm",
            "a stock ODrive has no such endpoint: set auth.check_contract = false",
        )
    missing = [_SIDE[n] for n in DRIVES if n not in got]
    tail = f" (not asked: {', '.join(missing)} absent)" if missing else ""
    return Check(
        "contract",
        Status.OK,
        f"{' and '.join(_SIDE[n] for n in got)} {host:08x} = host's ({codec.path.name}){tail}",
    )


def check_busload(cap: Capture, spec: BusSpec) -> Check:
    """The load of what was heard, at the bus's bitrate, worst-case bit stuffing."""
    # an emulated bus has no bitrate: its load as the real bus would carry it
    real = not transport.profile(spec.interface).emulated
    bitrate = spec.bitrate if real else NOMINAL_BITRATE
    pct = busload.load_pct(cap.bits, cap.seconds, bitrate)
    where = "" if real else " (on a real bus)"
    detail = (
        f"{pct:.1f} % of {bitrate // 1000} kbit/s{where} over {cap.seconds:.1f} s: "
        f"{cap.frames} frames, {cap.bits} bits worst-case stuffing"
    )
    if cap.bench_frames:
        own = busload.load_pct(cap.bits - cap.bench_bits, cap.seconds, bitrate)
        detail += f" ({own:.1f} % without the bench's {cap.bench_frames} frames)"
    if cap.rx_dropped:
        detail += f"; dropped receives {cap.rx_dropped}"
    if cap.send_failed:
        detail += f"; requests not sent: {cap.send_failed[0]}"
    if pct > BUSLOAD_FAIL_PCT:
        return Check("busload", Status.FAIL, detail, "find the node that floods the bus (candump)")
    if pct > BUSLOAD_WARN_PCT:
        return Check("busload", Status.WARN, detail, "reduce cyclic rates or raise the bitrate")
    return Check("busload", Status.OK, detail)
