"""The host's plausibility check (controller/obedience.py): the wheels do what it commanded.

Synthetic time and a link whose drive feedback the test sets; the loop's answer (Estop to
both drives, DISOBEYED in the heartbeat) is checked on a ControllerNode's sent frames.
"""

from __future__ import annotations

import math

import can
import pytest

from controller.config import load_config
from controller.link import DriveLink
from controller.obedience import ObedienceMonitor
from dbc.codec import Codec, Node

CFG = load_config()
T = 10_000_000
L, R = Node.LEFT, Node.RIGHT


def _monitor() -> tuple[ObedienceMonitor, DriveLink, can.BusABC]:
    bus = can.Bus(interface="virtual", channel="plausibility", receive_own_messages=False)
    link = DriveLink(bus, Codec.default())
    return ObedienceMonitor(CFG.safety, CFG.limits, CFG.geometry, T), link, bus


def _run(
    mon: ObedienceMonitor,
    link: DriveLink,
    cmd: list[tuple[float, float]],
    meas: list[tuple[float, float]],
) -> int | None:
    """Feed commands and measurements tick by tick; the tick of the first trip or None."""
    for k, ((cl, cr), (ml, mr)) in enumerate(zip(cmd, meas, strict=True)):
        mon.commanded(cl, cr)
        link.drives[L].vel_revps, link.drives[R].vel_revps = ml, mr
        if mon.check(link, k * T):
            return k
    return None


def _lagging(cmd: list[float], tau_s: float = 0.05) -> list[float]:
    """A drive that follows its commands with a first-order lag (a healthy speed loop)."""
    out, y = [], 0.0
    a = 1.0 - math.exp(-0.01 / tau_s)
    for c in cmd:
        y += a * (c - y)
        out.append(y)
    return out


def test_a_wheel_that_follows_its_commands_never_trips() -> None:
    mon, link, bus = _monitor()
    try:
        # accelerate at the limiter's 1 m/s^2 (0.53 rev/s^2), cruise, turn, brake
        left = [min(0.6, 0.0053 * k) for k in range(300)] + [0.4] * 100 + [0.0] * 100
        right = [min(0.6, 0.0053 * k) for k in range(300)] + [0.55] * 100 + [0.0] * 100
        cmd = list(zip(left, right, strict=True))
        meas = list(zip(_lagging(left), _lagging(right), strict=True))
        assert _run(mon, link, cmd, meas) is None
        assert mon.worst_revps < CFG.safety.obey_margin_revps
    finally:
        bus.shutdown()


def test_a_wheel_driven_by_someone_else_trips_after_the_stated_time() -> None:
    mon, link, bus = _monitor()
    try:
        cmd = [(0.0, 0.0)] * 100
        # the left wheel runs up at 2.4 rev/s^2 (the drive's current limit) towards 0.907
        left = [min(0.907, 0.024 * max(0, k - 10)) for k in range(100)]
        meas = [(v, 0.0) for v in left]
        k = _run(mon, link, cmd, meas)
        assert k is not None
        first_out = next(i for i, v in enumerate(left) if v > CFG.safety.obey_margin_revps)
        assert (k - first_out) * T == pytest.approx(CFG.safety.obey_time_s * 1e9, abs=T)
        assert "wheel LEFT" in mon.detail
    finally:
        bus.shutdown()


def test_a_short_excursion_does_not_trip() -> None:
    mon, link, bus = _monitor()
    try:
        n_out = round(CFG.safety.obey_time_s * 100) - 1  # one tick short of the stated time
        cmd = [(0.3, 0.3)] * 100
        meas = [(0.3, 0.3)] * 40 + [(0.5, 0.3)] * n_out + [(0.3, 0.3)] * (60 - n_out)
        assert _run(mon, link, cmd, meas) is None
    finally:
        bus.shutdown()


def test_a_yaw_rate_beyond_the_hosts_limit_trips_even_when_commanded() -> None:
    mon, link, bus = _monitor()
    try:
        # commanded and measured alike, but a spin beyond omega_max + margin
        w = (
            (CFG.limits.omega_max_radps + CFG.safety.twist_margin_radps + 0.2)
            * (CFG.geometry.half_track_m / (math.pi * CFG.geometry.wheel_radius_m))
            / 2.0
        )
        cmd = [(-w, w)] * 50
        assert _run(mon, link, cmd, cmd) is not None
        assert "yaw rate" in mon.detail
    finally:
        bus.shutdown()


def test_after_the_stop_a_turning_wheel_is_reported() -> None:
    mon, link, bus = _monitor()
    try:
        link.drives[L].vel_revps, link.drives[R].vel_revps = 0.0, 0.0
        assert not any(mon.moving(link, k * T) for k in range(20))
        link.drives[L].vel_revps = 0.2
        hits = [k for k in range(20, 60) if mon.moving(link, k * T)]
        assert hits and (hits[0] - 20) * T == pytest.approx(CFG.safety.obey_time_s * 1e9, abs=T)
    finally:
        bus.shutdown()
