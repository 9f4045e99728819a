"""Parking at the route's end, shared by the laws that stop on their own there.

Once the reference is done and the chair is within ``stop_radius_m`` of its end, the law
commands standstill and keeps doing so until it is reset: a parked chair does not creep
back towards a point it has already reached.
"""

from __future__ import annotations


class RouteEndLatch:
    """Latches ``parked`` when the route is done and the chair is close enough to its end."""

    __slots__ = ("parked",)

    def __init__(self) -> None:
        self.parked = False

    def check(self, route_done: bool, distance_m: float, stop_radius_m: float) -> bool:
        """True (and latched) once ``route_done`` and ``distance_m < stop_radius_m``."""
        if self.parked or (route_done and distance_m < stop_radius_m):
            self.parked = True
        return self.parked
