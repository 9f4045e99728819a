"""Drives on other node IDs than the wire contract's: the translation at a bus boundary.

``dbc/wheelchair.dbc`` names the left drive node 1 and the right drive node 2 (ODrive CAN
Simple: an 11-bit ID is ``node << 5 | cmd``).  A chair whose drives were configured with
other node IDs (a stock ODrive's ``axis0.config.can.node_id`` is often 0) keeps them: each
side of the bus that talks to or as the drives (the controller's link, the doctor's
capture, the bench's emulated drives) translates at its boundary, and everything inside it,
the codec included, sees the contract's IDs.

* a frame going out to or from a drive leaves with the drive's configured ID
  (:meth:`NodeMap.to_wire`);
* a frame coming in with a drive's configured ID is read as the contract's
  (:meth:`NodeMap.from_wire`); one with a drive's *contract* ID where that drive is not is
  nobody's (``None``: a stranger on the contract's ID, counted by the caller).

A secured setpoint's MAC and a ``Host_Auth`` PDU's target are computed over the contract's
IDs on both sides, so the translation leaves authentication unchanged.  With the contract's
IDs (the default) the map is empty and both calls return the frame they were given.
"""

from __future__ import annotations

import copy

import can

from dbc.codec import DRIVES, Node
from dbc.runtime.errors import ConfigError

#: Node IDs the contract gives to nodes other than the drives: a drive may not take them.
RESERVED_NODE_IDS = {int(Node.LOCALIZER): "the localizer", int(Node.HOST): "the host"}
#: ODrive CAN Simple's node IDs: 6 bits, 0x3F being the broadcast address.
MAX_NODE_ID = 62


class NodeMap:
    """The drives' configured node IDs against the contract's (``{Node.LEFT: 0, ...}``)."""

    __slots__ = ("_in", "_out", "ids")

    def __init__(self, ids: dict[Node, int] | None = None, *, source: str = "drives") -> None:
        ids = {n: int(n) for n in DRIVES} | dict(ids or {})
        for n, nid in ids.items():
            key = f"{source}.{n.name.lower()}_node_id"
            if n not in DRIVES:
                raise ConfigError(f"{source}: only the drives' node IDs can be set, not {n.name}")
            if not 0 <= nid <= MAX_NODE_ID:
                raise ConfigError(f"{key} = {nid} is outside [0, {MAX_NODE_ID}]")
            if nid in RESERVED_NODE_IDS:
                raise ConfigError(f"{key} = {nid} is {RESERVED_NODE_IDS[nid]}'s node ID")
        left, right = ids[Node.LEFT], ids[Node.RIGHT]
        if left == right:
            raise ConfigError(f"{source}.left_node_id and {source}.right_node_id are both {left}")
        self.ids = ids
        self._out = {int(n): nid for n, nid in ids.items() if nid != int(n)}
        self._in = {nid: c for c, nid in self._out.items()}

    def __bool__(self) -> bool:
        """Whether any drive is on another node ID than the contract's."""
        return bool(self._out)

    def wire_id(self, node: Node) -> int:
        """The node ID ``node`` talks as on the wire."""
        return self.ids.get(node, int(node))

    def wire_frame_id(self, frame_id: int) -> int:
        """The 11-bit ID on the wire of the contract's ``frame_id``."""
        nid = self._out.get(frame_id >> 5)
        return frame_id if nid is None else (nid << 5) | (frame_id & 0x1F)

    def to_wire(self, msg: can.Message) -> can.Message:
        """``msg`` (with the contract's ID) as it goes on the wire; changed in place."""
        if self._out and not msg.is_extended_id:
            nid = self._out.get(msg.arbitration_id >> 5)
            if nid is not None:
                msg.arbitration_id = (nid << 5) | (msg.arbitration_id & 0x1F)
        return msg

    def from_wire(self, msg: can.Message) -> can.Message | None:
        """A received frame with the contract's ID (a copy where it changes: the receivers of
        a virtual bus share the object), or None for a frame on a drive's contract ID where
        that drive is not."""
        if not self._out or msg.is_extended_id:
            return msg
        nid = msg.arbitration_id >> 5
        contract = self._in.get(nid)
        if contract is not None:
            msg = copy.copy(msg)
            msg.arbitration_id = (contract << 5) | (msg.arbitration_id & 0x1F)
            return msg
        if nid in self._out:
            return None
        return msg
