"""The controller's view of the bus: drive and localizer feedback in, commands out.

:class:`DriveLink` decodes every standard-ID frame with the codec, keeps the
latest state of each drive (heartbeat, encoder estimates, current, bus voltage)
and of the localizer, and sends commands.  It never raises: undecodable frames
are counted by reason, send failures are counted.  Valid frames the controller has no use
for (an ODrive's Get_Version, Address, Get_Torques or Get_Powers answers, another tool's
RTR polls, ...) are ignored and counted by DBC message name, never rejected.  Frames arriving between
ticks set *fresh* flags that the loop consumes at its next tick, so staleness is
measured in ticks of the loop's own clock in both clock modes.

Extended-ID (bench) frames are dropped on arrival, unread: the controller cannot
see the bench's ground truth.  On SocketCAN they do not even arrive: the controller's
socket gets the kernel filters of :func:`host_filters`, which pass only what the DBC
says the host receives.
"""

from __future__ import annotations

import errno
import logging
import math
from collections import Counter
from dataclasses import dataclass, field

import can

from dbc.codec import (
    DRIVES,
    AxisState,
    BusVoltageCurrent,
    Codec,
    EncoderEstimates,
    Estop,
    GetError,
    Heartbeat,
    Iq,
    Node,
    PoseFix,
    RxSdo,
    SdoOpcode,
    TxSdo,
)
from dbc.errors import CodecError, DecodeError
from dbc.nodemap import NodeMap
from dbc.runtime.busio import os_errno
from dbc.secoc import Authenticator

log = logging.getLogger(__name__)


#: The DBC node name of this program.
HOST_NODE = "Host"


def host_filters(
    codec: Codec, *, lockstep: bool, nodes: NodeMap | None = None
) -> list[dict[str, object]]:
    """python-can ``can_filters`` passing exactly the frames the DBC has the host receive.

    That is the drives' and the localizer's feedback (with the node IDs ``nodes`` gives them
    on the wire) and, in lock-step only, the clock frames ``Bench_Step``
    and ``Bench_End``.  No other bench frame (ground truth, faults, recorder acks) passes:
    on SocketCAN the kernel applies these filters, so the controller's socket never holds a
    bench frame it could read.
    """
    nodes = nodes or NodeMap()
    out: list[dict[str, object]] = []
    for m in codec.db.messages:
        if HOST_NODE not in m.receivers:
            continue
        if m.is_extended_frame and not lockstep:
            continue
        full = 0x1FFFFFFF if m.is_extended_frame else 0x7FF
        can_id = m.frame_id if m.is_extended_frame else nodes.wire_frame_id(m.frame_id)
        out.append({"can_id": can_id, "can_mask": full, "extended": m.is_extended_frame})
    return out


@dataclass
class DriveState:
    """Latest feedback of one drive."""

    node: Node
    axis_state: AxisState | None = None
    axis_error: int = 0
    procedure_result: int = 0
    heartbeats: int = 0
    heartbeat_fresh: bool = False
    pos_rev: float = math.nan
    vel_revps: float = math.nan
    encoder_msgs: int = 0
    encoder_fresh: bool = False
    iq_measured_a: float = math.nan
    bus_voltage_v: float = math.nan
    active_errors: int = 0
    disarm_reason: int = 0
    #: Endpoint values the drive reported in TxSdo answers (contract hash, freshness).
    sdo: dict[int, int] = field(default_factory=dict)


@dataclass
class LinkCounters:
    """What the link counted: frames received, ignored, unused and rejected; sends and failures."""

    received: int = 0
    #: valid frames not acted on: the host's own (echoed) and :attr:`unused` ones
    ignored: int = 0
    #: valid frames the controller has no use for, by DBC message name
    unused: Counter[str] = field(default_factory=Counter)
    rejected: Counter[str] = field(default_factory=Counter)
    sent: int = 0
    send_failed: int = 0
    #: Sends failed one after the other (reset by a send that went out).
    send_fail_streak: int = 0


#: errnos of a send that say the interface itself is gone: down, removed, no device.
INTERFACE_DOWN_ERRNOS = frozenset({errno.ENETDOWN, errno.ENODEV, errno.ENXIO})
#: Consecutive failed sends (of any other error, e.g. ENOBUFS from a full transmit queue on
#: a bus that acknowledges nothing) after which the bus counts as down.
SEND_FAIL_STREAK_DOWN = 20


class DriveLink:
    """Feedback from the drives and the localizer; the only place the controller touches the bus."""

    def __init__(
        self,
        bus: can.BusABC,
        codec: Codec | None = None,
        auth: Authenticator | None = None,
        nodes: NodeMap | None = None,
    ) -> None:
        self.bus = bus
        self.codec = codec or Codec.default()
        #: The drives' and the localizer's node IDs on the wire ([drives] *_node_id, [bus]
        #: localizer_node_id): frames are translated to and from the contract's IDs here, at
        #: the bus; inside, everything is the contract's.
        self.nodes = nodes or NodeMap()
        #: With a key: every command to a drive is sent authenticated (:meth:`send`).
        self.auth = auth
        self.drives: dict[Node, DriveState] = {n: DriveState(n) for n in DRIVES}
        self.pose_fixes: list[PoseFix] = []
        self.counters = LinkCounters()
        #: The error of the most recent failed send (``None`` once a send went out again).
        self.last_send_error: BaseException | None = None
        self._last_reject_log = 0
        # IDs only this host sends: an echoing transport (udp_multicast) hands them back
        self._own_ids = frozenset(
            self.codec.frame_id(cls, node)
            for cls, node, _n in self.codec.all_messages()
            if node is not None and self.codec.senders(cls, node) == (HOST_NODE,)
        )

    # ------------------------------------------------------------------ receive

    def on_frame(self, msg: can.Message) -> None:
        """Handle one received frame (never raises: a failure is counted as ``internal``)."""
        try:
            self._on_frame(msg)
        except Exception as err:  # a codec or link bug must not stop the loop
            self.counters.rejected["internal"] += 1
            if self.counters.rejected["internal"] == 1:
                log.exception("receive path failed on %r: %s", msg, err)

    def _on_frame(self, msg: can.Message) -> None:
        if msg.is_extended_id:  # bench frames: not for the controller
            return
        self.counters.received += 1
        if self.nodes:
            seen = self.nodes.from_wire(msg)
            if seen is None:  # a node's contract ID, where that node is not
                self.counters.ignored += 1
                self.counters.unused["contract ID of a node on another node ID"] += 1
                return
            msg = seen
        if msg.arbitration_id in self._own_ids and not msg.is_remote_frame:
            self.counters.ignored += 1
            return
        try:
            node, payload = self.codec.decode(msg)
        except DecodeError as err:
            self.counters.rejected[err.reason] += 1
            n = sum(self.counters.rejected.values())
            if n - self._last_reject_log >= 100 or n == 1:
                self._last_reject_log = n
                log.warning("rejected frame (%d so far): %s", n, err)
            return
        drive = self.drives.get(node) if node is not None else None
        t = type(payload)
        if drive is not None:
            if t is EncoderEstimates:
                drive.pos_rev, drive.vel_revps = payload.pos_rev, payload.vel_revps
                drive.encoder_msgs += 1
                drive.encoder_fresh = True
            elif t is Heartbeat:
                drive.axis_state = payload.axis_state
                drive.axis_error = payload.axis_error
                drive.procedure_result = payload.procedure_result
                drive.heartbeats += 1
                drive.heartbeat_fresh = True
            elif t is Iq:
                drive.iq_measured_a = payload.measured_a
            elif t is BusVoltageCurrent:
                drive.bus_voltage_v = payload.voltage_v
            elif t is TxSdo:
                drive.sdo[payload.endpoint_id] = payload.value
            elif t is GetError:
                drive.active_errors, drive.disarm_reason = (
                    payload.active_errors,
                    payload.disarm_reason,
                )
            else:  # what the host does not read (versions, torques, RTR polls, ...)
                self._unused(msg)
        elif t is PoseFix:
            self.pose_fixes.append(payload)
        else:
            self._unused(msg)

    def _unused(self, msg: can.Message) -> None:
        self.counters.ignored += 1
        name = self.codec.db.get_message_by_frame_id(msg.arbitration_id).name
        self.counters.unused[("RTR " if msg.is_remote_frame else "") + name] += 1

    def take_pose_fixes(self) -> list[PoseFix]:
        """The pose fixes received since the last call, oldest first (the list is emptied)."""
        fixes, self.pose_fixes = self.pose_fixes, []
        return fixes

    # --------------------------------------------------------------------- send

    def send(self, payload: object, node: Node | None) -> bool:
        """Encode and send; returns False (and counts) instead of raising.

        With :attr:`auth`, a command to a drive goes out secured (``Codec.encode_secured``):
        a setpoint with its MAC, anything else followed by its Host_Auth PDU.  Exempt are an
        Estop (anyone may stop) and an RxSdo read, which a drive answers unauthenticated.
        """
        try:
            auth = self.auth
            if (
                auth is not None
                and node in DRIVES
                and type(payload) is not Estop
                and not (type(payload) is RxSdo and payload.opcode == SdoOpcode.READ)
            ):
                assert node is not None
                for msg in self.codec.encode_secured(payload, node, auth):
                    self.bus.send(self.nodes.to_wire(msg))
                    self.counters.sent += 1  # frames: a command and its Host_Auth are two
            else:
                self.bus.send(self.nodes.to_wire(self.codec.encode(payload, node)))
                self.counters.sent += 1
        except (CodecError, can.CanError, OSError) as err:
            self.counters.send_failed += 1
            if not isinstance(err, CodecError):  # an encoding bug is not the bus failing
                self.counters.send_fail_streak += 1
                self.last_send_error = err
            if self.counters.send_failed == 1 or self.counters.send_failed % 100 == 0:
                log.warning("send failed (%d so far): %s", self.counters.send_failed, err)
            return False
        self.counters.send_fail_streak = 0
        self.last_send_error = None
        return True

    def bus_down(self) -> str | None:
        """Why the bus cannot carry the host's frames, naming the interface; else ``None``.

        Down at once when a send failed because the interface is down or gone (ENETDOWN,
        ENODEV, ENXIO: ``ip link set can0 down``, a USB adapter unplugged); after
        :data:`SEND_FAIL_STREAK_DOWN` failed sends in a row for any other reason.
        """
        err = self.last_send_error
        if err is None:
            return None
        code = os_errno(err)
        streak = self.counters.send_fail_streak
        if code not in INTERFACE_DOWN_ERRNOS and streak < SEND_FAIL_STREAK_DOWN:
            return None
        where = getattr(self.bus, "channel_info", "") or "the bus"
        name = f"{errno.errorcode[code]}, " if code is not None and code in errno.errorcode else ""
        return f"cannot send on {where}: {err} ({name}{streak} sends failed)"

    def both_armed(self) -> bool:
        """Whether both drives report CLOSED_LOOP_CONTROL and no axis error."""
        return all(
            d.axis_state == AxisState.CLOSED_LOOP_CONTROL and d.axis_error == 0
            for d in self.drives.values()
        )
