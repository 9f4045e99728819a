"""Drive-side safety rules (docs/safety.md), on the emulated drives with synthetic time.

E2E freshness (AUTOSAR profile 2 counter window), neutral start, the coordinated two-wheel
stop, e-stop, the host-heartbeat monitor, no automatic resume, configuration refused in
motion, and the event heartbeat that reports a trip at once.
"""

from __future__ import annotations

import math
from typing import Any

import pytest

from dbc.codec import (
    AxisError,
    AxisState,
    ClearErrors,
    Estop,
    Heartbeat,
    HostHeartbeat,
    HostState,
    Node,
    Reboot,
    SetAxisState,
    SetInputVel,
    SetInputVelE2E,
    SetLimits,
    SetVelGains,
    SetWatchdog,
)
from firmware_sim.config import load_bench_config
from firmware_sim.drive import E2E_MAX_DELTA_COUNTER_INIT, Out, SetpointWatchdog
from firmware_sim.sim import ChairSim

L, R = Node.LEFT, Node.RIGHT
MS = 1_000_000
TWO_PI = 2.0 * math.pi
SAFETY = SetWatchdog(
    timeout_ms=100,
    stop_decel_revps2=0.53,
    require_e2e=True,
    host_timeout_ms=0,
    require_neutral=True,
)


class Chair:
    """Both drives of a ChairSim, driven by a scripted host in 10 ms steps."""

    def __init__(self, wd: SetWatchdog = SAFETY) -> None:
        self.sim = ChairSim(load_bench_config({}, source="test"))
        self.counter = {L: 0, R: 0}
        self.emitted: list[tuple[int, Any, Node | None]] = []
        self.replies: Out = []
        self.hb_alive = 0
        for n in (L, R):
            self.send(n, wd)
            self.send(n, SetAxisState(AxisState.CLOSED_LOOP_CONTROL))

    def send(self, node: Node, payload: Any) -> bool:
        return self.sim.handle(node, payload, self.replies)

    def e2e(self, left: float, right: float, ref: float | None = None) -> None:
        ref = max(abs(left), abs(right)) if ref is None else ref
        for n, v in ((L, left), (R, right)):
            self.counter[n] = (self.counter[n] + 1) % 16
            self.send(n, SetInputVelE2E(self.counter[n], v, ref))

    def heartbeat(self) -> None:
        self.hb_alive = (self.hb_alive + 1) % 256
        self.send(Node.HOST, HostHeartbeat(HostState.TRACKING, self.hb_alive))

    def step(self, n: int = 1, each: Any = None) -> None:
        for _ in range(n):
            if each is not None:
                each(self)
            self.sim.advance()
            out: Out = []
            self.sim.emit_due(out)
            self.emitted.extend((self.sim.now_ns, p, node) for p, node in out)

    def wheels(self) -> tuple[float, float]:
        p = self.sim.plant
        return p.left.omega_radps, p.right.omega_radps

    def drive_to(self, left: float, right: float, seconds: float = 1.5) -> None:
        """Neutral first, then ramp to (left, right) rev/s and hold."""
        self.e2e(0.0, 0.0)
        steps = round(seconds * 100)
        for k in range(steps):
            f = min(1.0, (k + 1) / (steps / 2))
            self.e2e(left * f, right * f)
            self.step()


# ------------------------------------------------------------- E2E counter window


def test_a_repeated_counter_is_stale_and_does_not_feed() -> None:
    wd = SetpointWatchdog(100, 0.5, True, 0)
    wd.arm(0)
    assert wd.accept_e2e(3, 10 * MS)
    assert not wd.accept_e2e(3, 20 * MS)
    assert wd.last_reject == "e2e_counter_repeated"
    assert wd.last_feed_ns == 10 * MS


def test_the_counter_window_grows_with_the_time_without_a_valid_frame() -> None:
    wd = SetpointWatchdog(100, 0.5, True, 0)
    wd.arm(0)
    assert wd.accept_e2e(0, 0)
    # 10 ms later one lost frame is tolerated (delta 2), not a jump of 3
    assert not wd.accept_e2e(3, 10 * MS)
    assert wd.last_reject == "e2e_wrong_sequence"
    assert wd.accept_e2e(E2E_MAX_DELTA_COUNTER_INIT, 10 * MS)
    # after 9 lost periods (90 ms without a valid frame) the 10th frame is in sequence
    assert wd.accept_e2e((E2E_MAX_DELTA_COUNTER_INIT + 10) % 16, 110 * MS)


@pytest.mark.parametrize("first", [13, 14, 15])
def test_reordered_frames_across_the_counter_wrap_are_rejected(first: int) -> None:
    wd = SetpointWatchdog(100, 0.5, True, 0)
    wd.arm(0)
    seq = [(first + k) % 16 for k in range(4)]  # e.g. 14 15 0 1: crosses 15 -> 0
    t = 0
    assert wd.accept_e2e(seq[0], t)
    # seq[2] overtakes seq[1]: the newer one is applied, the older one is then refused
    t += 20 * MS
    assert wd.accept_e2e(seq[2], t)
    assert not wd.accept_e2e(seq[1], t)
    assert wd.last_reject == "e2e_wrong_sequence"
    t += 10 * MS
    assert wd.accept_e2e(seq[3], t)


def test_plain_setpoints_are_refused_with_e2e_and_accepted_without() -> None:
    wd = SetpointWatchdog(100, 0.5, True, 0)
    wd.arm(0)
    assert not wd.accept_plain(10 * MS, 0.0)
    wd.configure(100, 0.5, False, 0)
    assert wd.accept_plain(20 * MS, 0.3)  # ODrive compatibility when E2E is off


def test_a_hung_host_re_sending_its_last_frame_trips_the_drive() -> None:
    chair = Chair()
    chair.drive_to(0.4, 0.4)
    last = SetInputVelE2E(chair.counter[L], 0.4, 0.4)
    chair.step(30, each=lambda c: c.send(L, last))
    d = chair.sim.left
    assert d.active_errors & AxisError.WATCHDOG_TIMER_EXPIRED
    assert d.ignored["e2e_counter_repeated"] >= 9


# ------------------------------------------------------------------ neutral start


def test_a_drive_does_not_move_until_it_has_seen_a_neutral_setpoint() -> None:
    chair = Chair()

    def push(c: Chair) -> None:
        c.e2e(0.3, 0.3)

    chair.step(5, each=push)
    assert max(abs(w) for w in chair.wheels()) < 1e-6
    assert chair.sim.left.ignored["not_neutral_after_arm"] == 5
    chair.step(10, each=push)  # never fed: the watchdog trips, nothing ever moved
    assert chair.sim.left.active_errors & AxisError.WATCHDOG_TIMER_EXPIRED
    assert chair.sim.left.state == AxisState.IDLE
    assert max(abs(w) for w in chair.wheels()) < 1e-6


def test_after_a_neutral_setpoint_commands_are_followed() -> None:
    chair = Chair()
    chair.drive_to(0.3, 0.3)
    assert chair.wheels()[0] / TWO_PI == pytest.approx(0.3, rel=0.05)


# ------------------------------------------------------------ coordinated stop


def _stop_profile(chair: Chair, seconds: float) -> list[tuple[float, float]]:
    samples: list[tuple[float, float]] = []
    chair.sim.add_tick_hook(lambda _t, p: samples.append((p.left.omega_radps, p.right.omega_radps)))
    chair.step(round(seconds * 100))
    return samples


def test_on_expiry_both_wheels_ramp_to_zero_together_keeping_their_ratio() -> None:
    chair = Chair()
    chair.drive_to(0.3, 0.5)  # a left turn: the right wheel is faster
    samples = _stop_profile(chair, 1.5)  # the host falls silent
    left, right = chair.sim.left, chair.sim.right
    assert left.stop_started_ns == right.stop_started_ns  # both fed by the same host tick
    # the setpoint ramps end together: T = 0.5 rev/s / 0.53 rev/s^2, after the 100 ms timeout
    ratios = [wl / wr for wl, wr in samples if wr > 0.5]
    assert len(ratios) > 500
    assert max(ratios) - min(ratios) < 0.02  # curvature kept: wL/wR = 0.6 throughout
    assert min(ratios) == pytest.approx(0.6, abs=0.01)
    for d in (left, right):
        assert d.state == AxisState.IDLE
        assert d.disarm_reason == AxisError.WATCHDOG_TIMER_EXPIRED
    assert chair.sim.plant.left.brake_engaged and chair.sim.plant.right.brake_engaged
    # the faster wheel decelerated at Stop_Decel: stopped within timeout + T + lag
    stop_ms = next(i for i, (wl, wr) in enumerate(samples) if max(abs(wl), abs(wr)) < 0.03)
    assert stop_ms <= 100 + 1000 * 0.5 / 0.53 + 60


def test_without_a_stop_reference_each_wheel_ramps_at_stop_decel() -> None:
    chair = Chair(SetWatchdog(100, 2.0, False, 0))
    for n in (L, R):
        chair.send(n, SetInputVel(0.0))
    chair.step(40, each=lambda c: [c.send(n, SetInputVel(v)) for n, v in ((L, 0.2), (R, 0.4))])
    idle_at: dict[Node, int] = {}

    def watch(t: int, _p: Any) -> None:
        for n, d in ((L, chair.sim.left), (R, chair.sim.right)):
            if not d.armed:
                idle_at.setdefault(n, t)

    chair.sim.add_tick_hook(watch)
    chair.step(60)
    # plain ODrive setpoints carry no reference: both ramp at 2 rev/s^2, so the slower wheel
    # stops about (0.4 - 0.2) / 2 = 100 ms earlier (the curvature is not kept)
    assert chair.sim.left.stop_started_ns == chair.sim.right.stop_started_ns
    assert (idle_at[R] - idle_at[L]) / MS == pytest.approx(100, abs=15)


def test_estop_in_motion_ramps_like_the_watchdog_then_latches_estop() -> None:
    chair = Chair()
    chair.drive_to(0.4, 0.4)
    chair.send(L, Estop())
    chair.send(R, Estop())
    chair.step(1, each=lambda c: c.e2e(0.4, 0.4))  # setpoints after the e-stop are ignored
    d = chair.sim.left
    assert d.state == AxisState.CLOSED_LOOP_CONTROL  # ramping, not slammed to the brake
    assert d.ignored["setpoint_while_stopping"] == 1
    chair.step(120)
    assert d.state == AxisState.IDLE
    assert d.disarm_reason == AxisError.ESTOP_REQUESTED
    assert max(abs(w) for w in chair.wheels()) < 0.05


# ------------------------------------------------------------- no automatic resume


def test_after_a_stop_motion_needs_clear_errors_re_arming_and_a_neutral_command() -> None:
    chair = Chair()
    chair.drive_to(0.3, 0.3)
    chair.step(150)  # watchdog stop
    assert chair.sim.left.state == AxisState.IDLE
    chair.step(20, each=lambda c: c.e2e(0.3, 0.3))  # a host that comes back
    assert max(abs(w) for w in chair.wheels()) < 0.01
    chair.send(L, SetAxisState(AxisState.CLOSED_LOOP_CONTROL))
    assert chair.sim.left.state == AxisState.IDLE  # errors latched: arming refused
    chair.send(L, ClearErrors())
    chair.send(L, SetAxisState(AxisState.CLOSED_LOOP_CONTROL))
    assert chair.sim.left.state == AxisState.CLOSED_LOOP_CONTROL
    chair.step(5, each=lambda c: c.send(L, SetInputVelE2E((c.counter[L] + 1) % 16, 0.3, 0.3)))
    assert abs(chair.wheels()[0]) < 0.01  # re-armed, but no neutral command yet


# ------------------------------------------------------------ host heartbeat monitor


def test_the_drives_stop_when_the_host_heartbeat_is_missing() -> None:
    wd = SetWatchdog(100, 0.53, True, host_timeout_ms=300, require_neutral=True)
    chair = Chair(wd)
    chair.drive_to(0.3, 0.3, seconds=0.5)

    def setpoints_only(c: Chair) -> None:
        c.e2e(0.3, 0.3)

    chair.step(25, each=setpoints_only)  # setpoints keep coming, heartbeats do not
    d = chair.sim.left
    assert d.active_errors == AxisError.MISSING_INPUT
    chair.step(150, each=setpoints_only)
    assert d.state == AxisState.IDLE and d.disarm_reason == AxisError.MISSING_INPUT


def test_a_repeated_host_heartbeat_does_not_feed_the_monitor() -> None:
    wd = SetWatchdog(100, 0.53, True, host_timeout_ms=300, require_neutral=False)
    chair = Chair(wd)

    def same_heartbeat(c: Chair) -> None:
        c.e2e(0.0, 0.0)
        c.send(Node.HOST, HostHeartbeat(HostState.TRACKING, 7))

    chair.step(40, each=same_heartbeat)
    assert chair.sim.left.active_errors == AxisError.MISSING_INPUT
    assert chair.sim.left.ignored["host_heartbeat_repeated"] >= 30


def test_fresh_heartbeats_and_setpoints_keep_the_drives_running() -> None:
    wd = SetWatchdog(100, 0.53, True, host_timeout_ms=300, require_neutral=True)
    chair = Chair(wd)

    def host(c: Chair) -> None:
        c.e2e(0.2, 0.2)
        if len(c.emitted) % 10 == 0:
            c.heartbeat()

    chair.e2e(0.0, 0.0)
    chair.step(300, each=host)
    assert chair.sim.left.active_errors == 0 and chair.sim.right.active_errors == 0


# ------------------------------------------------------- configuration in motion


@pytest.mark.parametrize(
    "frame",
    [SetLimits(5.0, 200.0), SetVelGains(0.0, 0.0), SetWatchdog(0, 0.0, False), Reboot(0)],
    ids=["limits", "gains", "watchdog", "reboot"],
)
def test_configuration_frames_are_refused_while_in_closed_loop(frame: Any) -> None:
    chair = Chair()
    before = chair.sim.left.rt.copy()
    chair.send(L, frame)
    assert chair.sim.left.ignored["config_while_armed"] == 1
    assert chair.sim.left.rt == before
    assert chair.sim.left.state == AxisState.CLOSED_LOOP_CONTROL
    chair.send(L, SetAxisState(AxisState.IDLE))
    chair.send(L, frame)  # idle: accepted
    assert chair.sim.left.ignored["config_while_armed"] == 1


# --------------------------------------------------------------- event heartbeat


def test_a_trip_is_reported_in_a_heartbeat_at_the_next_step() -> None:
    chair = Chair()
    chair.drive_to(0.3, 0.3, seconds=0.5)
    chair.emitted.clear()
    chair.step(20)
    trip = chair.sim.left.stop_started_ns
    assert trip is not None
    hbs = [(t, p) for t, p, n in chair.emitted if type(p) is Heartbeat and n == L]
    first = next(t for t, p in hbs if p.axis_error & AxisError.WATCHDOG_TIMER_EXPIRED)
    assert 0 < first - trip <= 10 * MS
