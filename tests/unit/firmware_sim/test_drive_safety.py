"""Drive-side safety rules (docs/safety.md), on the emulated drives with synthetic time.

Authentication (SecOC: forged, replayed and unauthenticated frames refused and counted), the
locked configuration, the contract check at arming, neutral start, the coordinated two-wheel
stop, e-stop, the host-heartbeat monitor, no automatic resume, configuration refused in
motion, and the event heartbeat that reports a trip at once.
"""

from __future__ import annotations

import math
import time
from typing import Any

import can
import pytest

from dbc.codec import (
    DRIVES,
    AxisError,
    AxisState,
    ClearErrors,
    Codec,
    Estop,
    Heartbeat,
    HostHeartbeat,
    HostState,
    Node,
    Reboot,
    RebootAction,
    RxSdo,
    SdoEndpoint,
    SdoOpcode,
    SetAxisState,
    SetInputVel,
    SetInputVelAuth,
    SetLimits,
    SetVelGains,
    SetWatchdog,
    TxSdo,
)
from dbc.secoc import Authenticator, Key, load_key
from firmware_sim.config import default_config, load_bench_config
from firmware_sim.drive import Out
from firmware_sim.sim import ChairSim
from firmware_sim.watchdog import SetpointWatchdog

L, R = Node.LEFT, Node.RIGHT
MS = 1_000_000
TWO_PI = 2.0 * math.pi
SAFETY = SetWatchdog(
    timeout_ms=100,
    stop_decel_revps2=0.53,
    require_auth=True,
    host_timeout_ms=0,
    require_neutral=True,
)
KEY = load_key(default_config().key_path)
#: A key that is not the drives': what an attacker who guessed one would hold.
WRONG_KEY = Key(bytes(range(32)), "wrong", False)


class Chair:
    """Both drives of a ChairSim, driven by a scripted host (the key holder) in 10 ms steps.

    Frames go through the codec, so MACs are computed and checked on real bytes.  ``forge``
    sends as a node without the key would.
    """

    def __init__(self, wd: SetWatchdog = SAFETY, codec: Codec | None = None) -> None:
        self.codec = codec or Codec.default()
        self.sim = ChairSim(load_bench_config({}, source="test"))
        self.auth = Authenticator(KEY)
        self.sent: list[can.Message] = []
        self.emitted: list[tuple[int, Any, Node | None]] = []
        self.replies: Out = []
        self.hb_alive = 0
        for n in (L, R):
            self.send(n, wd)
            self.send(
                n, RxSdo(SdoOpcode.WRITE, SdoEndpoint.CONTRACT_HASH, self.codec.contract_hash)
            )
            self.send(n, SetAxisState(AxisState.CLOSED_LOOP_CONTROL))

    def deliver(self, msg: can.Message) -> bool:
        frame = Codec.default().decode(msg)  # the bench decodes with its own contract
        return self.sim.handle(frame.node, frame.payload, self.replies, msg)

    def send(self, node: Node, payload: Any) -> bool:
        """As the host sends: authenticated while the drive requires it (Estop and reads
        never are)."""
        secured = (
            node in DRIVES
            and self.sim.drives[node].watchdog.require_auth
            and type(payload) is not Estop
            and not (type(payload) is RxSdo and payload.opcode == 0)
        )
        if secured:
            msgs = self.codec.encode_secured(payload, node, self.auth)
        else:
            msgs = (self.codec.encode(payload, node),)
        ok = True
        for m in msgs:
            self.sent.append(m)
            ok = self.deliver(m) and ok
        return ok

    def forge(self, node: Node, payload: Any, key: Key | None = None) -> None:
        """As a node without the drives' key sends: plain, or signed with ``key``."""
        if key is None:
            self.deliver(self.codec.encode(payload, node))
        else:
            for m in self.codec.encode_secured(payload, node, Authenticator(key)):
                self.deliver(m)

    def setpoint(self, left: float, right: float, ref: float | None = None) -> None:
        ref = max(abs(left), abs(right)) if ref is None else ref
        for n, v in ((L, left), (R, right)):
            self.send(n, SetInputVelAuth(v, min(2.55, math.ceil(ref * 100 - 1e-9) / 100)))

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
        self.setpoint(0.0, 0.0)
        steps = round(seconds * 100)
        for k in range(steps):
            f = min(1.0, (k + 1) / (steps / 2))
            self.setpoint(left * f, right * f)
            self.step()


# ---------------------------------------------------------------- authentication


def test_the_key_holder_arms_and_drives_both_wheels() -> None:
    chair = Chair()
    assert all(d.state == AxisState.CLOSED_LOOP_CONTROL for d in chair.sim.drives.values())
    chair.drive_to(0.3, 0.3)
    assert chair.wheels()[0] / TWO_PI == pytest.approx(0.3, rel=0.05)
    assert not any(k.startswith("auth") for d in chair.sim.drives.values() for k in d.ignored)


@pytest.mark.parametrize("key", [None, WRONG_KEY], ids=["plain-mac-field", "wrong-key"])
def test_a_forged_setpoint_is_refused_and_counted(key: Key | None) -> None:
    chair = Chair()
    chair.drive_to(0.0, 0.0, seconds=0.2)

    def attack(c: Chair) -> None:
        c.setpoint(0.0, 0.0)  # the host keeps commanding standstill
        # the attacker's frame right after, with the live freshness + 1 and a made-up MAC
        fv = c.auth.fv(int(L)) + 1
        c.forge(L, SetInputVelAuth(0.9, 0.9, fv & 0xFF, 0x12345678), key)

    chair.step(100, each=attack)
    d = chair.sim.left
    assert abs(chair.wheels()[0]) / TWO_PI < 0.005
    assert d.ignored["auth_mac_mismatch"] == 100
    assert d.state == AxisState.CLOSED_LOOP_CONTROL  # the host's own frames still arrive


def test_a_replayed_setpoint_is_refused_and_counted() -> None:
    chair = Chair()
    chair.drive_to(0.4, 0.4)
    recorded = [
        m for m in chair.sent if m.arbitration_id == chair.codec.frame_id(SetInputVelAuth, L)
    ][-50:]  # half a second of the host's own setpoints at 0.4 rev/s
    chair.drive_to(0.0, 0.0, seconds=2.0)
    d = chair.sim.left
    before = dict(d.ignored)
    for m in recorded:  # replayed in order, each in its own step, after the host's frame
        chair.setpoint(0.0, 0.0)
        chair.deliver(m)
        chair.step()
    assert d.ignored.get("auth_replayed", 0) - before.get("auth_replayed", 0) == 50
    assert abs(chair.wheels()[0]) / TWO_PI < 0.005


def test_a_hung_host_re_sending_its_last_frame_trips_the_drive() -> None:
    chair = Chair()
    chair.drive_to(0.4, 0.4)
    last = chair.sent[-2]  # the host's last left setpoint, re-sent by a stuck mailbox
    assert last.arbitration_id == chair.codec.frame_id(SetInputVelAuth, L)
    chair.step(30, each=lambda c: c.deliver(last))
    d = chair.sim.left
    assert d.active_errors & AxisError.WATCHDOG_TIMER_EXPIRED
    assert d.ignored["auth_replayed"] >= 9


def test_plain_setpoints_are_refused_with_auth_and_accepted_without() -> None:
    wd = SetpointWatchdog(100, 0.5, True, 0)
    assert not wd.accept_plain(10 * MS, 0.0)
    wd.configure(100, 0.5, False, 0)
    assert wd.accept_plain(20 * MS, 0.3)  # ODrive compatibility when authentication is off


def test_a_command_whose_host_auth_names_another_command_is_refused() -> None:
    chair = Chair()
    chair.send(L, SetAxisState(AxisState.IDLE))
    # the host's Set_Limits, then an attacker's Clear_Errors slipped in before its Host_Auth
    msgs = chair.codec.encode_secured(SetLimits(0.5, 25.0), L, chair.auth)
    chair.deliver(msgs[0])
    chair.forge(L, ClearErrors())
    chair.deliver(msgs[1])
    d = chair.sim.left
    assert d.ignored["auth_missing"] == 1  # the host's Set_Limits, displaced
    assert d.ignored["auth_link_mismatch"] == 1  # the Host_Auth does not fit Clear_Errors
    assert d.rt.vel_limit_revps != 0.5


@pytest.mark.parametrize(
    ("arrival_clock", "gap_ms", "taken"),
    [(True, 1, True), (True, 30, False), (False, 1, False)],
    ids=["real-time-1ms-apart", "real-time-30ms-apart", "lock-step"],
)
def test_in_real_time_a_host_auth_is_judged_by_when_it_arrived_not_by_the_benchs_steps(
    arrival_clock: bool, gap_ms: int, taken: bool
) -> None:
    """A real-time bench that fell behind runs its late steps back to back: between a
    command and its Host_Auth 1 ms apart on the wire it may step five times.  Its drive
    judges the wait (two steps, 20 ms) on the frames' receive times, as a drive with its own
    clock does; in lock-step the steps are the drive's clock and five are too many."""
    chair = Chair()
    chair.send(L, SetAxisState(AxisState.IDLE))
    d = chair.sim.left
    d.auth.arrival_clock = arrival_clock
    cmd, tag = chair.codec.encode_secured(SetLimits(0.5, 25.0), L, chair.auth)
    now = time.time()
    cmd.timestamp, tag.timestamp = now - gap_ms / 1e3, now
    chair.deliver(cmd)
    chair.step(5)  # the bench catching up: 50 ms of steps within a millisecond of wall time
    chair.deliver(tag)
    assert (d.rt.vel_limit_revps == 0.5) is taken, d.ignored
    assert (d.ignored.get("auth_missing", 0) == 0) is taken, d.ignored


# ------------------------------------------------ re-arming after a latched stop


ATTACKS = {
    "clear-arm-plain": [ClearErrors(), SetAxisState(AxisState.CLOSED_LOOP_CONTROL)],
    "watchdog-off-limits-arm": [
        ClearErrors(),
        SetWatchdog(0, 0.0, False, 0, False),
        SetLimits(20.0, 60.0),
        SetAxisState(AxisState.CLOSED_LOOP_CONTROL),
    ],
    "reboot-then-arm": [
        Reboot(RebootAction.REBOOT),
        ClearErrors(),
        SetWatchdog(0, 0.0, False, 0, False),
        SetAxisState(AxisState.CLOSED_LOOP_CONTROL),
    ],
}


@pytest.mark.parametrize("sequence", list(ATTACKS), ids=list(ATTACKS))
@pytest.mark.parametrize("key", [None, WRONG_KEY], ids=["plain", "wrong-key"])
def test_after_a_latched_stop_no_re_arm_sequence_without_the_key_moves_a_wheel(
    sequence: str, key: Key | None
) -> None:
    chair = Chair(SetWatchdog(100, 0.53, True, host_timeout_ms=300, require_neutral=True))
    chair.drive_to(0.4, 0.4, seconds=0.5)
    chair.step(150)  # the host is killed: watchdog stop, latched
    assert all(d.state == AxisState.IDLE for d in chair.sim.drives.values())

    def attacker(c: Chair) -> None:
        for n in (L, R):
            for frame in ATTACKS[sequence]:
                c.forge(n, frame, key)
            c.forge(n, SetInputVel(0.9, 0.0), key)
            c.forge(n, SetInputVelAuth(0.9, 0.9), key)

    chair.step(200, each=attacker)
    assert max(abs(w) for w in chair.wheels()) / TWO_PI < 0.02
    for d in chair.sim.drives.values():
        assert d.state == AxisState.IDLE
        assert d.active_errors  # still latched (host timeout)


def test_after_a_latched_stop_the_key_holder_can_re_arm() -> None:
    chair = Chair()
    chair.drive_to(0.3, 0.3, seconds=0.5)
    chair.step(150)
    for n in (L, R):
        chair.send(n, ClearErrors())
        chair.send(n, SetAxisState(AxisState.CLOSED_LOOP_CONTROL))
    chair.drive_to(0.3, 0.3)
    assert chair.wheels()[0] / TWO_PI == pytest.approx(0.3, rel=0.05)


def test_an_unauthenticated_idle_in_motion_is_a_coordinated_stop() -> None:
    chair = Chair()
    chair.drive_to(0.3, 0.5)
    chair.forge(L, SetAxisState(AxisState.IDLE))  # a foreign node tries to brake one wheel
    chair.step(2, each=lambda c: c.setpoint(0.3, 0.5))  # no Host_Auth for it comes
    left = chair.sim.left
    assert left.ignored["unauthenticated_idle_as_estop"] == 1
    assert left.state == AxisState.CLOSED_LOOP_CONTROL  # ramping, not braked
    assert left.active_errors & AxisError.ESTOP_REQUESTED
    assert not chair.sim.plant.left.brake_engaged


# ------------------------------------------------------------ locked configuration


@pytest.mark.parametrize(
    "frame",
    [
        SetWatchdog(0, 0.53, True, 0, True),  # watchdog off
        SetWatchdog(200, 0.53, True, 0, True),  # watchdog longer
        SetWatchdog(100, 0.53, False, 0, True),  # authentication off
        SetWatchdog(100, 0.53, True, 0, False),  # neutral start off
        SetWatchdog(100, 0.1, True, 0, True),  # gentler stop
        SetLimits(5.0, 25.0),  # faster
        SetLimits(1.0, 1.0),  # a current limit that would turn a stop into coasting
        SetVelGains(0.0, 0.0),
    ],
    ids=[
        "watchdog-off",
        "watchdog-longer",
        "auth-off",
        "neutral-off",
        "stop-decel",
        "velocity-limit-up",
        "current-limit",
        "gains",
    ],
)
def test_once_armed_a_loosening_configuration_is_refused_until_reboot(frame: Any) -> None:
    chair = Chair()
    chair.send(L, SetLimits(1.0, 25.0))  # not applied: in closed loop
    for n in (L, R):
        chair.send(n, SetAxisState(AxisState.IDLE))
    d = chair.sim.left
    assert d.locked
    before = d.rt.copy()
    chair.send(L, frame)  # authenticated, from the host itself, while idle
    assert d.ignored["config_loosening_locked"] == 1
    assert d.rt == before
    chair.send(L, Reboot(RebootAction.REBOOT))
    chair.step(10)  # booted: unlocked, the power-on configuration again
    assert not d.locked
    chair.send(L, frame)
    assert d.ignored["config_loosening_locked"] == 1


def test_once_armed_tightening_is_accepted() -> None:
    chair = Chair()
    for n in (L, R):
        chair.send(n, SetAxisState(AxisState.IDLE))
    d = chair.sim.left
    chair.send(L, SetWatchdog(50, 0.53, True, 200, True))
    chair.send(L, SetLimits(0.5, d.rt.current_limit_a))
    assert d.rt.wd_timeout_ms == 50 and d.rt.wd_host_timeout_ms == 200
    assert d.rt.vel_limit_revps == 0.5
    assert "config_loosening_locked" not in d.ignored


# --------------------------------------------------------------- contract check


def test_a_drive_refuses_to_arm_for_another_wire_contract() -> None:
    sim = ChairSim(load_bench_config({}, source="test"))
    codec = Codec.default()
    auth = Authenticator(KEY)
    replies: Out = []

    def send(payload: Any) -> None:
        for m in codec.encode_secured(payload, L, auth):
            f = codec.decode(m)
            sim.handle(f.node, f.payload, replies, m)

    send(RxSdo(SdoOpcode.WRITE, SdoEndpoint.CONTRACT_HASH, codec.contract_hash ^ 1))
    send(SetAxisState(AxisState.CLOSED_LOOP_CONTROL))
    assert sim.left.state == AxisState.IDLE
    assert sim.left.ignored["contract_mismatch"] == 2  # the write and the arming
    f = codec.decode(codec.encode(RxSdo(SdoOpcode.READ, SdoEndpoint.CONTRACT_HASH), L))
    sim.handle(f.node, f.payload, replies)
    assert replies[-1] == (TxSdo(SdoEndpoint.CONTRACT_HASH, codec.contract_hash), L)
    send(RxSdo(SdoOpcode.WRITE, SdoEndpoint.CONTRACT_HASH, codec.contract_hash))
    send(SetAxisState(AxisState.CLOSED_LOOP_CONTROL))
    assert sim.left.state == AxisState.CLOSED_LOOP_CONTROL


# ------------------------------------------------------------------ neutral start


def test_a_drive_does_not_move_until_it_has_seen_a_neutral_setpoint() -> None:
    chair = Chair()

    def push(c: Chair) -> None:
        c.setpoint(0.3, 0.3)

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
    chair.step(1, each=lambda c: c.setpoint(0.4, 0.4))  # setpoints after the e-stop are ignored
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
    chair.step(20, each=lambda c: c.setpoint(0.3, 0.3))  # a host that comes back
    assert max(abs(w) for w in chair.wheels()) < 0.01
    chair.send(L, SetAxisState(AxisState.CLOSED_LOOP_CONTROL))
    assert chair.sim.left.state == AxisState.IDLE  # errors latched: arming refused
    chair.send(L, ClearErrors())
    chair.send(L, SetAxisState(AxisState.CLOSED_LOOP_CONTROL))
    assert chair.sim.left.state == AxisState.CLOSED_LOOP_CONTROL
    chair.step(5, each=lambda c: c.send(L, SetInputVelAuth(0.3, 0.3)))
    assert abs(chair.wheels()[0]) < 0.01  # re-armed, but no neutral command yet


# ------------------------------------------------------------ host heartbeat monitor


def test_the_drives_stop_when_the_host_heartbeat_is_missing() -> None:
    wd = SetWatchdog(100, 0.53, True, host_timeout_ms=300, require_neutral=True)
    chair = Chair(wd)
    chair.drive_to(0.3, 0.3, seconds=0.5)

    def setpoints_only(c: Chair) -> None:
        c.setpoint(0.3, 0.3)

    chair.step(25, each=setpoints_only)  # setpoints keep coming, heartbeats do not
    d = chair.sim.left
    assert d.active_errors == AxisError.MISSING_INPUT
    chair.step(150, each=setpoints_only)
    assert d.state == AxisState.IDLE and d.disarm_reason == AxisError.MISSING_INPUT


def test_a_repeated_host_heartbeat_does_not_feed_the_monitor() -> None:
    wd = SetWatchdog(100, 0.53, True, host_timeout_ms=300, require_neutral=False)
    chair = Chair(wd)

    def same_heartbeat(c: Chair) -> None:
        c.setpoint(0.0, 0.0)
        c.send(Node.HOST, HostHeartbeat(HostState.TRACKING, 7))

    chair.step(40, each=same_heartbeat)
    assert chair.sim.left.active_errors == AxisError.MISSING_INPUT
    assert chair.sim.left.ignored["host_heartbeat_repeated"] >= 30


def test_fresh_heartbeats_and_setpoints_keep_the_drives_running() -> None:
    wd = SetWatchdog(100, 0.53, True, host_timeout_ms=300, require_neutral=True)
    chair = Chair(wd)

    def host(c: Chair) -> None:
        c.setpoint(0.2, 0.2)
        if len(c.emitted) % 10 == 0:
            c.heartbeat()

    chair.setpoint(0.0, 0.0)
    chair.step(300, each=host)
    assert chair.sim.left.active_errors == 0 and chair.sim.right.active_errors == 0


# ------------------------------------------------------- configuration in motion


@pytest.mark.parametrize(
    "frame",
    [
        SetLimits(5.0, 200.0),
        SetVelGains(0.0, 0.0),
        SetWatchdog(0, 0.0, False),
        Reboot(RebootAction.REBOOT),
    ],
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
