"""Emulated ODrive 0.6 drive node: one axis' state machine, driven by frames and its 1 kHz tick.

One :class:`DriveNode` per wheel (node 1 left, node 2 right).  It is fed decoded
payloads (:meth:`DriveNode.handle`), produces payloads for the bench to encode
(:meth:`DriveNode.emit_due`, replies to RTR requests), and runs its 1 kHz control
tick against the :class:`~firmware_sim.plant.Wheel` it drives
(:meth:`DriveNode.control`; :class:`~firmware_sim.sim.ChairSim` samples
:attr:`DriveNode.encoder` at the end of every tick).  It never sees CAN IDs or
bytes.  Its parts live beside it: the velocity PID (:mod:`firmware_sim.pid`), the setpoint
watchdog and host monitor (:mod:`firmware_sim.watchdog`), command authentication
(:mod:`firmware_sim.drive_auth`) and what it answers when asked (:mod:`firmware_sim.drive_reads`).

It owns the axis' state: armed or stopping, the setpoints, the configuration that Set_*
frames change and Reboot restores, and the latched errors, which every frame handler and the
control tick read and change.

Behaviour (ODrive 0.6 semantics unless marked *ext*):

* states IDLE (1) and CLOSED_LOOP_CONTROL (8); Estop latches ESTOP_REQUESTED and
  idles; arming while an error is latched is refused (procedure result
  DISARMED); Clear_Errors clears; Reboot restores the power-on configuration
  after a silent boot (the encoder count restarts at zero, like a real
  incremental encoder);
* VELOCITY_CONTROL with PASSTHROUGH or VEL_RAMP input; setpoints in wheel rev/s,
  torque feed-forward in motor N*m; the velocity limit clamps the setpoint and
  the current limit the current command;
* the velocity PID at 1 kHz (:class:`~firmware_sim.pid.VelocityPid`) gives the torque within
  the current and the voltage limit, ``i* = tau / K``; voltage-mode current control
  ``u = R i* + K omega_motor_estimate`` saturated at the bus voltage;
* the setpoint watchdog (:class:`~firmware_sim.watchdog.SetpointWatchdog`, *ext*
  configuration via Set_Watchdog): expiry latches WATCHDOG_TIMER_EXPIRED, ramps the setpoint
  to zero at Stop_Decel and then idles;
* not in closed loop, the inverter is off and the holding brake engaged;
* it answers what an ODrive 0.6 answers (:mod:`firmware_sim.drive_reads`);
* the ODrive commands of other control modes (Set_Input_Pos, Set_Input_Torque, the trajectory
  planner's limits, Set_Absolute_Position, Set_Pos_Gain) and Enter_DFU_Mode are ignored
  and counted (``ignored["unsupported_command"]``): the emulation is velocity control only.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import can

from dbc.codec import (
    Address,
    AxisError,
    AxisState,
    BusVoltageCurrent,
    ClearErrors,
    ControlMode,
    EncoderEstimates,
    EnterDfuMode,
    Estop,
    Heartbeat,
    HostAuth,
    HostHeartbeat,
    InputMode,
    Iq,
    Node,
    ProcedureResult,
    Reboot,
    RebootAction,
    Request,
    RxSdo,
    SdoEndpoint,
    SdoOpcode,
    SetAbsolutePosition,
    SetAxisState,
    SetControllerMode,
    SetInputPos,
    SetInputTorque,
    SetInputVel,
    SetInputVelAuth,
    SetLimits,
    SetPosGain,
    SetTrajAccelLimits,
    SetTrajInertia,
    SetTrajVelLimit,
    SetVelDerivativeGain,
    SetVelGains,
    SetWatchdog,
    TxSdo,
)
from dbc.endpoints import BY_ID, to_value
from dbc.secoc import (
    REJECT_AUTH_REQUIRED,
    REJECT_NO_COMMAND,
    REJECT_UNAUTHENTICATED,
    Key,
)
from firmware_sim.config import BenchConfig, DriveParams
from firmware_sim.drive_auth import CommandAuth
from firmware_sim.drive_reads import EMULATED_SERIAL_BASE, answers, endpoint_reads
from firmware_sim.encoder import QuadratureEncoder
from firmware_sim.pid import VelocityPid
from firmware_sim.plant import Wheel
from firmware_sim.watchdog import SetpointWatchdog

log = logging.getLogger(__name__)

_VEL_RAMP = int(InputMode.VEL_RAMP)

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

#: ODrive commands of the control modes the emulation does not run, and Enter_DFU_Mode:
#: ignored and counted.
_UNSUPPORTED_COMMANDS = (
    SetInputPos,
    SetInputTorque,
    SetTrajVelLimit,
    SetTrajAccelLimits,
    SetTrajInertia,
    SetAbsolutePosition,
    SetPosGain,
    EnterDfuMode,
)

#: Frames that change the axis' configuration.  With Require_Auth (the safety profile) they are
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

#: Host commands that, with Require_Auth, are applied only once their Host_Auth PDU verifies
#: (an IDLE request and an RxSdo read are exceptions: see DriveNode.handle).  Estop needs none:
#: anyone may stop the chair.
_SECURED_COMMANDS = frozenset(
    {
        SetAxisState,
        SetControllerMode,
        SetLimits,
        SetVelGains,
        SetVelDerivativeGain,
        SetWatchdog,
        Reboot,
        ClearErrors,
        RxSdo,
        # the commands of other control modes would move a wheel on an ODrive, and DFU mode
        # takes the drive off the bus: the same rule, although the emulation ignores them
        *_UNSUPPORTED_COMMANDS,
    }
)

#: On a trip, a setpoint this far beyond the wheel's own speed is replaced by that speed.
_STOP_FROM_SPEED_REVPS = 0.05

#: Where nodes append (payload, node) pairs for the bench to encode and send.
Out = list[tuple[Any, Node | None]]


#: A configuration frame that would loosen a locked (armed-since-boot) drive's safety settings.
REJECT_LOOSENING = "config_loosening_locked"
#: Arming refused: the host's wire-contract hash differs from the drive's (or none written).
REJECT_CONTRACT = "contract_mismatch"


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
    wd_require_auth: bool
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
            wd_require_auth=p.require_auth,
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
        *,
        key: Key | None = None,
        contract_hash: int = 0,
    ) -> None:
        self.node = node
        self.wheel = wheel
        self._cfg = config
        p = config.drive
        m = config.motor
        self._dt_s = config.tick_ns / 1e9
        self.torque_constant_nm_per_a = m.torque_constant_nm_per_a
        self.phase_resistance_ohm = m.resistance_ohm
        self.bus_voltage_v = m.bus_voltage_v
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
            neutral_revps=p.stop_speed_revps,
        )
        self._saved = _Runtime.from_params(p)
        self._handlers: dict[type, Callable[[Any, int, Out], None]] = {
            Estop: self._on_estop,
            SetAxisState: self._on_set_axis_state,
            SetControllerMode: self._on_set_controller_mode,
            SetInputVel: self._on_set_input_vel,
            SetInputVelAuth: self._on_set_input_vel_auth,
            RxSdo: self._on_rx_sdo,
            SetLimits: self._on_set_limits,
            SetVelGains: self._on_set_vel_gains,
            SetVelDerivativeGain: self._on_set_vel_derivative_gain,
            SetWatchdog: self._on_set_watchdog,
            Reboot: self._on_reboot,
            ClearErrors: self._on_clear_errors,
            Address: self._on_address,
            Request: self._on_request,
        }
        for cls in _UNSUPPORTED_COMMANDS:
            self._handlers[cls] = self._on_unsupported
        #: This drive's serial number (Address).
        self.serial_number = EMULATED_SERIAL_BASE + int(node)
        #: Answers to RTR requests, by payload class, and RxSdo reads, by endpoint ID.
        self._answers = answers(self)
        self._endpoint_reads = endpoint_reads(self)
        #: Counters of frames that were not acted on, by cause.
        self.ignored: dict[str, int] = {}
        #: Command authentication: the SecOC receiver (:attr:`secoc`: the key and the freshness
        #: reference, kept across reboots) and the command held for its Host_Auth.
        self.auth = CommandAuth(key, config.step_ns)
        self.secoc = self.auth.verifier
        #: This drive's wire-contract hash (its DBC's), compared with the host's before arming.
        self.contract_hash = contract_hash
        self._check_contract = p.check_contract
        self._refusals_logged = 0
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
        self.procedure_result = ProcedureResult.SUCCESS
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
        #: Armed by the host since power-on: safety settings may only tighten until a reboot.
        self.locked = False
        #: The wire-contract hash the host wrote (RxSdo endpoint CONTRACT_HASH), None: none yet.
        self.host_contract_hash: int | None = None
        self.auth.pending = None
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
            rt.wd_require_auth,
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
        self.procedure_result = ProcedureResult.DISARMED if reason else ProcedureResult.CANCELLED
        if reason:
            self.disarm_reason = reason
            self._hb_event = True
        self._disable()

    def _arm(self, now_ns: int) -> None:
        self.state = AxisState.CLOSED_LOOP_CONTROL
        self.armed = True
        self.procedure_result = ProcedureResult.BUSY
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

    def handle(
        self,
        node: Node | None,
        payload: Any,
        now_ns: int,
        out: Out,
        msg: can.Message | None = None,
    ) -> bool:
        """Act on a decoded frame for ``node``; replies are appended to ``out``.

        ``msg`` is the frame as received: its ID and bytes are what a MAC covers (the drive's
        SecOC layer is the only part that reads them).  Returns whether the frame was for this
        node and acted on.  Frames for other nodes, frames this node sends itself (an echoing
        transport returns them) and everything during a reboot are ignored.

        With Require_Auth: a setpoint must carry a valid MAC at a fresh freshness value; every
        other command that can move the wheel or change the configuration is held until the
        host's :class:`HostAuth` for it arrives and verifies (:meth:`_on_host_auth`).  Exempt
        are Estop, an RTR request, an RxSdo read and an IDLE request; an unauthenticated IDLE
        request in closed loop is taken as an Estop (the same coordinated ramp), so that a
        foreign node cannot brake one wheel alone.
        """
        if node != self.node:
            return False
        if self.booting(now_ns):
            self._count("booting")
            return False
        t = type(payload)
        if t is HostAuth:
            self._on_host_auth(payload, now_ns, out, msg)
            return True
        handler = self._handlers.get(t)
        if handler is None:
            self._count("not_a_command")
            return False
        if t is SetInputVelAuth:
            why = self.auth.verify_setpoint(payload, msg)
            if why:
                self._refuse(why, payload)
                return True
        elif (
            self.watchdog.require_auth
            and t in _SECURED_COMMANDS
            and not (t is RxSdo and payload.opcode == SdoOpcode.READ)
        ):
            if self.auth.pending is not None:
                self._unauthenticated(REJECT_UNAUTHENTICATED, now_ns, out)
            self.auth.hold(payload, msg, now_ns)
            if msg is None:
                self._unauthenticated(REJECT_AUTH_REQUIRED, now_ns, out)
            return True
        self._dispatch(payload, now_ns, out)
        return True

    def _unauthenticated(self, why: str, now_ns: int, out: Out) -> None:
        """The held command was not authenticated: refuse it.  An IDLE request in closed
        loop is a stop request whoever sent it: it is honoured as an Estop (the coordinated
        ramp), so that nobody can brake one wheel alone."""
        payload = self.auth.take()
        if payload is None:
            return
        self._refuse(why, payload)
        if (
            type(payload) is SetAxisState
            and payload.requested_state == AxisState.IDLE
            and self.armed
        ):
            self._count("unauthenticated_idle_as_estop")
            self._on_estop(Estop(), now_ns, out)

    def _dispatch(self, payload: Any, now_ns: int, out: Out) -> None:
        if self.armed and self.watchdog.require_auth and type(payload) in _CONFIG_FRAMES:
            self._count("config_while_armed")
            return
        self._handlers[type(payload)](payload, now_ns, out)

    def _on_host_auth(
        self, p: HostAuth, now_ns: int, out: Out, msg: can.Message | None = None
    ) -> None:
        """The cryptographic PDU for the command held last: apply it if the MAC verifies."""
        if self.auth.pending is None:
            self._refuse(REJECT_NO_COMMAND, p)
            return
        why = self.auth.check(p, now_ns, msg)
        if why:
            self._unauthenticated(why, now_ns, out)
            return
        self._dispatch(self.auth.take(), now_ns, out)

    def _refuse(self, why: str, payload: Any) -> None:
        """Count an authentication refusal; log the first few and then every 100th."""
        self._count(why)
        self._refusals_logged += 1
        n = self._refusals_logged
        if n <= 3 or n % 100 == 0:
            log.warning(
                "drive %s refused %s: %s (%d refusals so far)",
                self.node.name,
                type(payload).__name__,
                why,
                n,
            )

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
                self.procedure_result = ProcedureResult.DISARMED
                self._count("arm_refused")
            elif self._check_contract and self.host_contract_hash != self.contract_hash:
                self.procedure_result = ProcedureResult.DISARMED
                self._count(REJECT_CONTRACT)
                log.error(
                    "drive %s refuses to arm: host wire-contract hash %s, drive's %08x",
                    self.node.name,
                    "none" if self.host_contract_hash is None else f"{self.host_contract_hash:08x}",
                    self.contract_hash,
                )
            elif self.state != AxisState.CLOSED_LOOP_CONTROL:
                # The safety firmware locks its configuration; a stock ODrive (no
                # authentication) keeps ODrive's semantics.
                self.locked = self.locked or self.watchdog.require_auth
                self._arm(now_ns)
        elif req == AxisState.IDLE:
            if self.state == AxisState.CLOSED_LOOP_CONTROL:
                self._disarm(0)
        elif req in _CALIBRATION_STATES and self.state == AxisState.IDLE:
            self.procedure_result = ProcedureResult.SUCCESS
        else:
            self.procedure_result = ProcedureResult.INVALID_STATE
            self._count("unsupported_state")

    def _loosens(self, what: str) -> bool:
        """True (counted, logged) if a locked drive was asked to loosen ``what``."""
        if not self.locked:
            return False
        self._count(REJECT_LOOSENING)
        log.warning("drive %s: locked since arming, refused to loosen %s", self.node.name, what)
        return True

    def _on_set_controller_mode(self, p: SetControllerMode, _now: int, _out: Out) -> None:
        if (
            p.control_mode != self.control_mode or p.input_mode != self.rt.input_mode
        ) and self._loosens("the controller mode"):
            return
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

    def _on_set_input_vel_auth(self, p: SetInputVelAuth, now_ns: int, _out: Out) -> None:
        if self._stopping:
            self._count("setpoint_while_stopping")
        elif self.watchdog.accept_auth(now_ns, p.input_vel_revps, p.stop_ref_revps):
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
        rt = self.rt
        if (
            p.velocity_limit_revps > rt.vel_limit_revps
            or min(p.current_limit_a, self._max_current_a) != rt.current_limit_a
        ) and self._loosens(
            "the limits (velocity may only decrease; the current limit is fixed: lower would "
            "weaken the stop)"
        ):
            return
        self.rt.vel_limit_revps = p.velocity_limit_revps
        self.rt.current_limit_a = min(p.current_limit_a, self._max_current_a)

    def _on_set_vel_gains(self, p: SetVelGains, _now: int, _out: Out) -> None:
        rt = self.rt
        if (p.vel_gain, p.vel_integrator_gain) != (rt.kp, rt.ki) and self._loosens("the gains"):
            return
        self.rt.kp = p.vel_gain
        self.rt.ki = p.vel_integrator_gain
        self.pid.set_gains(p.vel_gain, p.vel_integrator_gain)

    def _on_set_vel_derivative_gain(self, p: SetVelDerivativeGain, _now: int, _out: Out) -> None:
        rt = self.rt
        if (p.vel_derivative_gain, p.derivative_cutoff_hz) != (
            rt.kd,
            rt.kd_cutoff_hz,
        ) and self._loosens("the derivative gain"):
            return
        self.rt.kd = p.vel_derivative_gain
        self.rt.kd_cutoff_hz = p.derivative_cutoff_hz
        self.pid.set_derivative(p.vel_derivative_gain, p.derivative_cutoff_hz)

    def _on_set_watchdog(self, p: SetWatchdog, now_ns: int, _out: Out) -> None:
        rt = self.rt
        if self.locked:

            def looser(new: int, old: int) -> bool:  # 0 = off
                return old > 0 and (new == 0 or new > old)

            loose = [
                what
                for what, bad in (
                    ("the watchdog timeout", looser(p.timeout_ms, rt.wd_timeout_ms)),
                    ("the host timeout", looser(p.host_timeout_ms, rt.wd_host_timeout_ms)),
                    ("Require_Auth", rt.wd_require_auth and not p.require_auth),
                    ("Require_Neutral", rt.wd_require_neutral and not p.require_neutral),
                    ("Stop_Decel", p.stop_decel_revps2 != rt.wd_stop_decel_revps2),
                )
                if bad
            ]
            if loose and self._loosens(", ".join(loose)):
                return
        if p.require_auth and self.secoc.key is None:
            self._count("auth_no_key")
            log.error("drive %s: Require_Auth asked, but the drive has no key", self.node.name)
            return
        rt.wd_timeout_ms = p.timeout_ms
        rt.wd_stop_decel_revps2 = p.stop_decel_revps2
        rt.wd_require_auth = p.require_auth
        rt.wd_host_timeout_ms = p.host_timeout_ms
        rt.wd_require_neutral = p.require_neutral
        self._apply_runtime(rt)
        self.watchdog.restart(now_ns)

    def _on_reboot(self, p: Reboot, now_ns: int, _out: Out) -> None:
        if p.action == RebootAction.SAVE_CONFIGURATION:
            self._saved = self.rt.copy()
        elif p.action == RebootAction.ERASE_CONFIGURATION:
            self._saved = _Runtime.from_params(self._cfg.drive)
        elif p.action != RebootAction.REBOOT:
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

    def _on_rx_sdo(self, p: RxSdo, _now: int, out: Out) -> None:
        """ODrive endpoint access: reads of the emulated ODrive endpoints
        (:data:`dbc.endpoints.ODRIVE_ENDPOINTS`) and of this project's two (SdoEndpoint);
        the only write is the host's contract hash.  Like an ODrive, no answer to a read of
        an endpoint the drive does not have (counted)."""
        ep = p.endpoint_id
        if p.opcode == SdoOpcode.READ:
            if ep == SdoEndpoint.CONTRACT_HASH:
                out.append((TxSdo(ep, self.contract_hash), self.node))
            elif ep == SdoEndpoint.FRESHNESS:
                out.append((TxSdo(ep, self.secoc.reference & 0xFFFF_FFFF), self.node))
            elif (read := self._endpoint_reads.get(ep)) is not None:
                try:
                    value = to_value(BY_ID[ep].kind, read())
                except ValueError:  # e.g. a NaN estimate is a float, a value too wide is not
                    self._count("endpoint_value_unrepresentable")
                    return
                out.append((TxSdo(ep, value), self.node))
            else:
                self._count("unsupported_endpoint")
        elif ep == SdoEndpoint.CONTRACT_HASH:
            self.host_contract_hash = p.value
            if p.value != self.contract_hash:
                self._count(REJECT_CONTRACT)
                log.error(
                    "drive %s: host wire-contract hash %08x differs from the drive's %08x",
                    self.node.name,
                    p.value,
                    self.contract_hash,
                )
        else:
            self._count("unsupported_endpoint")

    def _on_address(self, p: Address, _now: int, _out: Out) -> None:
        """The host assigns a node ID by serial number: the bench's drives keep theirs."""
        if p.serial_number == self.serial_number and p.node_id != int(self.node):
            self._count("address_change_unsupported")

    def _on_unsupported(self, _p: Any, _now: int, _out: Out) -> None:
        self._count("unsupported_command")

    def torque_estimate_nm(self) -> float:
        """Motor torque from the measured current, in N*m."""
        return self.torque_constant_nm_per_a * self.wheel.current_a

    def mechanical_power_w(self) -> float:
        """Motor shaft torque times motor speed (from the encoder estimate)."""
        enc = self.encoder
        vel_est = enc.vel_countsps * enc._inv_counts_per_wheel_rev
        return self.wheel.current_a * self._emf_per_revps * vel_est

    def _on_request(self, p: Request, _now: int, out: Out) -> None:
        answer = self._answers.get(p.what)
        if answer is None:
            self._count("unsupported_request")
            return
        out.append((answer(), self.node))

    def encoder_estimates(self) -> EncoderEstimates:
        """The Get_Encoder_Estimates payload: wheel position (rev) and velocity (rev/s)."""
        return EncoderEstimates(self.encoder.pos_rev, self.encoder.vel_revps)

    # ----------------------------------------------------------------- frames out

    def emit_due(self, now_ns: int, out: Out) -> None:
        """Append the cyclic frames due at ``now_ns`` (a bench step boundary)."""
        if self.booting(now_ns):
            return
        if self.auth.overdue(now_ns):
            self._unauthenticated(REJECT_UNAUTHENTICATED, now_ns, out)
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
                    out.append((self.encoder_estimates(), node))
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
                    out.append((BusVoltageCurrent(self.bus_voltage_v, self.bus_current_a), node))

    def housekeeping(self, dt_s: float) -> None:
        """Once per bench step: bus current and the thermal models."""
        w = self.wheel
        i = w.current_a
        self.bus_current_a = w.voltage_v * i / self.bus_voltage_v if w.powered else 0.0
        th = self._cfg.thermal
        res = self.phase_resistance_ohm
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
        res = self.phase_resistance_ohm
        vbus = self.bus_voltage_v
        ilim = self.rt.current_limit_a
        i_hi = (vbus - emf) / res
        if i_hi > ilim:
            i_hi = ilim
        i_lo = (-vbus - emf) / res
        if i_lo < -ilim:
            i_lo = -ilim
        if i_lo > i_hi:  # back-EMF beyond the bus: nothing to command but zero
            i_lo = i_hi = 0.0
        k = self.torque_constant_nm_per_a
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
        speed of the last accepted authenticated setpoint (both drives got it from the same tick): each
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
        # A stop never speeds a wheel up: when the wheel lags far behind its setpoint (it was
        # being driven up by a foreign setpoint, or is torque-limited), ramp from its speed.
        enc = self.encoder
        vel_est = enc.vel_countsps * enc._inv_counts_per_wheel_rev
        sp = self.vel_setpoint_revps
        if abs(sp - vel_est) > _STOP_FROM_SPEED_REVPS and abs(vel_est) < abs(sp):
            self.vel_setpoint_revps = vel_est
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
