"""The drive's side of command authentication (AUTOSAR SecOC style, :mod:`dbc.secoc`).

With Require_Auth a setpoint (Set_Input_Vel_Auth) carries its own MAC and freshness value,
checked as it arrives (:meth:`CommandAuth.verify_setpoint`); every other command that can
move a wheel or change the drive's configuration is held (:meth:`CommandAuth.hold`) until the
host's Host_Auth PDU for it arrives and verifies (:meth:`CommandAuth.check`), at most
:data:`AUTH_WAIT_STEPS` bench steps later.  What the drive does with a refusal (count it, and
take an unauthenticated IDLE request in closed loop as an Estop) is
:class:`firmware_sim.drive.DriveNode`'s.
"""

from __future__ import annotations

import time
from typing import Any

import can

from dbc.codec import HostAuth, SetInputVelAuth
from dbc.runtime.busio import receive_ns
from dbc.secoc import (
    AUTH_FV_BITS,
    REJECT_AUTH_REQUIRED,
    REJECT_LINK,
    REJECT_NO_COMMAND,
    REJECT_UNAUTHENTICATED,
    SETPOINT_FV_BITS,
    Key,
    Verifier,
    linked_id,
)

#: A held command whose Host_Auth has not come within this many bench steps is refused (the
#: host sends both back to back; in real time they may straddle one step boundary).
AUTH_WAIT_STEPS = 2


class CommandAuth:
    """One drive's SecOC receiver and the secured command it holds for its Host_Auth.

    ``step_ns``: the bench step (the wait for a Host_Auth is :data:`AUTH_WAIT_STEPS` of them).
    """

    def __init__(self, key: Key | None, step_ns: int) -> None:
        #: The key and the freshness reference (kept across reboots, as a real drive keeps
        #: them in non-volatile memory).
        self.verifier = Verifier(key)
        self.wait_ns = AUTH_WAIT_STEPS * step_ns
        #: A secured command waiting for its Host_Auth: (frame ID, payload bytes, payload, time).
        self.pending: tuple[int, bytes, Any, int] | None = None
        #: Real time: the wait is judged on the frames' arrival (their receive times, the
        #: wall clock), as a drive with its own clock judges it, not on the bench's step
        #: time.  A bench that fell behind catches its late steps up back to back, so that
        #: its step time runs ahead of the wire's: a host preempted between a command and
        #: its Host_Auth for a millisecond was refused because the bench stepped 30 ms
        #: meanwhile (a drive that never armed, in a one-CPU guest).
        self.arrival_clock = False
        #: the held command's receive time (ns of the wall clock; arrival clock only)
        self._held_rx_ns = 0

    def verify_setpoint(self, payload: SetInputVelAuth, msg: can.Message | None) -> str:
        """Why an authenticated setpoint is refused ("": its MAC and freshness verify).

        ``msg`` is the frame as received (its ID and first four bytes are what the MAC
        covers); None (a payload without its frame) cannot be verified."""
        if msg is None:
            return REJECT_AUTH_REQUIRED
        return self.verifier.verify(
            msg.arbitration_id,
            msg.data[:4],
            payload.freshness,
            SETPOINT_FV_BITS,
            payload.mac,
        )

    def hold(self, payload: Any, msg: can.Message | None, now_ns: int) -> None:
        """Hold a secured command for its Host_Auth (replacing any held before)."""
        if msg is None:
            self.pending = (0, b"", payload, now_ns)
        else:
            self.pending = (msg.arbitration_id, bytes(msg.data), payload, now_ns)
        self._held_rx_ns = receive_ns(msg)

    def take(self) -> Any:
        """The held command (None: none), no longer held."""
        pending, self.pending = self.pending, None
        return None if pending is None else pending[2]

    def check(self, p: HostAuth, now_ns: int, msg: can.Message | None = None) -> str:
        """Whether ``p`` (received as ``msg``) authenticates the held command: "" (then
        :meth:`take` it) or why not."""
        pending = self.pending
        if pending is None:
            return REJECT_NO_COMMAND
        frame_id, data, _payload, t_ns = pending
        if linked_id(p.target_node, p.target_cmd) != frame_id:
            return REJECT_LINK
        rx_ns = receive_ns(msg)
        if self.arrival_clock and rx_ns and self._held_rx_ns:
            late = rx_ns - self._held_rx_ns >= self.wait_ns
        else:
            late = now_ns - t_ns >= self.wait_ns
        if late:
            return REJECT_UNAUTHENTICATED
        return self.verifier.verify(frame_id, data, p.freshness, AUTH_FV_BITS, p.mac)

    def overdue(self, now_ns: int) -> bool:
        """A command is held and its Host_Auth did not come in time (with the arrival
        clock: the wait has passed on the wall clock too, so that a Host_Auth that is in
        flight while the bench catches up is still taken)."""
        pending = self.pending
        if pending is None or now_ns - pending[3] < self.wait_ns:
            return False
        if self.arrival_clock and self._held_rx_ns:
            return time.time_ns() - self._held_rx_ns >= self.wait_ns
        return True
