"""Emulated ODrive 0.6 drive node: axis state machine, velocity PID, watchdog, telemetry.

One :class:`DriveNode` per wheel (node 1 left, node 2 right).  It is fed decoded
payloads (:meth:`DriveNode.handle`), produces payloads for the bench to encode
(:meth:`DriveNode.emit_due`, replies to RTR requests), and runs its 1 kHz control
tick against the :class:`~firmware_sim.plant.Wheel` it drives
(:meth:`DriveNode.control`; :class:`~firmware_sim.sim.ChairSim` samples
:attr:`DriveNode.encoder` at the end of every tick).  It never sees CAN IDs or
bytes.

Behaviour (ODrive 0.6 semantics unless marked *ext*):

* states IDLE (1) and CLOSED_LOOP_CONTROL (8); Estop latches ESTOP_REQUESTED and
  idles; arming while an error is latched is refused (procedure result
  DISARMED); Clear_Errors clears; Reboot restores the power-on configuration
  after a silent boot (the encoder count restarts at zero, like a real
  incremental encoder);
* VELOCITY_CONTROL with PASSTHROUGH or VEL_RAMP input; setpoints in wheel rev/s,
  torque feed-forward in motor N*m; the velocity limit clamps the setpoint and
  the current limit the current command;
* a PID at 1 kHz: ``tau = Kp e + Ki int(e) - Kd d/dt(filtered measurement) + ff``
  (Kd *ext*), conditional-integration anti-windup against the current and the
  voltage limit, ``i* = tau / K``; voltage-mode current control
  ``u = R i* + K omega_motor_estimate`` saturated at the bus voltage;
* the setpoint watchdog (:class:`SetpointWatchdog`, *ext* configuration via
  Set_Watchdog): expiry latches WATCHDOG_TIMER_EXPIRED, ramps the setpoint to
  zero at Stop_Decel and then idles;
* not in closed loop, the inverter is off and the holding brake engaged.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

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
    HostHeartbeat,
    InputMode,
    Iq,
    Node,
    Reboot,
    Request,
    SetAxisState,
    SetControllerMode,
    SetInputVel,
    SetInputVelE2E,
    SetLimits,
    SetVelDerivativeGain,
    SetVelGains,
    SetWatchdog,
    Temperature,
)
from firmware_sim.config import BenchConfig, DriveParams
from firmware_sim.encoder import QuadratureEncoder, wrap_int32
from firmware_sim.plant import Wheel

_VEL_RAMP = int(InputMode.VEL_RAMP)

#: ODrive 0.6 procedure results (the DBC's Procedure_Result choices).
PROCEDURE_SUCCESS = 0
PROCEDURE_BUSY = 1
PROCEDURE_CANCELLED = 2
PROCEDURE_DISARMED = 3
PROCEDURE_INVALID_STATE = 13

#: Requested states a pre-calibrated emulated drive completes at once.
_CALIBRATION_STATES = frozenset(
    {
        AxisState.STARTUP_SEQUENCE,
        AxisState.FULL_CALIBRATION_SEQUENCE,
        AxisState.MOTOR_CALIBRATION,
        AxisState.ENCODER_INDEX_SEARCH,
        AxisState.ENCODER_OFFSET_CALIBRATION,
        AxisState.ENCODER_DIR_FIND,
        AxisState.ENCODER_HALL_POLARITY_CALIBRATION,
        AxisState.ENCODER_HALL_PHASE_CALIBRATION,
    }
)

#: Frames that change the axis' configuration.  With Require_E2E (the safety profile) they are
#: refused while the axis is in closed loop: a chair in motion is not reconfigured (or
#: rebooted) by a stray or corrupted frame; the host configures the drives before arming.
_CONFIG_FRAMES = frozenset(
    {
        SetControllerMode,
        SetLimits,
        SetVelGains,
        SetVelDerivativeGain,
        SetWatchdog,
        Reboot,
    }
)

#: Reboot actions (the DBC's Action choices).
REBOOT = 0
SAVE_CONFIGURATION = 1
ERASE_CONFIGURATION = 2

#: Where nodes append (payload, node) pairs for the bench to encode and send.
Out = list[tuple[Any, Node | None]]


class VelocityPid:
    """The drive's velocity loop: wheel rev/s in, motor N*m out, at a fixed rate.

    Gains follow ODrive's units with wheel revolutions: ``kp`` N*m/(rev/s),
    ``ki`` N*m/rev, ``kd`` N*m/(rev/s^2).  The derivative acts on the
    measurement (no kick on setpoint steps) through a first-order low-pass of
    cut-off ``cutoff_hz`` (0 = the raw difference).  Anti-windup by conditional
    integration: while the output sits on a limit the integrator only moves away
    from it; the integrator itself never leaves the torque range.
    """

    __slots__ = ("_alpha", "_d_filt", "_dt_s", "_prev_meas", "integrator", "kd", "ki", "kp")

    def __init__(self, dt_s: float) -> None:
        self._dt_s = dt_s
        self.kp = 0.0
        self.ki = 0.0
        self.kd = 0.0
        self._alpha = 1.0
        self.integrator = 0.0
        self._d_filt = 0.0
        self._prev_meas: float | None = None

    def set_gains(self, kp: float, ki: float) -> None:
        self.kp = kp
        self.ki = ki

    def set_derivative(self, kd: float, cutoff_hz: float) -> None:
        self.kd = kd
        if cutoff_hz <= 0.0:
            self._alpha = 1.0
        else:
            self._alpha = 1.0 - math.exp(-math.tau * cutoff_hz * self._dt_s)

    def reset(self) -> None:
        self.integrator = 0.0
        self._d_filt = 0.0
        self._prev_meas = None

    def update(self, sp: float, meas: float, ff: float, lo: float, hi: float) -> float:
        """One tick: torque command within ``[lo, hi]`` for setpoint ``sp`` and ``meas``."""
        err = sp - meas
        prev = self._prev_meas
        self._prev_meas = meas
        out = self.kp * err + self.integrator + ff
        if self.kd:
            if prev is not None:
                raw = (meas - prev) / self._dt_s
                self._d_filt += self._alpha * (raw - self._d_filt)
            out -= self.kd * self._d_filt
        step = self.ki * self._dt_s * err
        if out > hi:
            out = hi
            if step < 0.0:
                self.integrator += step
        elif out < lo:
            out = lo
            if step > 0.0:
                self.integrator += step
        else:
            self.integrator += step
        if self.integrator > hi and self.integrator > 0.0:
            self.integrator = max(hi, 0.0)
        elif self.integrator < lo and self.integrator < 0.0:
            self.integrator = min(lo, 0.0)
        return out


#: AUTOSAR E2E profile 2 receive check (docs/safety.md): right after a valid frame the counter
#: may advance by 1..E2E_MAX_DELTA_COUNTER_INIT (one lost frame tolerated); the window widens
#: by one for every further E2E cycle without a valid frame, as profile 2's MaxDeltaCounter
#: does, up to 15.  A repeated counter is stale; a counter outside the window (an older,
#: reordered or replayed frame) is a wrong sequence: neither is applied or fed.
E2E_MAX_DELTA_COUNTER_INIT = 2
_E2E_MODULO = 16

#: Why a setpoint or heartbeat was not acted on (keys of :attr:`DriveNode.ignored`).
REJECT_PLAIN = "plain_setpoint_e2e_required"
REJECT_REPEATED = "e2e_counter_repeated"
REJECT_SEQUENCE = "e2e_wrong_sequence"
REJECT_NOT_NEUTRAL = "not_neutral_after_arm"
REJECT_HOST_REPEATED = "host_heartbeat_repeated"


class SetpointWatchdog:
    """Setpoint watchdog and host-heartbeat monitor of one axis (configured by Set_Watchdog).

    ``timeout_ms == 0`` disables the setpoint watchdog, ``host_timeout_ms == 0`` the host
    monitor.  Both start timing when the axis arms (:meth:`arm`) and restart on Set_Watchdog
    (:meth:`restart`).  Every *accepted* setpoint feeds the watchdog; with ``require_e2e``:

    * plain Set_Input_Vel frames are refused;
    * an E2E frame is accepted only if its 4-bit counter advanced by 1..max_delta since the
      last accepted one (AUTOSAR E2E profile 2: repeated = stale, outside the window = wrong
      sequence, see :data:`E2E_MAX_DELTA_COUNTER_INIT`), so a hung host whose last frame keeps
      being re-sent, duplicates and reordered (older) frames never feed it;

    With ``require_neutral``, setpoints after arming are refused until one is neutral
    (``|v| <= neutral_revps``): a host that starts with a non-zero command does not move the
    wheel (and, not feeding the watchdog, trips it).

    The last accepted E2E frame's ``stop_ref_revps`` is kept for the coordinated stop.  The
    host monitor is fed by every Host_Heartbeat whose alive counter changed.
    """

    __slots__ = (
        "_host_counter",
        "_last_counter",
        "e2e_period_ns",
        "host_last_ns",
        "host_timeout_ms",
        "host_timeout_ns",
        "last_feed_ns",
        "last_reject",
        "neutral_revps",
        "neutral_seen",
        "require_e2e",
        "require_neutral",
        "stop_decel_revps2",
        "stop_ref_revps",
        "timeout_ns",
    )

    def __init__(
        self,
        timeout_ms: int,
        stop_decel_revps2: float,
        require_e2e: bool,
        host_timeout_ms: int,
        require_neutral: bool = False,
        *,
        e2e_period_ns: int = 10_000_000,
        neutral_revps: float = 0.01,
    ) -> None:
        self.timeout_ns = 0
        self.stop_decel_revps2 = 0.0
        self.require_e2e = False
        self.require_neutral = False
        self.host_timeout_ms = 0
        self.host_timeout_ns = 0
        self.e2e_period_ns = e2e_period_ns
        self.neutral_revps = neutral_revps
        self.last_feed_ns = 0
        self.host_last_ns = 0
        self.stop_ref_revps = 0.0
        self.neutral_seen = False
        self.last_reject = ""
        self._last_counter: int | None = None
        self._host_counter: int | None = None
        self.configure(timeout_ms, stop_decel_revps2, require_e2e, host_timeout_ms, require_neutral)

    def configure(
        self,
        timeout_ms: int,
        stop_decel_revps2: float,
        require_e2e: bool,
        host_timeout_ms: int,
        require_neutral: bool = False,
    ) -> None:
        self.timeout_ns = int(timeout_ms) * 1_000_000
        self.stop_decel_revps2 = float(stop_decel_revps2)
        self.require_e2e = bool(require_e2e)
        self.require_neutral = bool(require_neutral)
        self.host_timeout_ms = int(host_timeout_ms)
        self.host_timeout_ns = self.host_timeout_ms * 1_000_000

    def arm(self, now_ns: int) -> None:
        """The axis entered closed loop: start timing, forget the counter, wait for neutral."""
        self.restart(now_ns)
        self._last_counter = None
        self.stop_ref_revps = 0.0
        self.neutral_seen = False

    def restart(self, now_ns: int) -> None:
        """Restart both timers from ``now_ns`` (Set_Watchdog), keeping the E2E state."""
        self.last_feed_ns = now_ns
        self.host_last_ns = now_ns

    def _neutral_ok(self, vel_revps: float) -> bool:
        if self.neutral_seen or not self.require_neutral:
            return True
        if -self.neutral_revps <= vel_revps <= self.neutral_revps:
            self.neutral_seen = True
            return True
        self.last_reject = REJECT_NOT_NEUTRAL
        return False

    def accept_plain(self, now_ns: int, vel_revps: float = 0.0) -> bool:
        """A Set_Input_Vel arrived: apply it (and feed) unless E2E is required."""
        if self.require_e2e:
            self.last_reject = REJECT_PLAIN
            return False
        if not self._neutral_ok(vel_revps):
            return False
        self.stop_ref_revps = 0.0
        self.last_feed_ns = now_ns
        return True

    def accept_e2e(
        self, counter: int, now_ns: int, vel_revps: float = 0.0, stop_ref_revps: float = 0.0
    ) -> bool:
        """A Set_Input_Vel_E2E (CRC already checked) arrived: apply it (and feed)?"""
        last = self._last_counter
        if last is not None:
            delta = (counter - last) % _E2E_MODULO
            if delta == 0:
                self.last_reject = REJECT_REPEATED
                return False
            cycles = (now_ns - self.last_feed_ns) // self.e2e_period_ns
            max_delta = min(_E2E_MODULO - 1, E2E_MAX_DELTA_COUNTER_INIT + max(0, cycles - 1))
            if delta > max_delta:
                self.last_reject = REJECT_SEQUENCE
                return False
        if not self._neutral_ok(vel_revps):
            return False
        self._last_counter = counter
        self.stop_ref_revps = stop_ref_revps
        self.last_feed_ns = now_ns
        return True

    def feed_host(self, alive_counter: int, now_ns: int) -> bool:
        """A Host_Heartbeat arrived: feed the host monitor if its alive counter changed."""
        if alive_counter == self._host_counter:
            self.last_reject = REJECT_HOST_REPEATED
            return False
        self._host_counter = alive_counter
        self.host_last_ns = now_ns
        return True

    def expired(self, now_ns: int) -> bool:
        return self.timeout_ns > 0 and now_ns - self.last_feed_ns > self.timeout_ns

    def host_expired(self, now_ns: int) -> bool:
        return self.host_timeout_ns > 0 and now_ns - self.host_last_ns > self.host_timeout_ns


@dataclass(slots=True)
class _Runtime:
    """The axis configuration that Set_* frames change and Reboot restores."""

    kp: float
    ki: float
    kd: float
    kd_cutoff_hz: float
    vel_limit_revps: float
    current_limit_a: float
    input_mode: InputMode
    vel_ramp_rate_revps2: float
    wd_timeout_ms: int
    wd_stop_decel_revps2: float
    wd_require_e2e: bool
    wd_host_timeout_ms: int
    wd_require_neutral: bool

    @classmethod
    def from_params(cls, p: DriveParams) -> _Runtime:
        return cls(
            kp=p.vel_gain,
            ki=p.vel_integrator_gain,
            kd=p.vel_derivative_gain,
            kd_cutoff_hz=p.vel_derivative_cutoff_hz,
            vel_limit_revps=p.vel_limit_revps,
            current_limit_a=p.current_limit_a,
            input_mode=InputMode[p.input_mode],
            vel_ramp_rate_revps2=p.vel_ramp_rate_revps2,
            wd_timeout_ms=p.watchdog_timeout_ms,
            wd_stop_decel_revps2=p.watchdog_stop_decel_revps2,
            wd_require_e2e=p.watchdog_require_e2e,
            wd_host_timeout_ms=p.host_timeout_ms,
            wd_require_neutral=False,  # ODrive-like power-on: the host sets it with Set_Watchdog
        )

    def copy(self) -> _Runtime:
        return dataclasses.replace(self)


class DriveNode:
    """An emulated ODrive 0.6 axis on CAN node ``node`` driving ``wheel``.

    ``periods_ns`` maps the cyclic payload classes (Heartbeat, EncoderEstimates,
    Iq, BusVoltageCurrent) to their periods; the bench takes them from the DBC.
    """

    def __init__(
        self,
        node: Node,
        config: BenchConfig,
        wheel: Wheel,
        periods_ns: Mapping[type, int],
    ) -> None:
        self.node = node
        self.wheel = wheel
        self._cfg = config
        p = config.drive
        m = config.motor
        self._dt_s = config.tick_ns / 1e9
        self._k = m.torque_constant_nm_per_a
        self._res = m.resistance_ohm
        self._v_bus = m.bus_voltage_v
        self._max_current_a = m.max_current_a
        self._emf_per_revps = m.torque_constant_nm_per_a * m.gear_ratio * math.tau
        self._stop_speed = p.stop_speed_revps
        self._stop_settle_ns = p.stop_settle_ms * 1_000_000
        self._boot_ns = p.boot_time_ms * 1_000_000
        th = config.thermal
        self._ambient = th.ambient_degc
        self._periods = (
            (Heartbeat, periods_ns[Heartbeat]),
            (EncoderEstimates, periods_ns[EncoderEstimates]),
            (Iq, periods_ns[Iq]),
            (BusVoltageCurrent, periods_ns[BusVoltageCurrent]),
        )
        self.encoder = QuadratureEncoder(
            config.encoder.cpr, m.gear_ratio, config.encoder.pll_bandwidth_radps, self._dt_s
        )
        self.pid = VelocityPid(self._dt_s)
        self.watchdog = SetpointWatchdog(
            0,
            0.0,
            False,
            0,
            e2e_period_ns=periods_ns.get(SetInputVelE2E, config.step_ns),
            neutral_revps=p.stop_speed_revps,
        )
        self._saved = _Runtime.from_params(p)
        self._handlers: dict[type, Callable[[Any, int, Out], None]] = {
            Estop: self._on_estop,
            SetAxisState: self._on_set_axis_state,
            SetControllerMode: self._on_set_controller_mode,
            SetInputVel: self._on_set_input_vel,
            SetInputVelE2E: self._on_set_input_vel_e2e,
            SetLimits: self._on_set_limits,
            SetVelGains: self._on_set_vel_gains,
            SetVelDerivativeGain: self._on_set_vel_derivative_gain,
            SetWatchdog: self._on_set_watchdog,
            Reboot: self._on_reboot,
            ClearErrors: self._on_clear_errors,
            Request: self._on_request,
        }
        self._answers: dict[type, Callable[[], Any]] = {
            GetError: lambda: GetError(self.active_errors, self.disarm_reason),
            EncoderEstimates: self._encoder_estimates,
            EncoderCount: lambda: EncoderCount(
                wrap_int32(self.encoder.shadow_count), self.encoder.count_in_cpr
            ),
            Iq: lambda: Iq(self.iq_setpoint_a, self.wheel.current_a),
            Temperature: lambda: Temperature(self.fet_degc, self.motor_degc),
            BusVoltageCurrent: lambda: BusVoltageCurrent(self._v_bus, self.bus_current_a),
        }
        #: Counters of frames that were not acted on, by cause.
        self.ignored: dict[str, int] = {}
        #: Fault seam: decides whether a due Get_Encoder_Estimates frame is lost (None: never).
        self.drop_estimates: Callable[[], bool] | None = None
        self.estimates_dropped = 0
        self.fet_degc = self._ambient
        self.motor_degc = self._ambient
        self._power_on(0)

    # ------------------------------------------------------------------ power-on

    def _power_on(self, now_ns: int) -> None:
        self.state = AxisState.IDLE
        #: In closed loop (``state == CLOSED_LOOP_CONTROL``), cached for the 1 kHz path.
        self.armed = False
        self.active_errors = 0
        self.disarm_reason = 0
        self.procedure_result = PROCEDURE_SUCCESS
        self.control_mode = ControlMode.VELOCITY_CONTROL
        self._apply_runtime(self._saved.copy())
        self.input_vel_revps = 0.0
        self.input_torque_ff_nm = 0.0
        self.vel_setpoint_revps = 0.0
        self.iq_setpoint_a = 0.0
        self.bus_current_a = 0.0
        self._stopping = False
        self._stop_reached_ns: int | None = None
        self._stop_step_revps = 0.0
        self._stop_error = 0
        #: Time the current stop began (a watchdog, host-timeout or e-stop ramp), for tests.
        self.stop_started_ns: int | None = None
        self._hb_event = False
        self._boot_done_ns: int | None = None
        self._next_due = [now_ns] * len(self._periods)
        self.pid.reset()
        self.encoder.reset(self.wheel.angle_rad)
        self._disable()

    def _apply_runtime(self, rt: _Runtime) -> None:
        self.rt = rt
        self.pid.set_gains(rt.kp, rt.ki)
        self.pid.set_derivative(rt.kd, rt.kd_cutoff_hz)
        self.watchdog.configure(
            rt.wd_timeout_ms,
            rt.wd_stop_decel_revps2,
            rt.wd_require_e2e,
            rt.wd_host_timeout_ms,
            rt.wd_require_neutral,
        )

    def booting(self, now_ns: int) -> bool:
        """True while the node reboots (silent, ignoring frames); finishes the boot when due."""
        done = self._boot_done_ns
        if done is None:
            return False
        if now_ns < done:
            return True
        self._power_on(done)
        return False

    def _disable(self) -> None:
        w = self.wheel
        w.powered = False
        w.brake_engaged = True
        w.voltage_v = 0.0
        w.current_a = 0.0
        self.iq_setpoint_a = 0.0

    def _disarm(self, reason: int) -> None:
        self.state = AxisState.IDLE
        self.armed = False
        self._stopping = False
        self._stop_reached_ns = None
        self.procedure_result = PROCEDURE_DISARMED if reason else PROCEDURE_CANCELLED
        if reason:
            self.disarm_reason = reason
            self._hb_event = True
        self._disable()

    def _arm(self, now_ns: int) -> None:
        self.state = AxisState.CLOSED_LOOP_CONTROL
        self.armed = True
        self.procedure_result = PROCEDURE_BUSY
        self.input_vel_revps = 0.0
        self.input_torque_ff_nm = 0.0
        self.vel_setpoint_revps = 0.0
        self._stopping = False
        self._stop_reached_ns = None
        self.stop_started_ns = None
        self.pid.reset()
        self.watchdog.arm(now_ns)
        w = self.wheel
        w.powered = True
        w.brake_engaged = False

    # ------------------------------------------------------------------ frames in

    def handle(self, node: Node | None, payload: Any, now_ns: int, out: Out) -> bool:
        """Act on a decoded frame for ``node``; replies are appended to ``out``.

        Returns whether the frame was for this node and acted on.  Frames for
        other nodes, frames this node sends itself (an echoing transport returns
        them) and everything during a reboot are ignored.
        """
        if node != self.node:
            return False
        if self.booting(now_ns):
            self._count("booting")
            return False
        handler = self._handlers.get(type(payload))
        if handler is None:
            self._count("not_a_command")
            return False
        if self.armed and self.watchdog.require_e2e and type(payload) in _CONFIG_FRAMES:
            self._count("config_while_armed")
            return True
        handler(payload, now_ns, out)
        return True

    def _count(self, why: str) -> None:
        self.ignored[why] = self.ignored.get(why, 0) + 1

    def _on_estop(self, _p: Estop, now_ns: int, _out: Out) -> None:
        """*ext*: in motion, the same coordinated ramp as a watchdog expiry, then idle."""
        if not self.armed:
            self.active_errors |= AxisError.ESTOP_REQUESTED
            self._disarm(AxisError.ESTOP_REQUESTED)
            return
        enc = self.encoder
        vel_est = enc.vel_countsps * enc._inv_counts_per_wheel_rev
        at_rest = self.vel_setpoint_revps == 0.0 and -self._stop_speed < vel_est < self._stop_speed
        self._trip(now_ns, AxisError.ESTOP_REQUESTED)
        if at_rest or self.watchdog.stop_decel_revps2 <= 0.0:
            self._disarm(AxisError.ESTOP_REQUESTED)

    def _on_set_axis_state(self, p: SetAxisState, now_ns: int, _out: Out) -> None:
        req = p.requested_state
        if req == AxisState.CLOSED_LOOP_CONTROL:
            if self.active_errors:
                self.procedure_result = PROCEDURE_DISARMED
                self._count("arm_refused")
            elif self.state != AxisState.CLOSED_LOOP_CONTROL:
                self._arm(now_ns)
        elif req == AxisState.IDLE:
            if self.state == AxisState.CLOSED_LOOP_CONTROL:
                self._disarm(0)
        elif req in _CALIBRATION_STATES and self.state == AxisState.IDLE:
            self.procedure_result = PROCEDURE_SUCCESS
        else:
            self.procedure_result = PROCEDURE_INVALID_STATE
            self._count("unsupported_state")

    def _on_set_controller_mode(self, p: SetControllerMode, _now: int, _out: Out) -> None:
        if p.control_mode != ControlMode.VELOCITY_CONTROL or p.input_mode not in (
            InputMode.PASSTHROUGH,
            InputMode.VEL_RAMP,
        ):
            self._count("unsupported_mode")
            return
        self.control_mode = p.control_mode
        self.rt.input_mode = p.input_mode

    def _on_set_input_vel(self, p: SetInputVel, now_ns: int, _out: Out) -> None:
        if self._stopping:
            self._count("setpoint_while_stopping")
        elif self.watchdog.accept_plain(now_ns, p.input_vel_revps):
            self.input_vel_revps = p.input_vel_revps
            self.input_torque_ff_nm = p.torque_ff_nm
        else:
            self._count(self.watchdog.last_reject)

    def _on_set_input_vel_e2e(self, p: SetInputVelE2E, now_ns: int, _out: Out) -> None:
        if self._stopping:
            self._count("setpoint_while_stopping")
        elif self.watchdog.accept_e2e(p.counter, now_ns, p.input_vel_revps, p.stop_ref_revps):
            self.input_vel_revps = p.input_vel_revps
            self.input_torque_ff_nm = 0.0
        else:
            self._count(self.watchdog.last_reject)

    def on_host_heartbeat(self, p: HostHeartbeat, now_ns: int) -> bool:
        """Host_Heartbeat (broadcast): feeds the host monitor if its alive counter changed."""
        if self.booting(now_ns):
            self._count("booting")
            return False
        if not self.watchdog.feed_host(p.alive_counter, now_ns):
            self._count(self.watchdog.last_reject)
        return True

    def _on_set_limits(self, p: SetLimits, _now: int, _out: Out) -> None:
        self.rt.vel_limit_revps = p.velocity_limit_revps
        self.rt.current_limit_a = min(p.current_limit_a, self._max_current_a)

    def _on_set_vel_gains(self, p: SetVelGains, _now: int, _out: Out) -> None:
        self.rt.kp = p.vel_gain
        self.rt.ki = p.vel_integrator_gain
        self.pid.set_gains(p.vel_gain, p.vel_integrator_gain)

    def _on_set_vel_derivative_gain(self, p: SetVelDerivativeGain, _now: int, _out: Out) -> None:
        self.rt.kd = p.vel_derivative_gain
        self.rt.kd_cutoff_hz = p.derivative_cutoff_hz
        self.pid.set_derivative(p.vel_derivative_gain, p.derivative_cutoff_hz)

    def _on_set_watchdog(self, p: SetWatchdog, now_ns: int, _out: Out) -> None:
        rt = self.rt
        rt.wd_timeout_ms = p.timeout_ms
        rt.wd_stop_decel_revps2 = p.stop_decel_revps2
        rt.wd_require_e2e = p.require_e2e
        rt.wd_host_timeout_ms = p.host_timeout_ms
        rt.wd_require_neutral = p.require_neutral
        self._apply_runtime(rt)
        self.watchdog.restart(now_ns)

    def _on_reboot(self, p: Reboot, now_ns: int, _out: Out) -> None:
        if p.action == SAVE_CONFIGURATION:
            self._saved = self.rt.copy()
        elif p.action == ERASE_CONFIGURATION:
            self._saved = _Runtime.from_params(self._cfg.drive)
        elif p.action != REBOOT:
            self._count("unsupported_reboot_action")
            return
        self.reboot(now_ns)

    def reboot(self, now_ns: int) -> None:
        """Reboot now (a Reboot frame, or a supply glitch): silent and deaf for the boot time."""
        self.state = AxisState.IDLE
        self.armed = False
        self._disable()
        self._boot_done_ns = now_ns + self._boot_ns

    def _on_clear_errors(self, _p: ClearErrors, _now: int, _out: Out) -> None:
        self.active_errors = 0

    def _on_request(self, p: Request, _now: int, out: Out) -> None:
        answer = self._answers.get(p.what)
        if answer is None:
            self._count("unsupported_request")
            return
        out.append((answer(), self.node))

    def _encoder_estimates(self) -> EncoderEstimates:
        return EncoderEstimates(self.encoder.pos_rev, self.encoder.vel_revps)

    # ----------------------------------------------------------------- frames out

    def emit_due(self, now_ns: int, out: Out) -> None:
        """Append the cyclic frames due at ``now_ns`` (a bench step boundary)."""
        if self.booting(now_ns):
            return
        due = self._next_due
        node = self.node
        if self._hb_event:
            # *ext*: an error latched or the axis idled since the last step: report it now
            # (the cyclic schedule keeps its phase).
            self._hb_event = False
            if now_ns < due[0]:
                out.append((Heartbeat(self.active_errors, self.state, self.procedure_result), node))
        for k, (cls, period) in enumerate(self._periods):
            if now_ns >= due[k]:
                nxt = due[k] + period
                while nxt <= now_ns:  # keep the phase of the schedule, skip what was missed
                    nxt += period
                due[k] = nxt
                if cls is EncoderEstimates:
                    drop = self.drop_estimates
                    if drop is not None and drop():
                        self.estimates_dropped += 1
                        continue
                    out.append((self._encoder_estimates(), node))
                elif cls is Heartbeat:
                    out.append(
                        (
                            Heartbeat(self.active_errors, self.state, self.procedure_result),
                            node,
                        )
                    )
                elif cls is Iq:
                    out.append((Iq(self.iq_setpoint_a, self.wheel.current_a), node))
                else:
                    out.append((BusVoltageCurrent(self._v_bus, self.bus_current_a), node))

    def housekeeping(self, dt_s: float) -> None:
        """Once per bench step: bus current and the thermal models."""
        w = self.wheel
        i = w.current_a
        self.bus_current_a = w.voltage_v * i / self._v_bus if w.powered else 0.0
        th = self._cfg.thermal
        res = self._res
        p_motor = i * i * res
        target = self._ambient + p_motor * th.motor_thermal_resistance_kpw
        self.motor_degc += (target - self.motor_degc) * (dt_s / th.motor_thermal_time_constant_s)
        p_fet = i * i * th.fet_loss_ohm
        target = self._ambient + p_fet * th.fet_thermal_resistance_kpw
        self.fet_degc += (target - self.fet_degc) * (dt_s / th.fet_thermal_time_constant_s)

    # ------------------------------------------------------------------- 1 kHz

    def control(self, now_ns: int) -> None:
        """One control tick: set the wheel's voltage (or brake) for the next period."""
        if not self.armed:
            if self._boot_done_ns is not None:
                self.booting(now_ns)
            return
        enc = self.encoder
        vel_est = enc.vel_countsps * enc._inv_counts_per_wheel_rev
        wd = self.watchdog
        if not self._stopping:
            if wd.timeout_ns and now_ns - wd.last_feed_ns > wd.timeout_ns:
                self._trip(now_ns, AxisError.WATCHDOG_TIMER_EXPIRED)
            elif wd.host_timeout_ns and now_ns - wd.host_last_ns > wd.host_timeout_ns:
                self._trip(now_ns, AxisError.MISSING_INPUT)
        if self._stopping:
            sp = self._ramp_to_zero(now_ns, vel_est)
            if sp is None:
                return
            ff = 0.0
        else:
            rt = self.rt
            sp = self.input_vel_revps
            if rt.input_mode == _VEL_RAMP:
                prev = self.vel_setpoint_revps
                step = rt.vel_ramp_rate_revps2 * self._dt_s
                if sp > prev + step:
                    sp = prev + step
                elif sp < prev - step:
                    sp = prev - step
            lim = rt.vel_limit_revps
            if sp > lim:
                sp = lim
            elif sp < -lim:
                sp = -lim
            ff = self.input_torque_ff_nm
        self.vel_setpoint_revps = sp
        emf = self._emf_per_revps * vel_est
        res = self._res
        vbus = self._v_bus
        ilim = self.rt.current_limit_a
        i_hi = (vbus - emf) / res
        if i_hi > ilim:
            i_hi = ilim
        i_lo = (-vbus - emf) / res
        if i_lo < -ilim:
            i_lo = -ilim
        if i_lo > i_hi:  # back-EMF beyond the bus: nothing to command but zero
            i_lo = i_hi = 0.0
        k = self._k
        i_cmd = self.pid.update(sp, vel_est, ff, k * i_lo, k * i_hi) / k
        self.iq_setpoint_a = i_cmd
        u = res * i_cmd + emf
        if u > vbus:
            u = vbus
        elif u < -vbus:
            u = -vbus
        self.wheel.voltage_v = u

    def _trip(self, now_ns: int, error: int) -> None:
        """Latch ``error`` and start the coordinated stop (if not already stopping).

        Both drives ramp their own setpoint to zero in the same time
        ``T = max(stop_ref, |sp0|) / Stop_Decel``, ``stop_ref`` being the host's peak wheel
        speed of the last accepted E2E setpoint (both drives got it from the same tick): each
        decelerates at ``Stop_Decel |sp0| / max(...)`` <= Stop_Decel, so the wheel-speed ratio,
        hence the chair's curvature, is kept to standstill (docs/safety.md).
        """
        self.active_errors |= error
        if self._stopping:
            return
        self._stopping = True
        self._stop_error = error
        self._stop_reached_ns = None
        self.stop_started_ns = now_ns
        self._hb_event = True
        wd = self.watchdog
        sp0 = abs(self.vel_setpoint_revps)
        ref = max(sp0, min(wd.stop_ref_revps, self.rt.vel_limit_revps))
        decel = wd.stop_decel_revps2
        self._stop_step_revps = decel * self._dt_s * (sp0 / ref if ref > 0.0 else 1.0)

    def _ramp_to_zero(self, now_ns: int, vel_est: float) -> float | None:
        """Stop ramp after a trip; ``None`` once the axis has idled."""
        sp = self.vel_setpoint_revps
        if self.watchdog.stop_decel_revps2 <= 0.0:
            self._disarm(self._stop_error)
            return None
        step = self._stop_step_revps
        if sp > step:
            sp -= step
        elif sp < -step:
            sp += step
        else:
            sp = 0.0
            if self._stop_reached_ns is None:
                self._stop_reached_ns = now_ns
            if (
                -self._stop_speed < vel_est < self._stop_speed
                or now_ns - self._stop_reached_ns >= self._stop_settle_ns
            ):
                self._disarm(self._stop_error)
                return None
        return sp
