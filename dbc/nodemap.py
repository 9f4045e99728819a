"""Nodes on other node IDs than the wire contract's: the translation at a bus boundary.

``dbc/wheelchair.dbc`` names the left drive node 1, the right drive node 2 and the
localizer node 3 (ODrive CAN Simple: an 11-bit ID is ``node << 5 | cmd``).  A chair whose
drives were configured with other node IDs (a stock ODrive's ``axis0.config.can.node_id`` is
often 0; drives on 3 and 4 move the localizer elsewhere) keeps them: each side of the bus that
talks to or as those nodes (the controller's link, the doctor's capture, the bench's emulated
drives and localizer) translates at its boundary, and everything inside it, the codec
included, sees the contract's IDs.

* a frame going out to or from a node leaves with the node's configured ID
  (:meth:`NodeMap.to_wire`);
* a frame coming in with a node's configured ID is read as the contract's
  (:meth:`NodeMap.from_wire`); one with a node's *contract* ID where no node is configured
  is nobody's (``None``: a stranger on the contract's ID, counted by the caller).

A secured setpoint's MAC and a ``Host_Auth`` PDU's target are computed over the contract's
IDs on both sides, so the translation leaves authentication unchanged.  With the contract's
IDs (the default) the map is empty and both calls return the frame they were given.
"""

from __future__ import annotations

import copy

import can

from dbc.codec import DRIVES, Node
from dbc.runtime.errors import ConfigError

#: The node the map never moves: the host is this program (the contract's node 8).
HOST_ID = int(Node.HOST)
#: ODrive CAN Simple's node IDs: 6 bits, 0x3F being the broadcast address.
MAX_NODE_ID = 62
#: The nodes a configuration may put on another ID: the drives and the localizer.
MAPPED = (*DRIVES, Node.LOCALIZER)
#: Each node's setting in the controller's configuration (named in errors).
KEYS = {
    Node.LEFT: "drives.left_node_id",
    Node.RIGHT: "drives.right_node_id",
    Node.LOCALIZER: "bus.localizer_node_id",
}


class NodeMap:
    """The nodes' configured IDs against the contract's (``{Node.LEFT: 3, Node.RIGHT: 4,
    Node.LOCALIZER: 5}``); a node not given keeps the contract's ID.

    ``keys`` names each node's setting in errors (default :data:`KEYS`)."""

    __slots__ = ("_in", "_out", "ids")

    def __init__(
        self, ids: dict[Node, int] | None = None, *, keys: dict[Node, str] | None = None
    ) -> None:
        names = KEYS | dict(keys or {})
        ids = {n: int(n) for n in MAPPED} | dict(ids or {})
        for n, nid in ids.items():
            if n not in MAPPED:
                raise ConfigError(f"{n.name}'s node ID cannot be set: it is this program's")
            if not 0 <= nid <= MAX_NODE_ID:
                raise ConfigError(f"{names[n]} = {nid} is outside [0, {MAX_NODE_ID}]")
            if nid == HOST_ID:
                raise ConfigError(f"{names[n]} = {nid} is the host's node ID")
        taken: dict[int, Node] = {}
        for n in MAPPED:
            other = taken.setdefault(ids[n], n)
            if other is not n:
                raise ConfigError(f"{names[other]} and {names[n]} are both {ids[n]}")
        self.ids = ids
        self._out = {int(n): nid for n, nid in ids.items() if nid != int(n)}
        self._in = {nid: c for c, nid in self._out.items()}

    def __bool__(self) -> bool:
        """Whether any node is on another node ID than the contract's."""
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
