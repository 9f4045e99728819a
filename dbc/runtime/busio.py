"""Receiving from a python-can bus against the monotonic clock (used by the controller's
real-time loop and the bus-fault wrapper)."""

from __future__ import annotations

import can


def recv_monotonic(bus: can.BusABC, timeout: float | None) -> can.Message | None:
    """One receive that waits at most ``timeout`` seconds of the monotonic clock.

    python-can's ``BusABC.recv`` re-computes its remaining timeout from ``time.time()``,
    so a backward wall-clock step (NTP, an operator) during a wait on a silent bus
    stretches the wait by the size of the step.  Every interface implements
    ``_recv_internal`` against its own (monotonic) wait, so the loop calls it directly
    and applies the bus filters itself.  A frame the filters reject returns ``None``
    early; the caller's loop is driven by its own deadline anyway.
    """
    msg, already_filtered = bus._recv_internal(timeout)
    if msg is None or already_filtered or bus._matches_filters(msg):
        return msg
    return None
