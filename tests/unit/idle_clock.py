"""A clock the unit tests hand a ControllerNode and never run: they call its ticks or its send
paths directly."""

from __future__ import annotations

from typing import Any

from controller.clock import ClockStats


class IdleClock:
    """Lock-step, with the node's 10 ms period; it never yields a tick."""

    lockstep = True

    def __init__(self, period_ns: int = 10_000_000) -> None:
        self.period_ns = period_ns
        self.stats = ClockStats()

    def start(self) -> None: ...

    def wait_tick(self, on_frame: Any) -> int | None:
        return None

    def tick_done(self, t_ns: int) -> None: ...
