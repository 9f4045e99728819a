"""Emulated ODrive drive: state machine, telemetry, velocity loop, watchdog (synthetic time)."""

from __future__ import annotations

import itertools
import math
from typing import Any

import pytest

from dbc.codec import (
    AxisError,
    AxisState,
    BusVoltageCurrent,
    ClearErrors,
    ControlMode,
    EncoderCount,
    EncoderEstimates,
    Estop,
    GetError,
    Heartbeat,
    InputMode,
    Iq,
    Node,
    ProcedureResult,
    Reboot,
    RebootAction,
    Request,
    SetAxisState,
    SetControllerMode,
    SetInputVel,
    SetLimits,
    SetVelDerivativeGain,
    SetVelGains,
    SetWatchdog,
    Temperature,
)
from firmware_sim.config import load_bench_config
from firmware_sim.drive import Out
from firmware_sim.encoder import QuadratureEncoder, wrap_int32
from firmware_sim.pid import VelocityPid
from firmware_sim.sim import ChairSim
from firmware_sim.watchdog import SetpointWatchdog

L, R = Node.LEFT, Node.RIGHT
MS = 1_000_000
TWO_PI = 2.0 * math.pi


#: These tests are about the ODrive emulation itself: a stock ODrive, no authentication and no
#: contract check (tests/unit/test_drive_safety.py covers those).
STOCK = {"drive.require_auth": False, "drive.check_contract": False}


class Rig:
    """A ChairSim with helpers: send payloads, run steps, collect emitted frames."""

    def __init__(self, **overrides: Any) -> None:
        self.sim = ChairSim(load_bench_config({**STOCK, **overrides}, source="test"))
        self.emitted: list[tuple[int, Any, Node | None]] = []
        self.replies: Out = []
        self._emit()  # frames due at t = 0, as the bench sends them

    def _emit(self) -> None:
        out: Out = []
        self.sim.emit_due(out)
        self.emitted.extend((self.sim.now_ns, p, n) for p, n in out)

    def send(self, node: Node, payload: Any) -> bool:
        return self.sim.handle(node, payload, self.replies)

    def arm(self, *nodes: Node) -> None:
        for n in nodes or (L, R):
            self.send(n, SetAxisState(AxisState.CLOSED_LOOP_CONTROL))

    def run(self, seconds: float, each_step: Any = None) -> None:
        for _ in range(round(seconds * 100)):
            if each_step is not None:
                each_step(self)
            self.sim.advance()
            self._emit()

    def frames(self, cls: type, node: Node | None = None) -> list[Any]:
        return [p for _t, p, n in self.emitted if type(p) is cls and (node is None or n == node)]

    def wheel_revps(self, node: Node) -> float:
        wheel = self.sim.plant.left if node == L else self.sim.plant.right
        return wheel.omega_radps / TWO_PI


# ------------------------------------------------------------------ state machine


def test_a_drive_powers_on_idle_braked_and_arms_on_request() -> None:
    rig = Rig()
    d = rig.sim.left
    assert d.state == AxisState.IDLE
    assert rig.sim.plant.left.brake_engaged
    assert not rig.sim.plant.left.powered
    rig.arm(L)
    assert d.state == AxisState.CLOSED_LOOP_CONTROL
    assert d.procedure_result == ProcedureResult.BUSY
    assert rig.sim.plant.left.powered and not rig.sim.plant.left.brake_engaged
    rig.send(L, SetAxisState(AxisState.IDLE))
    assert d.state == AxisState.IDLE
    assert d.procedure_result == ProcedureResult.CANCELLED


def test_estop_latches_and_blocks_arming_until_errors_are_cleared() -> None:
    rig = Rig()
    d = rig.sim.left
    rig.arm(L)
    rig.send(L, Estop())
    assert d.state == AxisState.IDLE
    assert d.active_errors == AxisError.ESTOP_REQUESTED
    assert d.disarm_reason == AxisError.ESTOP_REQUESTED
    rig.arm(L)
    assert d.state == AxisState.IDLE
    assert d.procedure_result == ProcedureResult.DISARMED
    rig.send(L, ClearErrors())
    rig.arm(L)
    assert d.state == AxisState.CLOSED_LOOP_CONTROL


def test_a_drive_ignores_frames_for_the_other_node_and_its_own_frames() -> None:
    rig = Rig()
    assert rig.sim.left.handle(R, SetAxisState(AxisState.CLOSED_LOOP_CONTROL), 0, []) is False
    assert rig.sim.left.state == AxisState.IDLE
    assert rig.send(L, Heartbeat(0, AxisState.CLOSED_LOOP_CONTROL)) is False  # an echo
    assert rig.send(L, EncoderEstimates(1.0, 2.0)) is False
    assert rig.sim.left.state == AxisState.IDLE
    assert rig.sim.left.ignored == {"not_a_command": 2}
    assert rig.send(Node.HOST, SetAxisState(AxisState.CLOSED_LOOP_CONTROL)) is False


def test_reboot_goes_silent_then_restores_power_on_defaults() -> None:
    rig = Rig()
    d = rig.sim.left
    rig.arm(L)
    rig.send(L, SetVelGains(10.0, 20.0))
    rig.send(L, SetInputVel(0.2))
    rig.run(0.5)
    rig.send(L, SetInputVel(0.0))
    rig.run(1.0)
    assert d.encoder.shadow_count > 1000
    rig.send(L, Reboot(RebootAction.REBOOT))
    assert d.state == AxisState.IDLE
    rig.emitted.clear()
    rig.run(0.04)  # boot time is 50 ms
    assert rig.frames(Heartbeat, L) == []
    assert rig.frames(EncoderEstimates, L) == []
    assert rig.send(L, SetAxisState(AxisState.CLOSED_LOOP_CONTROL)) is False  # deaf while booting
    rig.run(0.5)
    hbs = rig.frames(Heartbeat, L)
    assert hbs and hbs[0] == Heartbeat(0, AxisState.IDLE, ProcedureResult.SUCCESS)
    assert d.rt.kp == 80.0 and d.rt.ki == 400.0  # chair.toml defaults again
    assert abs(d.encoder.shadow_count) <= 1  # an incremental encoder restarts at zero
    left_times = [t for t, p, n in rig.emitted if type(p) is Heartbeat and n == L]
    assert left_times == [(1550 + 100 * k) * MS for k in range(5)]  # restarts after the boot
    assert len(rig.frames(Heartbeat, R)) == 5  # the other node kept talking: 1.6 ... 2.0 s


def test_save_configuration_survives_a_reboot() -> None:
    rig = Rig()
    rig.send(L, SetVelGains(12.0, 34.0))
    rig.send(L, Reboot(RebootAction.SAVE_CONFIGURATION))
    rig.run(0.1)
    assert (rig.sim.left.rt.kp, rig.sim.left.rt.ki) == (12.0, 34.0)
    rig.send(L, Reboot(RebootAction.ERASE_CONFIGURATION))
    rig.run(0.1)
    assert (rig.sim.left.rt.kp, rig.sim.left.rt.ki) == (80.0, 400.0)


# ---------------------------------------------------------------------- telemetry


def test_cyclic_frames_follow_the_dbc_cycle_times() -> None:
    rig = Rig()
    rig.run(1.0)
    for node in (L, R):
        assert len(rig.frames(Heartbeat, node)) == 11
        assert len(rig.frames(EncoderEstimates, node)) == 101
        assert len(rig.frames(Iq, node)) == 11
        assert len(rig.frames(BusVoltageCurrent, node)) == 11
    times = [t for t, p, n in rig.emitted if type(p) is Heartbeat and n == L]
    assert times == [k * 100 * MS for k in range(11)]


@pytest.mark.parametrize(
    "what", [GetError, EncoderEstimates, EncoderCount, Iq, Temperature, BusVoltageCurrent]
)
def test_rtr_requests_are_answered_with_the_requested_message(what: type) -> None:
    rig = Rig()
    rig.arm(R)
    rig.send(R, SetInputVel(0.1))
    rig.run(0.2)
    assert rig.send(R, Request(what))
    (payload, node), *rest = rig.replies
    assert not rest
    assert node == R and type(payload) is what


def test_estimates_come_from_the_quantized_encoder_in_wheel_revolutions() -> None:
    rig = Rig()
    rig.arm()
    rig.send(L, SetInputVel(0.25))
    rig.send(R, SetInputVel(0.25))
    rig.run(2.0)
    est = rig.frames(EncoderEstimates, L)[-1]
    true_rev = rig.sim.plant.left.angle_rad / TWO_PI
    counts_per_wheel_rev = 8192 * 32
    assert est.pos_rev == pytest.approx(true_rev, abs=3.0 / counts_per_wheel_rev + 0.25e-3)
    assert est.vel_revps == pytest.approx(0.25, rel=2e-3)
    rig.send(L, Request(EncoderCount))
    count = rig.replies[-1][0]
    assert count.shadow_count == math.floor(true_rev * counts_per_wheel_rev)
    assert count.count_in_cpr == count.shadow_count % 8192


def test_bus_current_iq_and_temperature_reflect_the_load() -> None:
    rig = Rig()
    rig.arm(L)
    rig.send(L, SetInputVel(0.5))
    rig.run(0.1)  # still accelerating, current-limited
    iq = rig.frames(Iq, L)[-1]
    assert iq.setpoint_a == pytest.approx(25.0)
    assert iq.measured_a > 20.0
    assert rig.frames(BusVoltageCurrent, L)[-1].current_a > 1.0
    assert rig.sim.left.motor_degc > 25.0


# ------------------------------------------------------------------ velocity loop


def _step_metrics(rig: Rig, node: Node, target: float, seconds: float) -> tuple[float, float]:
    samples: list[float] = []
    rig.sim.add_tick_hook(lambda _t, _p: samples.append(rig.wheel_revps(node)))
    rig.run(seconds)
    dt = 0.001
    t10 = next(i for i, y in enumerate(samples) if y >= 0.1 * target) * dt
    t90 = next(i for i, y in enumerate(samples) if y >= 0.9 * target) * dt
    overshoot = max(samples) / target - 1.0
    return t90 - t10, overshoot


def test_default_gains_give_a_fast_well_damped_step_response() -> None:
    rig = Rig()
    rig.arm()
    rig.send(L, SetInputVel(0.02))
    rig.send(R, SetInputVel(0.02))
    rise_s, overshoot = _step_metrics(rig, R, 0.02, 1.0)
    print(f"\nsmall step 0.02 rev/s: rise {rise_s * 1e3:.0f} ms, overshoot {overshoot:.1%}")
    assert rise_s < 0.040
    assert overshoot < 0.08
    assert rig.wheel_revps(R) == pytest.approx(0.02, rel=0.01)


def test_a_large_step_is_current_limited_without_windup_overshoot() -> None:
    rig = Rig()
    rig.arm()
    rig.send(L, SetInputVel(0.5))
    rig.send(R, SetInputVel(0.5))
    rise_s, overshoot = _step_metrics(rig, R, 0.5, 1.5)
    print(f"\nlarge step 0.5 rev/s: rise {rise_s * 1e3:.0f} ms, overshoot {overshoot:.1%}")
    assert max(abs(p.setpoint_a) for p in rig.frames(Iq, R)) <= 25.0 + 1e-9
    assert overshoot < 0.03
    assert rig.wheel_revps(R) == pytest.approx(0.5, rel=1e-3)


def test_the_velocity_limit_clamps_the_setpoint() -> None:
    rig = Rig()
    rig.arm(L)
    rig.send(L, SetLimits(velocity_limit_revps=0.2, current_limit_a=10.0))
    rig.send(L, SetInputVel(0.6))
    rig.run(2.0)
    assert rig.sim.left.vel_setpoint_revps == 0.2
    assert rig.wheel_revps(L) == pytest.approx(0.2, rel=0.01)


def test_the_current_limit_clamps_the_current_command_and_cannot_exceed_the_hardware() -> None:
    rig = Rig()
    rig.arm(L)
    rig.send(L, SetLimits(velocity_limit_revps=1.0, current_limit_a=5.0))
    peak = []
    rig.sim.add_tick_hook(lambda _t, p: peak.append(abs(p.left.current_a)))
    rig.send(L, SetInputVel(0.8))
    rig.run(0.3)
    assert max(peak) < 5.0 * 1.01
    rig.send(L, SetLimits(velocity_limit_revps=1.0, current_limit_a=150.0))
    assert rig.sim.left.rt.current_limit_a == 60.0  # motor.max_current_a


def test_vel_ramp_mode_slews_the_setpoint_at_the_ramp_rate() -> None:
    rig = Rig()
    rig.arm(L)
    rig.send(L, SetControllerMode(ControlMode.VELOCITY_CONTROL, InputMode.VEL_RAMP))
    rig.send(L, SetInputVel(0.5))
    rig.run(0.1)
    assert rig.sim.left.vel_setpoint_revps == pytest.approx(0.2, abs=1e-9)  # 2 rev/s^2 * 0.1 s
    rig.run(0.3)
    assert rig.sim.left.vel_setpoint_revps == 0.5


def test_unsupported_control_modes_are_refused() -> None:
    rig = Rig()
    rig.send(L, SetControllerMode(ControlMode.POSITION_CONTROL, InputMode.PASSTHROUGH))
    assert rig.sim.left.control_mode == ControlMode.VELOCITY_CONTROL
    assert rig.sim.left.ignored["unsupported_mode"] == 1


def test_gains_from_the_bus_change_the_loop() -> None:
    soft, stiff = Rig(), Rig()
    for rig, kp in ((soft, 5.0), (stiff, 80.0)):
        rig.arm(L)
        rig.send(L, SetVelGains(kp, 0.0))
        rig.send(L, SetVelDerivativeGain(0.5, 50.0))
        rig.send(L, SetInputVel(0.02))
        rig.run(0.03)
    assert stiff.wheel_revps(L) > 1.5 * soft.wheel_revps(L)
    assert soft.sim.left.pid.kd == 0.5


def test_pid_derivative_acts_on_the_measurement_only() -> None:
    pid = VelocityPid(0.001)
    pid.set_gains(0.0, 0.0)
    pid.set_derivative(2.0, 0.0)
    assert pid.update(1.0, 0.0, 0.0, -10, 10) == 0.0  # setpoint step: no kick
    assert pid.update(5.0, 0.0, 0.0, -10, 10) == 0.0
    assert pid.update(5.0, 0.001, 0.0, -10, 10) == pytest.approx(-2.0)  # 1 rev/s^2
    filtered = VelocityPid(0.001)
    filtered.set_gains(0.0, 0.0)
    filtered.set_derivative(2.0, 10.0)
    filtered.update(0.0, 0.0, 0.0, -10, 10)
    first = filtered.update(0.0, 0.001, 0.0, -10, 10)
    assert -2.0 < first < 0.0  # low-passed
    for k in range(2, 500):
        out = filtered.update(0.0, 0.001 * k, 0.0, -10, 10)
    assert out == pytest.approx(-2.0, rel=1e-3)


def test_pid_integrator_does_not_wind_up_on_a_limit() -> None:
    pid = VelocityPid(0.001)
    pid.set_gains(1.0, 100.0)
    for _ in range(5000):
        assert pid.update(1.0, 0.0, 0.0, -0.5, 0.5) == 0.5
    assert pid.integrator <= 0.5
    # Once the error reverses, the output leaves the limit at once.
    assert pid.update(0.0, 1.0, 0.0, -0.5, 0.5) < 0.0


# ----------------------------------------------------------------------- watchdog


def test_the_watchdog_ramps_to_zero_at_stop_decel_then_idles() -> None:
    rig = Rig()
    rig.arm(L)
    rig.send(L, SetWatchdog(timeout_ms=100, stop_decel_revps2=2.0, require_auth=False))
    rig.run(1.0, each_step=lambda r: r.send(L, SetInputVel(0.5)))
    assert rig.sim.left.active_errors == 0
    setpoints: list[float] = []
    rig.sim.add_tick_hook(lambda _t, _p: setpoints.append(rig.sim.left.vel_setpoint_revps))
    rig.run(0.5)  # no setpoints
    d = rig.sim.left
    assert d.active_errors & AxisError.WATCHDOG_TIMER_EXPIRED
    ramp = [s for s in setpoints[101:] if 0.0 < s < 0.5]
    slopes = {round((a - b) / 0.001, 6) for a, b in itertools.pairwise(ramp)}
    assert slopes == {2.0}
    rig.run(0.5)
    assert d.state == AxisState.IDLE
    assert d.disarm_reason == AxisError.WATCHDOG_TIMER_EXPIRED
    assert d.procedure_result == ProcedureResult.DISARMED
    assert abs(rig.wheel_revps(L)) < 0.01
    assert rig.frames(Heartbeat, L)[-1].axis_error & AxisError.WATCHDOG_TIMER_EXPIRED


def test_setpoints_keep_the_watchdog_fed() -> None:
    rig = Rig()
    rig.arm(L)
    rig.send(L, SetWatchdog(timeout_ms=30, stop_decel_revps2=2.0, require_auth=False))
    rig.run(2.0, each_step=lambda r: r.send(L, SetInputVel(0.1)))
    assert rig.sim.left.state == AxisState.CLOSED_LOOP_CONTROL
    assert rig.sim.left.active_errors == 0


def test_with_auth_required_plain_setpoints_do_not_feed_the_watchdog() -> None:
    plain = Rig()
    plain.arm(L)
    plain.send(L, SetWatchdog(timeout_ms=50, stop_decel_revps2=0.0, require_auth=False))
    plain.sim.left.secoc.key = None  # a stock drive has no key: Require_Auth is refused
    plain.send(L, SetWatchdog(timeout_ms=50, stop_decel_revps2=0.0, require_auth=True))
    assert plain.sim.left.ignored["auth_no_key"] == 1
    plain.run(0.5, lambda r: r.send(L, SetInputVel(0.1)))
    assert plain.sim.left.state == AxisState.CLOSED_LOOP_CONTROL  # fed by plain setpoints
    assert plain.wheel_revps(L) == pytest.approx(0.1, rel=0.05)


def test_watchdog_class_semantics() -> None:
    wd = SetpointWatchdog(
        timeout_ms=0, stop_decel_revps2=1.0, require_auth=False, host_timeout_ms=0
    )
    assert not wd.expired(10**12)  # 0 = off
    wd.configure(100, 1.0, True, 250)
    wd.arm(0)
    assert not wd.accept_plain(10 * MS)
    assert wd.accept_auth(40 * MS)
    assert not wd.expired(140 * MS)
    assert wd.expired(141 * MS)
    assert wd.host_timeout_ms == 250


# ------------------------------------------------------------------------ encoder


def test_the_encoder_pll_tracks_a_constant_speed_and_quantizes_position() -> None:
    enc = QuadratureEncoder(cpr=8192, gear_ratio=32.0, bandwidth_radps=400.0, dt_s=0.001)
    enc.reset(1.234)
    w = 3.0  # rad/s at the wheel
    angle = 1.234
    for _ in range(1000):
        angle += w * 0.001
        enc.update(angle)
    assert enc.vel_revps == pytest.approx(w / TWO_PI, rel=1e-3)
    travelled_rev = (angle - 1.234) / TWO_PI
    assert enc.pos_rev == pytest.approx(travelled_rev, abs=2 / (8192 * 32))
    assert enc.shadow_count == math.floor(angle * 8192 * 32 / TWO_PI) - math.floor(
        1.234 * 8192 * 32 / TWO_PI
    )


def test_int32_counts_wrap_like_hardware() -> None:
    assert wrap_int32(2**31) == -(2**31)
    assert wrap_int32(-(2**31) - 1) == 2**31 - 1
    assert wrap_int32(12345) == 12345
