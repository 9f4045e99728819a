"""The safe-stop policy on its own (controller/safe_stop.py): what it sends and commands for
each stop reason, with a recording link and scripted monitors; synthetic time."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import pytest

from controller.config import load_config
from controller.kinematics import radps_to_revps
from controller.limits import CommandLimiter, LimitedCommand
from controller.safe_stop import RE_ESTOP_NS, SafeStopPolicy
from controller.safety import StopReason
from dbc.codec import AxisState, Estop, Node, SetAxisState
from dbc.runtime import params

CFG = load_config()
AUTH = params.replace(CFG, {"drives": {"require_auth": True}}, source="test")
PERIOD_NS = round(CFG.loop.period_s * 1e9)
G = CFG.geometry


@dataclass
class _Drive:
    axis_state: AxisState | None = AxisState.CLOSED_LOOP_CONTROL
    vel_revps: float = 0.0


@dataclass
class _Link:
    drives: dict[Node, _Drive] = field(
        default_factory=lambda: {Node.LEFT: _Drive(), Node.RIGHT: _Drive()}
    )
    sent: list[tuple[Any, Node]] = field(default_factory=list)

    def send(self, msg: Any, node: Node) -> None:
        self.sent.append((msg, node))

    def kinds(self) -> list[tuple[str, Node]]:
        return [(type(m).__name__, n) for m, n in self.sent]


@dataclass
class _Safety:
    culprit: Node | None = None
    since: dict[Node, int] = field(default_factory=dict)

    def feedback_since_ns(self, node: Node) -> int | None:
        return self.since.get(node)


@dataclass
class _Obedience:
    turning: bool = False

    def moving(self, link: Any, t_ns: int, fresh: Any = None) -> bool:
        return self.turning


def _policy(cfg: Any = CFG, **kw: Any) -> tuple[SafeStopPolicy, _Link, CommandLimiter]:
    link = _Link()
    limiter = CommandLimiter(cfg.limits, G.half_track_m, G.wheel_radius_m)
    lsb = 0.01  # Set_Input_Vel_Auth's Stop_Ref_Vel resolution (rev/s)
    policy = SafeStopPolicy(
        cfg,
        link,  # type: ignore[arg-type]
        limiter,
        kw.get("safety", _Safety()),  # type: ignore[arg-type]
        kw.get("obedience", _Obedience()),  # type: ignore[arg-type]
        lambda peak: math.ceil(peak / lsb - 1e-9) * lsb,
    )
    return policy, link, limiter


def _cmd(v: float, omega: float) -> LimitedCommand:
    return LimitedCommand.from_twist(v, omega, G.half_track_m, G.wheel_radius_m)


def test_from_speed_the_ramp_stops_both_wheels_together_at_the_chairs_deceleration() -> None:
    policy, link, limiter = _policy()
    limiter.reset(1.2, 0.4)
    policy.begin(StopReason.OFF_PATH, 0)
    cmds: list[LimitedCommand] = []
    for k in range(1000):
        cmd, stopped = policy.ramp(k * PERIOD_NS)
        cmds.append(cmd)
        if stopped:
            break
    else:
        pytest.fail("the ramp never reported the chair stopped")
    assert link.sent == []  # a plain ramp: no frame of the policy's own
    assert cmds[-1].v_mps == cmds[-1].omega_radps == 0.0
    # v and omega shrink by the same factor: the arc is kept (no yaw kick)
    moving = [c for c in cmds if c.v_mps > 0.0]
    assert all(c.omega_radps / c.v_mps == pytest.approx(0.4 / 1.2) for c in moving)
    # the fastest rim decelerates at safe_stop_decel_mps2, so the stop takes rim / decel
    rim = max(abs(moving[0].left_radps), abs(moving[0].right_radps)) * G.wheel_radius_m
    expected_ticks = rim / CFG.limits.safe_stop_decel_mps2 / CFG.loop.period_s
    assert len(moving) == pytest.approx(expected_ticks, abs=2)
    # reported stopped after two ticks at rest
    assert [c.v_mps for c in cmds[-2:]] == [0.0, 0.0] and cmds[-3].v_mps > 0.0


@pytest.mark.parametrize("reason", [StopReason.ENCODER_STUCK, StopReason.ENCODER_JUMP])
def test_a_blind_speed_loop_brakes_both_drives_at_once(reason: StopReason) -> None:
    policy, link, limiter = _policy()
    limiter.reset(1.0, 0.0)
    policy.begin(reason, 0)
    assert link.kinds() == [("SetAxisState", Node.LEFT), ("SetAxisState", Node.RIGHT)]
    assert all(
        m.requested_state == AxisState.IDLE for m, _ in link.sent if isinstance(m, SetAxisState)
    )
    assert policy.braking


def test_disobeying_drives_get_estop_and_the_ramp_starts_from_their_measured_motion() -> None:
    policy, link, limiter = _policy()
    limiter.reset(0.2, 0.0)  # what the host commanded
    link.drives[Node.LEFT].vel_revps = 0.5  # what the wheels do
    link.drives[Node.RIGHT].vel_revps = 0.7
    policy.begin(StopReason.DISOBEYED, 0)
    assert link.kinds() == [("Estop", Node.LEFT), ("Estop", Node.RIGHT)]
    pr = math.pi * G.wheel_radius_m
    assert limiter.v_mps == pytest.approx(pr * 1.2)
    assert limiter.omega_radps == pytest.approx(pr * 0.2 / G.half_track_m)


def test_a_lost_drive_is_mirrored_the_healthy_one_holds_their_last_shared_command() -> None:
    """The lost drive last heard the host when the host last heard it; it holds that tick's
    command until its watchdog expires: the healthy drive holds the same, then both ramp,
    the healthy one stretched to the lost one's Stop_Ref_Vel so both reach zero together."""
    safety = _Safety(culprit=Node.LEFT, since={Node.LEFT: 5 * PERIOD_NS})
    policy, _link, limiter = _policy(AUTH, safety=safety)
    for k in range(10):
        policy.sent(k * PERIOD_NS, _cmd(0.5 + 0.01 * k, 0.1))
    now = 9 * PERIOD_NS
    limiter.reset(0.59, 0.1)
    policy.begin(StopReason.ENCODER_STALE, now)
    shared = _cmd(0.55, 0.1)  # the command of the lost drive's last tick heard
    until = 5 * PERIOD_NS + AUTH.drives.watchdog_timeout_ms * 1_000_000
    assert policy.hold == (shared, until)
    assert (limiter.v_mps, limiter.omega_radps) == (shared.v_mps, shared.omega_radps)
    peak = radps_to_revps(max(abs(shared.left_radps), abs(shared.right_radps)))
    ref = math.ceil(peak / 0.01 - 1e-9) * 0.01
    assert policy.decel_mps2 == pytest.approx(AUTH.limits.safe_stop_decel_mps2 * peak / ref)
    t = now
    while t < until:
        assert policy.ramp(t) == (shared, False)
        t += PERIOD_NS
    cmd, _ = policy.ramp(t)
    assert cmd.v_mps < shared.v_mps  # the ramp, from the shared command
    assert policy.hold is None


def test_a_drive_that_leaves_closed_loop_during_the_hold_brakes_both_and_ends_the_hold() -> None:
    safety = _Safety(culprit=Node.RIGHT, since={Node.RIGHT: 0})
    policy, link, limiter = _policy(safety=safety)
    policy.sent(0, _cmd(0.8, 0.0))
    limiter.reset(0.8, 0.0)
    policy.begin(StopReason.ENCODER_STALE, PERIOD_NS)
    assert policy.hold is not None
    link.drives[Node.LEFT].axis_state = AxisState.IDLE  # rebooted
    cmd, _ = policy.ramp(2 * PERIOD_NS)
    assert policy.braking and policy.hold is None
    assert ("SetAxisState", Node.RIGHT) in link.kinds()
    assert cmd.v_mps < 0.8


def test_after_a_latched_stop_a_turning_wheel_is_estopped_again_at_most_every_100_ms() -> None:
    obedience = _Obedience(turning=True)
    policy, link, _ = _policy(obedience=obedience)
    ticks = 50  # 0.5 s
    for k in range(ticks):
        policy.after_stop(k * PERIOD_NS, latched=True)
    rounds = math.ceil(ticks * PERIOD_NS / RE_ESTOP_NS)
    assert policy.re_estops == rounds
    assert [type(m) for m, _ in link.sent] == [Estop] * (2 * rounds)
    # DONE (not latched) and a wheel at rest: nothing is sent, the ticks are counted
    policy2, link2, _ = _policy(obedience=_Obedience(turning=True))
    for k in range(ticks):
        policy2.after_stop(k * PERIOD_NS, latched=False)
    assert link2.sent == [] and policy2.stopped_ticks == ticks
