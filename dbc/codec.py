"""Typed codec for ``wheelchair.dbc``: the only place where signal names are strings.

Every frame of the contract has a frozen dataclass here (``EncoderEstimates``,
``SetInputVel``, ``BenchStep`` ...), declared with :func:`message` (the DBC message it is),
each field naming the DBC signal that carries it (:func:`signal`, field metadata): the one
place that maps fields to signals.  :class:`Codec` turns those into ``can.Message`` objects
and back:

* **encoding is strict**: a missing, non-finite or out-of-range value raises
  :class:`~dbc.errors.EncodeError` naming message, signal, bound and value.
  Saturation is the caller's explicit job, never a silent wrap-around;
* **decoding is strict**: an unknown ID, a wrong length, an RTR for a message
  that cannot be requested, a value outside the DBC's ``[min|max]`` (cantools
  itself does not range-check on decode) or an undefined choice
  raise :class:`~dbc.errors.DecodeError` whose ``reason`` says which.

Packing goes through :mod:`dbc.bitpack`: each message's layout is compiled from the
DBC once (cantools stays the reference for loading, checking and any layout the fast path
cannot express), which makes a frame several times cheaper to encode and decode.

At load time the DBC is checked against this module (message names, frame IDs
``node << 5 | cmd``, signal sets, choice tables), so a DBC that
drifts from the code fails before anything moves.

One concern, kept whole: the DBC's typed mirror.  The value tables (the enumerations), the
payload types with the signal each field is carried by, and :class:`Codec`, which binds them
to the loaded DBC, checks them against it and packs and unpacks them, are one mapping and its
only reader.  Apart, either the signal names would be strings outside the codec or the codec
would read a mapping another module declares and the load-time check spans both.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import typing
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import can
import cantools
import numpy as np

from dbc.bitpack import compile_layout
from dbc.errors import DbcError, DecodeError, EncodeError
from dbc.secoc import AUTH_FV_BITS, MAC_BYTES, SETPOINT_FV_BITS, Authenticator, contract_digest

DBC_PATH = Path(__file__).with_name("wheelchair.dbc")


# --------------------------------------------------------------------------- nodes


class Node(enum.IntEnum):
    """CAN node IDs (the upper 6 bits of an 11-bit ODrive CAN Simple ID)."""

    LEFT = 1
    RIGHT = 2
    LOCALIZER = 3
    HOST = 8


DRIVES: tuple[Node, Node] = (Node.LEFT, Node.RIGHT)

_PREFIX = {Node.LEFT: "Left", Node.RIGHT: "Right", Node.LOCALIZER: "Localizer", Node.HOST: "Host"}


class Cmd(enum.IntEnum):
    """Command IDs (the lower 5 bits): every one of ODrive 0.6 CAN Simple, and the project's
    extensions on the four it leaves free (0x08, 0x0A, 0x10, 0x1E)."""

    GET_VERSION = 0x00
    HEARTBEAT = 0x01
    ESTOP = 0x02
    GET_ERROR = 0x03
    RX_SDO = 0x04
    TX_SDO = 0x05
    ADDRESS = 0x06
    SET_AXIS_STATE = 0x07
    SET_INPUT_VEL_AUTH = 0x08
    GET_ENCODER_ESTIMATES = 0x09
    GET_ENCODER_COUNT = 0x0A
    SET_CONTROLLER_MODE = 0x0B
    SET_INPUT_POS = 0x0C
    SET_INPUT_VEL = 0x0D
    SET_INPUT_TORQUE = 0x0E
    SET_LIMITS = 0x0F
    SET_VEL_DERIVATIVE_GAIN = 0x10
    SET_TRAJ_VEL_LIMIT = 0x11
    SET_TRAJ_ACCEL_LIMITS = 0x12
    SET_TRAJ_INERTIA = 0x13
    GET_IQ = 0x14
    GET_TEMPERATURE = 0x15
    REBOOT = 0x16
    GET_BUS_VOLTAGE_CURRENT = 0x17
    CLEAR_ERRORS = 0x18
    SET_ABSOLUTE_POSITION = 0x19
    SET_POS_GAIN = 0x1A
    SET_VEL_GAINS = 0x1B
    GET_TORQUES = 0x1C
    GET_POWERS = 0x1D
    SET_WATCHDOG = 0x1E
    ENTER_DFU_MODE = 0x1F


#: Command IDs ODrive firmware 0.6 does not use; extensions may only live here.
ODRIVE_06_FREE_CMDS = frozenset({0x08, 0x0A, 0x10, 0x1E})
#: Command IDs of ODrive firmware 0.6's CAN Simple messages (its 0.6.10 definition).
ODRIVE_06_CMDS = frozenset(range(0x20)) - ODRIVE_06_FREE_CMDS


class AxisState(enum.IntEnum):
    UNDEFINED = 0
    IDLE = 1
    STARTUP_SEQUENCE = 2
    FULL_CALIBRATION_SEQUENCE = 3
    MOTOR_CALIBRATION = 4
    SENSORLESS_CONTROL = 5
    ENCODER_INDEX_SEARCH = 6
    ENCODER_OFFSET_CALIBRATION = 7
    CLOSED_LOOP_CONTROL = 8
    LOCKIN_SPIN = 9
    ENCODER_DIR_FIND = 10
    HOMING = 11
    ENCODER_HALL_POLARITY_CALIBRATION = 12
    ENCODER_HALL_PHASE_CALIBRATION = 13
    ANTICOGGING_CALIBRATION = 14


class ProcedureResult(enum.IntEnum):
    """ODrive 0.6's result of the last procedure (Heartbeat.Procedure_Result)."""

    SUCCESS = 0
    BUSY = 1
    CANCELLED = 2
    DISARMED = 3
    NO_RESPONSE = 4
    POLE_PAIR_CPR_MISMATCH = 5
    PHASE_RESISTANCE_OUT_OF_RANGE = 6
    PHASE_INDUCTANCE_OUT_OF_RANGE = 7
    UNBALANCED_PHASES = 8
    INVALID_MOTOR_TYPE = 9
    ILLEGAL_HALL_STATE = 10
    TIMEOUT = 11
    HOMING_WITHOUT_ENDSTOP = 12
    INVALID_STATE = 13
    NOT_CALIBRATED = 14
    NOT_CONVERGING = 15


class RebootAction(enum.IntEnum):
    """Reboot's Action (ODrive 0.6; its DBC spells the choices in lower case)."""

    REBOOT = 0
    SAVE_CONFIGURATION = 1
    ERASE_CONFIGURATION = 2
    ENTER_DFU_MODE = 3


class SdoOpcode(enum.IntEnum):
    """RxSdo's Opcode."""

    READ = 0
    WRITE = 1


class SdoEndpoint(enum.IntEnum):
    """This project's RxSdo/TxSdo endpoints (outside ODrive 0.6's endpoint table)."""

    #: The wire-contract hash (:attr:`Codec.contract_hash`): the host writes its own, a drive
    #: refuses to arm on a mismatch; a read returns the drive's.
    CONTRACT_HASH = 0xFF00
    #: Read-only: the low 32 bits of the drive's freshness reference (a restarted host
    #: continues above it).
    FRESHNESS = 0xFF01


class ControlMode(enum.IntEnum):
    VOLTAGE_CONTROL = 0
    TORQUE_CONTROL = 1
    VELOCITY_CONTROL = 2
    POSITION_CONTROL = 3


class InputMode(enum.IntEnum):
    INACTIVE = 0
    PASSTHROUGH = 1
    VEL_RAMP = 2
    POS_FILTER = 3
    MIX_CHANNELS = 4
    TRAP_TRAJ = 5
    TORQUE_RAMP = 6
    MIRROR = 7
    TUNING = 8


class HostState(enum.IntEnum):
    INIT = 0
    ARMING = 1
    TRACKING = 2
    SAFE_STOP = 3
    FAULT = 4
    DONE = 5


class StopReason(enum.IntEnum):
    """Why the controller stopped: Host_Heartbeat.Stop_Reason on the wire, logs, summary."""

    NONE = 0
    ROUTE_DONE = 1
    DRIVE_LOST = 2
    DRIVE_ERROR = 3
    ENCODER_STALE = 4
    NON_FINITE = 5
    TICK_EXCEPTION = 6
    ARMING_TIMEOUT = 7
    OPERATOR = 8
    ENCODER_STUCK = 9
    ENCODER_JUMP = 10
    #: The chair does not do what the host commanded (controller.obedience).
    DISOBEYED = 11
    #: A drive's wire-contract hash differs from the host's: never armed.
    CONTRACT_MISMATCH = 12
    #: The host cannot send: its CAN interface is down or gone (the controller's DriveLink.bus_down).
    BUS_DOWN = 13
    #: The chair's estimated position is farther from the reference than
    #: ``safety.max_path_error_m``: the tracking law has lost the path.
    OFF_PATH = 14


class Hypothesis(enum.IntEnum):
    NOMINAL = 0
    FLAT_LEFT = 1
    FLAT_RIGHT = 2
    BUMP_LEFT = 3
    BUMP_RIGHT = 4
    SLIP = 5


class FaultType(enum.IntEnum):
    """Fault models of the bench (docs/faults.md), as carried in the Bench_Fault_* frames."""

    NONE = 0
    FLAT_TIRE = 1
    SHAFT_BUMP = 2
    SLIP = 3
    ENCODER_NOISE = 4
    ENCODER_STUCK = 5
    ENCODER_SCALE = 6
    ENCODER_DROPOUT = 7
    LOCALIZER_DROPOUT = 8
    LOCALIZER_BIAS = 9
    LOCALIZER_HEADING_BIAS = 10
    TORQUE_LOSS = 11
    DEAD_MOTOR = 12
    BUS_DROP = 13
    BUS_DELAY = 14
    BUS_DUPLICATE = 15
    BUS_REORDER = 16
    BUS_CORRUPT = 17
    NODE_SILENT = 18
    NODE_REBOOT = 19


class FaultSide(enum.IntEnum):
    NONE = 0
    LEFT = 1
    RIGHT = 2
    BOTH = 3


class FaultAction(enum.IntEnum):
    CLEAR = 0
    INJECT = 1


class FaultState(enum.IntEnum):
    CLEARED = 0
    ACTIVE = 1
    REJECTED = 2


class AxisError(enum.IntFlag):
    """ODrive 0.6 ``ODriveError`` bits as carried in Heartbeat.Axis_Error and in
    Get_Error.Active_Errors and Disarm_Reason (the DBC's value tables on those signals)."""

    NONE = 0
    INITIALIZING = 0x1
    SYSTEM_LEVEL = 0x2
    TIMING_ERROR = 0x4
    MISSING_ESTIMATE = 0x8
    BAD_CONFIG = 0x10
    DRV_FAULT = 0x20
    MISSING_INPUT = 0x40
    DC_BUS_OVER_VOLTAGE = 0x100
    DC_BUS_UNDER_VOLTAGE = 0x200
    DC_BUS_OVER_CURRENT = 0x400
    DC_BUS_OVER_REGEN_CURRENT = 0x800
    CURRENT_LIMIT_VIOLATION = 0x1000
    MOTOR_OVER_TEMP = 0x2000
    INVERTER_OVER_TEMP = 0x4000
    VELOCITY_LIMIT_VIOLATION = 0x8000
    POSITION_LIMIT_VIOLATION = 0x10000
    WATCHDOG_TIMER_EXPIRED = 0x1000000
    ESTOP_REQUESTED = 0x2000000
    SPINOUT_DETECTED = 0x4000000
    BRAKE_RESISTOR_DISARMED = 0x8000000
    THERMISTOR_DISCONNECTED = 0x10000000
    CALIBRATION_ERROR = 0x40000000


# ------------------------------------------------------------------------ payloads
# One frozen dataclass per message, declared with @message: the DBC message it is (the name
# without the node prefix, the command ID and the nodes that carry it), and for each field,
# whose name carries the unit, the DBC signal that carries it (signal(NAME)).  That is the
# whole mapping, written once: the codec reads it from the classes, and at load checks it
# against the DBC (every message present, every signal named and no other).

#: The field metadata keys: the field's DBC signal, and the enumeration of its value table.
SIGNAL = "signal"
VALUES = "values"


def signal(
    name: str,
    *,
    default: Any = dataclasses.MISSING,
    values: type[enum.IntEnum] | type[enum.IntFlag] | None = None,
) -> Any:
    """A payload field carried by the DBC signal ``name`` (and its default, if it has one).

    ``values``: the enumeration whose members are the signal's value table, for a field
    that holds a plain int (an IntFlag for a bit field: its value table names each bit).  A
    field typed as an IntEnum has that enumeration's table without saying so."""
    return dataclasses.field(default=default, metadata={SIGNAL: name, VALUES: values})


@dataclass(frozen=True)
class _Spec:
    cls: type
    cmd: int | None  # command ID (lower 5 bits); None for bench frames
    suffix: str  # DBC message name without node prefix
    nodes: tuple[Node, ...] | None  # None: a bench frame on a fixed extended ID
    fields: tuple[tuple[str, str], ...]  # (dataclass field, DBC signal), in field order
    requestable: bool = False  # drives answer an RTR with this message
    #: (DBC signal, the enumeration its value table must match)
    enums: tuple[tuple[str, type[enum.Enum]], ...] = ()


#: Every message type, in declaration order (filled by :func:`message`).
_SPECS: list[_Spec] = []

_T = typing.TypeVar("_T")


@typing.dataclass_transform(frozen_default=True, field_specifiers=(signal,))
def message(
    suffix: str,
    cmd: int | None = None,
    nodes: tuple[Node, ...] | None = None,
    *,
    requestable: bool = False,
) -> Callable[[type[_T]], type[_T]]:
    """Declare a payload class (made a frozen, slotted dataclass) as the DBC message
    ``<node prefix>_<suffix>`` with command ID ``cmd`` for each of ``nodes`` (``Left_``,
    ``Right_`` ...), or, without ``cmd`` and ``nodes``, the bench frame ``suffix`` (a fixed
    extended ID).  ``requestable``: the drives answer an RTR with it.  Every field must
    name its signal with :func:`signal`."""

    def declare(cls: type[_T]) -> type[_T]:
        out = dataclass(frozen=True, slots=True)(cls)
        hints = typing.get_type_hints(out)
        fields = []
        enums = []
        for f in dataclasses.fields(out):  # type: ignore[arg-type]
            sname = f.metadata.get(SIGNAL)
            if sname is None:
                raise TypeError(f"{cls.__name__}.{f.name} names no DBC signal: use signal(...)")
            fields.append((f.name, sname))
            t = hints[f.name]
            values = f.metadata[VALUES] or (
                t if isinstance(t, type) and issubclass(t, enum.Enum) else None
            )
            if values is not None:
                enums.append((sname, values))
        _SPECS.append(_Spec(out, cmd, suffix, nodes, tuple(fields), requestable, tuple(enums)))
        return out

    return declare


@message("Get_Version", Cmd.GET_VERSION, DRIVES, requestable=True)
class Version:
    """ODrive Get_Version: the drive's CAN protocol, hardware and firmware versions."""

    protocol_version: int = signal("Protocol_Version")
    hw_version_major: int = signal("Hw_Version_Major")
    hw_version_minor: int = signal("Hw_Version_Minor")
    hw_version_variant: int = signal("Hw_Version_Variant")
    fw_version_major: int = signal("Fw_Version_Major")
    fw_version_minor: int = signal("Fw_Version_Minor")
    fw_version_revision: int = signal("Fw_Version_Revision")
    fw_version_unreleased: int = signal("Fw_Version_Unreleased", default=0)


@message("Address", Cmd.ADDRESS, DRIVES, requestable=True)
class Address:
    """ODrive Address: a drive's node ID and 48-bit serial number (the answer to an RTR, or
    the host assigning ``node_id`` to the drive with that serial number)."""

    node_id: int = signal("Node_ID")
    serial_number: int = signal("Serial_Number")


@message("Heartbeat", Cmd.HEARTBEAT, DRIVES)
class Heartbeat:
    axis_error: int = signal("Axis_Error", values=AxisError)
    axis_state: AxisState = signal("Axis_State")
    procedure_result: ProcedureResult = signal("Procedure_Result", default=ProcedureResult.SUCCESS)
    trajectory_done: bool = signal("Trajectory_Done_Flag", default=False)


@message("Estop", Cmd.ESTOP, DRIVES)
class Estop:
    pass


@message("Get_Error", Cmd.GET_ERROR, DRIVES, requestable=True)
class GetError:
    active_errors: int = signal("Active_Errors", values=AxisError)
    disarm_reason: int = signal("Disarm_Reason", values=AxisError)


@message("Set_Axis_State", Cmd.SET_AXIS_STATE, DRIVES)
class SetAxisState:
    requested_state: AxisState = signal("Axis_Requested_State")


@message("Set_Input_Vel_Auth", Cmd.SET_INPUT_VEL_AUTH, DRIVES)
class SetInputVelAuth:
    """Authenticated velocity setpoint (AUTOSAR SecOC style, :mod:`dbc.secoc`).

    ``stop_ref_revps`` is the coordinated-stop reference: the larger wheel-speed magnitude
    the host commands in this tick (docs/safety.md); 0 = unknown.  ``freshness`` (the low 8
    bits of the freshness value) and ``mac`` are filled in by :meth:`Codec.encode_secured`.
    """

    input_vel_revps: float = signal("Input_Vel")
    stop_ref_revps: float = signal("Stop_Ref_Vel", default=0.0)
    freshness: int = signal("Freshness", default=0)
    mac: int = signal("Auth_MAC", default=0)


@message("RxSdo", Cmd.RX_SDO, DRIVES)
class RxSdo:
    """ODrive 0.6 endpoint access: read (``opcode`` 0) or write (1) ``endpoint_id``."""

    opcode: int = signal("Opcode", values=SdoOpcode)
    endpoint_id: int = signal("Endpoint_ID")
    value: int = signal("Value", default=0)
    reserved: int = signal("Reserved", default=0)


@message("TxSdo", Cmd.TX_SDO, DRIVES)
class TxSdo:
    """A drive's answer to an :class:`RxSdo` read."""

    endpoint_id: int = signal("Endpoint_ID")
    value: int = signal("Value")
    reserved0: int = signal("Reserved0", default=0)
    reserved1: int = signal("Reserved1", default=0)


@message("Get_Encoder_Estimates", Cmd.GET_ENCODER_ESTIMATES, DRIVES, requestable=True)
class EncoderEstimates:
    pos_rev: float = signal("Pos_Estimate")
    vel_revps: float = signal("Vel_Estimate")


@message("Get_Encoder_Count", Cmd.GET_ENCODER_COUNT, DRIVES, requestable=True)
class EncoderCount:
    shadow_count: int = signal("Shadow_Count")
    count_in_cpr: int = signal("Count_In_Cpr")


@message("Set_Controller_Mode", Cmd.SET_CONTROLLER_MODE, DRIVES)
class SetControllerMode:
    control_mode: ControlMode = signal("Control_Mode")
    input_mode: InputMode = signal("Input_Mode")


@message("Set_Input_Vel", Cmd.SET_INPUT_VEL, DRIVES)
class SetInputVel:
    input_vel_revps: float = signal("Input_Vel")
    torque_ff_nm: float = signal("Input_Torque_FF", default=0.0)


@message("Set_Input_Pos", Cmd.SET_INPUT_POS, DRIVES)
class SetInputPos:
    """ODrive Set_Input_Pos (POSITION_CONTROL); the feed-forwards at ODrive's default 0.001."""

    input_pos_rev: float = signal("Input_Pos")
    vel_ff_revps: float = signal("Vel_FF", default=0.0)
    torque_ff_nm: float = signal("Torque_FF", default=0.0)


@message("Set_Input_Torque", Cmd.SET_INPUT_TORQUE, DRIVES)
class SetInputTorque:
    input_torque_nm: float = signal("Input_Torque")


@message("Set_Traj_Vel_Limit", Cmd.SET_TRAJ_VEL_LIMIT, DRIVES)
class SetTrajVelLimit:
    traj_vel_limit_revps: float = signal("Traj_Vel_Limit")


@message("Set_Traj_Accel_Limits", Cmd.SET_TRAJ_ACCEL_LIMITS, DRIVES)
class SetTrajAccelLimits:
    traj_accel_limit_revps2: float = signal("Traj_Accel_Limit")
    traj_decel_limit_revps2: float = signal("Traj_Decel_Limit")


@message("Set_Traj_Inertia", Cmd.SET_TRAJ_INERTIA, DRIVES)
class SetTrajInertia:
    traj_inertia: float = signal("Traj_Inertia")  # N*m/(rev/s^2)


@message("Set_Absolute_Position", Cmd.SET_ABSOLUTE_POSITION, DRIVES)
class SetAbsolutePosition:
    position_rev: float = signal("Position")


@message("Set_Pos_Gain", Cmd.SET_POS_GAIN, DRIVES)
class SetPosGain:
    pos_gain: float = signal("Pos_Gain")  # (rev/s)/rev


@message("Get_Torques", Cmd.GET_TORQUES, DRIVES, requestable=True)
class Torques:
    """ODrive Get_Torques: torque target and estimate on the motor shaft."""

    target_nm: float = signal("Torque_Target")
    estimate_nm: float = signal("Torque_Estimate")


@message("Get_Powers", Cmd.GET_POWERS, DRIVES, requestable=True)
class Powers:
    """ODrive Get_Powers: electrical (DC bus) and mechanical power of the axis."""

    electrical_w: float = signal("Electrical_Power")
    mechanical_w: float = signal("Mechanical_Power")


@message("Enter_DFU_Mode", Cmd.ENTER_DFU_MODE, DRIVES)
class EnterDfuMode:
    pass


@message("Set_Limits", Cmd.SET_LIMITS, DRIVES)
class SetLimits:
    velocity_limit_revps: float = signal("Velocity_Limit")
    current_limit_a: float = signal("Current_Limit")


@message("Set_Vel_Derivative_Gain", Cmd.SET_VEL_DERIVATIVE_GAIN, DRIVES)
class SetVelDerivativeGain:
    vel_derivative_gain: float = signal("Vel_Derivative_Gain")
    derivative_cutoff_hz: float = signal("Vel_Derivative_Cutoff")


@message("Get_Iq", Cmd.GET_IQ, DRIVES, requestable=True)
class Iq:
    setpoint_a: float = signal("Iq_Setpoint")
    measured_a: float = signal("Iq_Measured")


@message("Get_Temperature", Cmd.GET_TEMPERATURE, DRIVES, requestable=True)
class Temperature:
    fet_degc: float = signal("FET_Temperature")
    motor_degc: float = signal("Motor_Temperature")


@message("Reboot", Cmd.REBOOT, DRIVES)
class Reboot:
    action: RebootAction = signal("Action", default=RebootAction.REBOOT)


@message("Get_Bus_Voltage_Current", Cmd.GET_BUS_VOLTAGE_CURRENT, DRIVES, requestable=True)
class BusVoltageCurrent:
    voltage_v: float = signal("Bus_Voltage")
    current_a: float = signal("Bus_Current")


@message("Clear_Errors", Cmd.CLEAR_ERRORS, DRIVES)
class ClearErrors:
    identify: bool = signal("Identify", default=False)


@message("Set_Vel_Gains", Cmd.SET_VEL_GAINS, DRIVES)
class SetVelGains:
    vel_gain: float = signal("Vel_Gain")
    vel_integrator_gain: float = signal("Vel_Integrator_Gain")


@message("Set_Watchdog", Cmd.SET_WATCHDOG, DRIVES)
class SetWatchdog:
    timeout_ms: int = signal("Watchdog_Timeout")
    stop_decel_revps2: float = signal("Stop_Decel")
    require_auth: bool = signal("Require_Auth")
    host_timeout_ms: int = signal("Host_Timeout", default=0)
    require_neutral: bool = signal("Require_Neutral", default=False)


@message("Pose_Fix", 0x08, (Node.LOCALIZER,))
class PoseFix:
    x_m: float = signal("X")
    y_m: float = signal("Y")
    heading_rad: float = signal("Heading")


@message("Auth", 0x0A, (Node.HOST,))
class HostAuth:
    """SecOC cryptographic PDU for the host command just sent to ``target_node``."""

    target_node: int = signal("Auth_Target_Node")
    target_cmd: int = signal("Auth_Target_Cmd")
    freshness: int = signal("Freshness")
    mac: int = signal("Auth_MAC")


@message("Diagnosis", 0x10, (Node.HOST,))
class HostDiagnosis:
    hypothesis: Hypothesis = signal("Hypothesis")
    probability: float = signal("Probability")
    radius_left_m: float = signal("Radius_Left_Est")
    radius_right_m: float = signal("Radius_Right_Est")


@message("Heartbeat", 0x1E, (Node.HOST,))
class HostHeartbeat:
    state: HostState = signal("Host_State")
    alive_counter: int = signal("Alive_Counter")
    route_time_s: float = signal("Route_Time", default=0.0)
    stop_reason: int = signal("Stop_Reason", default=0)


@message("Bench_Step")
class BenchStep:
    sim_time_ns: int = signal("Sim_Time")


@message("Bench_Step_Ack")
class BenchStepAck:
    sim_time_ns: int = signal("Sim_Time")


@message("Bench_Truth_Pose")
class TruthPose:
    x_m: float = signal("X")
    y_m: float = signal("Y")
    heading_rad: float = signal("Heading")


@message("Bench_Truth_Twist")
class TruthTwist:
    v_mps: float = signal("V")
    omega_radps: float = signal("Omega")


@message("Bench_Truth_Wheels")
class TruthWheels:
    radius_left_m: float = signal("Radius_Left")
    radius_right_m: float = signal("Radius_Right")
    omega_left_radps: float = signal("Omega_Left")
    omega_right_radps: float = signal("Omega_Right")


@message("Bench_End")
class BenchEnd:
    sim_time_ns: int = signal("Sim_Time")


@message("Bench_Record_Ack")
class RecordAck:
    """A recorder has written everything up to ``Bench_Step(sim_time_ns)``."""

    sim_time_ns: int = signal("Sim_Time")


@message("Bench_Truth_Contact")
class TruthContact:
    slip_left: float = signal("Slip_Left")
    slip_right: float = signal("Slip_Right")
    contact_radius_left_m: float = signal("Contact_Radius_Left")
    contact_radius_right_m: float = signal("Contact_Radius_Right")


@message("Bench_Fault_Command")
class FaultCommand:
    """Operator -> bench: inject or clear a fault (docs/faults.md gives each type's units)."""

    fault_id: int = signal("Fault_Id")
    fault_type: FaultType = signal("Fault_Type")
    side: FaultSide = signal("Side")
    action: FaultAction = signal("Fault_Action")
    duration_s: float = signal("Duration", default=0.0)
    amplitude: float = signal("Amplitude", default=0.0)
    param: float = signal("Param", default=0.0)


@message("Bench_Fault_Event")
class FaultEvent:
    """Bench -> operator: a fault became active, was cleared, or a command was refused."""

    fault_id: int = signal("Fault_Id")
    fault_type: FaultType = signal("Fault_Type")
    side: FaultSide = signal("Side")
    state: FaultState = signal("Fault_State")
    duration_s: float = signal("Duration", default=0.0)
    amplitude: float = signal("Amplitude", default=0.0)
    param: float = signal("Param", default=0.0)


@dataclass(frozen=True, slots=True)
class Request:
    """A remote (RTR) frame asking ``node`` to send a message of type ``what``."""

    what: type


Payload = Any  # any of the dataclasses above


class Frame(NamedTuple):
    """A decoded frame: the node it belongs to (``None`` for bench frames) and its payload."""

    node: Node | None
    payload: Payload


def _enums_by_signal(kind: type[enum.Enum]) -> dict[str, Any]:
    """Signal name -> the enumeration of ``kind`` its fields declare (one per signal name)."""
    out: dict[str, Any] = {}
    for spec in _SPECS:
        for sname, enum_cls in spec.enums:
            if issubclass(enum_cls, kind) and out.setdefault(sname, enum_cls) is not enum_cls:
                raise TypeError(f"signal {sname}: {out[sname]} and {enum_cls} both declared")
    return out


#: Enumerations whose members must match a DBC choice table, by signal name.
_CHOICE_ENUMS: dict[str, type[enum.IntEnum]] = _enums_by_signal(enum.IntEnum)
#: Bit-field signals: their value table names each bit (as ODrive's DBC does), and any
#: combination of bits is a valid value (a newer firmware may set bits this table lacks).
_FLAG_ENUMS: dict[str, type[enum.IntFlag]] = _enums_by_signal(enum.IntFlag)


class _Bound:
    """One message of the loaded DBC bound to its payload class (precomputed for speed)."""

    __slots__ = (
        "choice_tables",
        "cls",
        "convert",
        "dec_fields",
        "enc_checks",
        "fields",
        "frame_id",
        "is_extended",
        "layout",
        "length",
        "limits",
        "message",
        "name",
        "node",
        "requestable",
    )

    def __init__(self, spec: _Spec, message: Any, node: Node | None) -> None:
        self.cls = spec.cls
        self.message = message
        self.name: str = message.name
        self.frame_id: int = message.frame_id
        self.is_extended: bool = bool(message.is_extended_frame)
        self.length: int = message.length
        self.layout = compile_layout(message)  # None: cantools packs this one
        self.node = node
        self.requestable = spec.requestable
        self.fields = spec.fields
        hints = typing.get_type_hints(spec.cls)
        self.convert: dict[str, Any] = {}
        for fname, _sig in spec.fields:
            t = hints[fname]
            self.convert[fname] = t if t in (int, float, bool) or isinstance(t, type) else float
        sigs = {s.name: s for s in message.signals}
        self.limits = tuple(
            (fname, sname, sigs[sname].minimum, sigs[sname].maximum, sigs[sname].unit or "")
            for fname, sname in spec.fields
        )
        self.choice_tables = tuple(
            (s.name, frozenset(int(k) for k in s.choices))
            for s in message.signals
            if s.choices and s.name not in _FLAG_ENUMS
        )
        # The per-frame fast paths (Codec.encode/decode); None: the general path only.
        # encode: (field, min, max) in the layout's signal order;
        # decode: (signal index, min, max, converter) in the payload's field order.
        self.enc_checks: tuple[tuple[str, Any, Any], ...] | None = None
        self.dec_fields: tuple[tuple[int, Any, Any, Any], ...] | None = None
        layout = self.layout
        if layout is not None:
            by_sig = {sname: (fname, lo, hi) for fname, sname, lo, hi, _u in self.limits}
            self.enc_checks = tuple(by_sig[name] for name in layout.names)
            by_field = {fname: sname for fname, sname in spec.fields}
            order = [f.name for f in dataclasses.fields(spec.cls)]
            if sorted(order) == sorted(by_field):
                self.dec_fields = tuple(
                    (
                        layout.names.index(by_field[f]),
                        sigs[by_field[f]].minimum,
                        sigs[by_field[f]].maximum,
                        self.convert[f],
                    )
                    for f in order
                )


class Codec:
    """Encode payload dataclasses to ``can.Message`` and decode frames back.

    ``Codec()`` loads the project's DBC; ``Codec(path)`` another file with the
    same contract (it is validated and rejected with a :class:`DbcError` naming
    the file and the first mismatch).
    """

    _default: ClassVar[Codec | None] = None

    def __init__(self, dbc_path: str | Path = DBC_PATH) -> None:
        self.path = Path(dbc_path)
        if not self.path.is_file():
            raise DbcError(f"{self.path}: DBC file not found")
        try:
            db = cantools.database.load_file(str(self.path), database_format="dbc", strict=True)
        except Exception as err:  # cantools raises several types for a malformed file
            raise DbcError(f"{self.path}: cannot load DBC: {err}") from err
        if not isinstance(db, cantools.database.can.Database):
            raise DbcError(f"{self.path}: not a CAN database")
        self.db: cantools.database.can.Database = db
        self._by_key: dict[tuple[int, bool], _Bound] = {}
        self._by_type: dict[tuple[type, Node | None], _Bound] = {}
        for spec in _SPECS:
            for node in spec.nodes or (None,):
                bound = self._bind(spec, node)
                key = (bound.message.frame_id, bound.message.is_extended_frame)
                self._by_key[key] = bound
                self._by_type[(spec.cls, node)] = bound
        self._check_choices()
        self._contract_hash: int | None = None

    @classmethod
    def default(cls) -> Codec:
        """The process-wide codec for the project's DBC (loaded once)."""
        if cls._default is None:
            cls._default = cls()
        return cls._default

    # ----------------------------------------------------------------- load checks

    def _bind(self, spec: _Spec, node: Node | None) -> _Bound:
        name = spec.suffix if node is None else f"{_PREFIX[node]}_{spec.suffix}"
        try:
            message = self.db.get_message_by_name(name)
        except KeyError as err:
            raise DbcError(f"{self.path}: message {name!r} is missing") from err
        if node is None:
            if not message.is_extended_frame:
                raise DbcError(f"{self.path}: bench message {name} must use a 29-bit extended ID")
        else:
            cmd = spec.cmd
            assert cmd is not None
            if cmd not in ODRIVE_06_FREE_CMDS and node not in DRIVES:
                raise DbcError(
                    f"{self.path}: {name}: non-drive nodes may only use free command IDs"
                )
            expected = (int(node) << 5) | int(cmd)
            if message.is_extended_frame or message.frame_id != expected:
                raise DbcError(
                    f"{self.path}: {name} has ID {message.frame_id:#x}, expected "
                    f"node {int(node)} << 5 | cmd {int(cmd):#04x} = {expected:#05x}"
                )
        dbc_sigs = {s.name for s in message.signals}
        code_sigs = {sig: f"{spec.cls.__name__}.{f}" for f, sig in spec.fields}
        if dbc_sigs != set(code_sigs):
            missing = [f"{sig} ({code_sigs[sig]})" for sig in sorted(set(code_sigs) - dbc_sigs)]
            extra = sorted(dbc_sigs - set(code_sigs))
            raise DbcError(
                f"{self.path}: {name} signals differ from the codec: "
                f"missing {', '.join(missing) or 'none'}; unexpected {', '.join(extra) or 'none'}"
            )
        for s in message.signals:
            if s.minimum is None or s.maximum is None:
                raise DbcError(f"{self.path}: {name}.{s.name} has no [min|max] range")
        bound = _Bound(spec, message, node)
        return bound

    def _check_choices(self) -> None:
        for bound in self._by_key.values():
            for s in bound.message.signals:
                enum_cls: type[enum.Enum] | None = _CHOICE_ENUMS.get(s.name) or _FLAG_ENUMS.get(
                    s.name
                )
                if enum_cls is None:
                    continue
                # names compare in upper case: ODrive's DBC spells Reboot's Action choices
                # in lower case ("reboot"), the enums' members are upper case
                dbc_choices = {int(k): str(v).upper() for k, v in (s.choices or {}).items()}
                code_choices = {int(m.value): name for name, m in enum_cls.__members__.items()}
                if dbc_choices != code_choices:
                    raise DbcError(
                        f"{self.path}: {bound.name}.{s.name} choices differ from "
                        f"{enum_cls.__name__}"
                    )

    # ------------------------------------------------------------------- lookups

    def frame_id(self, cls: type, node: Node | None = None) -> int:
        """Arbitration ID of message ``cls`` for ``node`` (``None`` for bench frames)."""
        return self._bound(cls, node).message.frame_id

    def frame_key(self, name: str) -> tuple[int, bool]:
        """``(arbitration ID, is extended)`` of the DBC message called ``name``.

        Raises :class:`EncodeError` naming the message if the contract has no such frame.
        """
        for bound in self._by_key.values():
            if bound.name == name:
                return bound.message.frame_id, bool(bound.message.is_extended_frame)
        raise EncodeError(f"no message {name!r} in {self.path.name}")

    def message_name(self, cls: type, node: Node | None = None) -> str:
        return self._bound(cls, node).name

    def signal_scale(
        self, cls: type, field: str, node: Node | None = None
    ) -> tuple[float, float, float]:
        """``(resolution, minimum, maximum)`` of the signal carrying ``field`` of ``cls``.

        For code that must round or bound a value as the frame will (constants that mirror
        a DBC scale or range are read here, never written twice).
        """
        bound = self._bound(cls, node)
        sname = dict(bound.fields).get(field)
        if sname is None:
            raise EncodeError(f"{bound.name} has no field {field!r}")
        sig = bound.message.get_signal_by_name(sname)
        if sig.minimum is None or sig.maximum is None:
            raise EncodeError(f"{bound.name}.{sname} has no range in {self.path.name}")
        return float(sig.scale), float(sig.minimum), float(sig.maximum)

    def cycle_time_ms(self, cls: type, node: Node | None = None) -> int | None:
        return self._bound(cls, node).message.cycle_time

    def sender(self, cls: type, node: Node | None = None) -> str:
        """The DBC node that sends message ``cls`` (for ``node``); the first of several."""
        return str(self._bound(cls, node).message.senders[0])

    def senders(self, cls: type, node: Node | None = None) -> tuple[str, ...]:
        """Every DBC node that sends message ``cls`` (Address: the host and the drive)."""
        return tuple(str(s) for s in self._bound(cls, node).message.senders)

    def is_known(self, msg: can.Message) -> bool:
        return (msg.arbitration_id, msg.is_extended_id) in self._by_key

    def filters(self, pairs: Iterable[tuple[type, Node | None]]) -> list[dict[str, Any]]:
        """python-can ``can_filters`` that pass exactly the given messages."""
        out = []
        for cls, node in pairs:
            m = self._bound(cls, node).message
            out.append(
                {
                    "can_id": m.frame_id,
                    "can_mask": 0x1FFFFFFF if m.is_extended_frame else 0x7FF,
                    "extended": m.is_extended_frame,
                }
            )
        return out

    def _bound(self, cls: type, node: Node | None) -> _Bound:
        try:
            return self._by_type[(cls, node)]
        except KeyError:
            raise EncodeError(
                f"no message {getattr(cls, '__name__', cls)} for node {node!r}"
            ) from None

    # -------------------------------------------------------------------- encode

    def encode(self, payload: Payload, node: Node | None = None) -> can.Message:
        """Encode ``payload`` for ``node`` into a ``can.Message`` (strict)."""
        bound = self._by_type.get((type(payload), node))
        checks = None if bound is None else bound.enc_checks
        if checks is None or bound is None or bound.layout is None:
            return self._encode_checked(payload, node)
        # The fast path: every value in range (NaN is not) and packed in one go.  Anything
        # else takes the general path, which names the first bad signal.
        values = []
        try:
            for fname, lo, hi in checks:
                v = getattr(payload, fname)
                if not lo <= v <= hi:
                    return self._encode_checked(payload, node)
                values.append(v)
            data = bound.layout.pack_values(values)
        except Exception:
            return self._encode_checked(payload, node)
        return self._message(bound, data)

    def _encode_checked(self, payload: Payload, node: Node | None) -> can.Message:
        """The general encoder: each signal checked in turn, the first bad one named."""
        bound = self._bound(type(payload), node)
        values: dict[str, Any] = {}
        for fname, sname, lo, hi, unit in bound.limits:
            v = getattr(payload, fname)
            if isinstance(v, bool | enum.IntEnum):
                v = int(v)
            if isinstance(v, float) and not math.isfinite(v):
                raise EncodeError(f"{bound.name}.{sname} = {v} is not finite")
            try:
                outside = v < lo or v > hi
            except TypeError:
                raise EncodeError(f"{bound.name}.{sname} = {v!r} is not a number") from None
            if outside:
                raise EncodeError(
                    f"{bound.name}.{sname} = {v} {unit} is outside [{lo}, {hi}]".replace("  ", " ")
                )
            values[sname] = v
        try:
            if bound.layout is not None:
                data = bound.layout.pack(values)
            else:
                data = bytearray(
                    bound.message.encode(values, scaling=True, padding=False, strict=False)
                )
        except Exception as err:
            raise EncodeError(f"{bound.name}: {err}") from err
        return self._message(bound, data)

    def _message(self, bound: _Bound, data: bytearray) -> can.Message:
        return can.Message(
            arbitration_id=bound.frame_id,
            data=data,
            is_extended_id=bound.is_extended,
            dlc=len(data),
            check=False,  # built from the DBC's own ID and length
        )

    def request(self, cls: type, node: Node) -> can.Message:
        """An RTR frame asking ``node`` for message ``cls`` (ODrive's way of polling)."""
        bound = self._bound(cls, node)
        if not bound.requestable:
            raise EncodeError(f"{bound.name} cannot be requested by RTR")
        return can.Message(
            arbitration_id=bound.message.frame_id,
            is_remote_frame=True,
            is_extended_id=False,
            dlc=bound.message.length,
        )

    def encode_secured(
        self, payload: Payload, node: Node, auth: Authenticator
    ) -> tuple[can.Message, ...]:
        """Encode a host command to drive ``node``, secured with the next freshness value.

        A :class:`SetInputVelAuth` carries its truncated freshness and MAC itself (the MAC
        covers its bytes 0..3); any other command is followed by a :class:`HostAuth` PDU whose
        MAC covers the command's whole payload (SecOC's secured PDU collection).  Raises
        :class:`EncodeError` like :meth:`encode`.
        """
        fv = auth.next_fv(int(node))
        if type(payload) is SetInputVelAuth:
            mask = (1 << SETPOINT_FV_BITS) - 1
            msg = self.encode(
                SetInputVelAuth(payload.input_vel_revps, payload.stop_ref_revps, fv & mask, 0),
                node,
            )
            data = msg.data
            data[4 : 4 + MAC_BYTES] = auth.sign(msg.arbitration_id, data[:4], fv).to_bytes(
                MAC_BYTES, "little"
            )
            return (msg,)
        msg = self.encode(payload, node)
        bound = self._by_type[(type(payload), node)]
        cmd = bound.frame_id & 0x1F
        tag = HostAuth(
            int(node),
            cmd,
            fv & ((1 << AUTH_FV_BITS) - 1),
            auth.sign(msg.arbitration_id, msg.data, fv),
        )
        return msg, self.encode(tag, Node.HOST)

    @property
    def contract_hash(self) -> int:
        """32-bit hash of the wire contract as loaded: every message's ID, name, length and
        cycle time and every signal's layout, scale, offset, range and choices (comments and
        formatting do not count).  Host and drives compare it before arming."""
        h = self._contract_hash
        if h is None:
            lines = []
            for m in sorted(self.db.messages, key=lambda m: (m.frame_id, m.is_extended_frame)):
                lines.append(
                    f"{m.frame_id:x} {int(m.is_extended_frame)} {m.name} {m.length} {m.cycle_time}"
                )
                for sg in sorted(m.signals, key=lambda sg: sg.start):
                    choices = sorted((int(k), str(v)) for k, v in (sg.choices or {}).items())
                    lines.append(
                        f" {sg.name} {sg.start} {sg.length} {sg.byte_order} {int(sg.is_signed)} "
                        f"{int(sg.is_float)} {sg.scale!r} {sg.offset!r} {sg.minimum!r} "
                        f"{sg.maximum!r} {choices}"
                    )
            h = self._contract_hash = contract_digest(lines)
        return h

    # -------------------------------------------------------------------- decode

    def decode(self, msg: can.Message) -> Frame:
        """Decode one frame; raise :class:`DecodeError` with a ``reason`` if it is not valid."""
        bound = self._by_key.get((msg.arbitration_id, msg.is_extended_id))
        fields = None if bound is None else bound.dec_fields
        data = msg.data
        if (
            fields is None
            or bound is None
            or bound.layout is None
            or msg.is_remote_frame
            or msg.is_error_frame
            or len(data) != bound.length
            or msg.dlc != bound.length
        ):
            return self._decode_checked(msg)
        # The fast path for a valid frame; anything else takes the general path, which
        # names what is wrong.
        try:
            raw = bound.layout.unpack_values(data)
            args = []
            for i, lo, hi, conv in fields:
                v = raw[i]
                if not lo <= v <= hi:
                    return self._decode_checked(msg)
                args.append(conv(v))
        except Exception:
            return self._decode_checked(msg)
        return Frame(bound.node, bound.cls(*args))

    def _decode_checked(self, msg: can.Message) -> Frame:
        """The general decoder: each check in turn, the first failure named."""
        bound, raw = self._validated(msg)
        if raw is None:
            return Frame(bound.node, Request(bound.cls))
        kwargs: dict[str, Any] = {}
        for fname, sname, _lo, _hi, _unit in bound.limits:
            v = raw[sname]
            conv = bound.convert[fname]
            try:
                kwargs[fname] = conv(v) if conv is not float else float(v)
            except ValueError as err:
                raise DecodeError(
                    f"{bound.name}.{sname} = {v} is not a defined choice", reason="choice"
                ) from err
        return Frame(bound.node, bound.cls(**kwargs))

    def decode_signals(self, msg: can.Message) -> tuple[str, dict[str, float | int]]:
        """Validate ``msg`` like :meth:`decode` and return its DBC name and signal values.

        Values are physical (scaled) numbers; choice signals stay integers.  An RTR
        request decodes to an empty dict.
        """
        bound, raw = self._validated(msg)
        if raw is None:
            return bound.name, {}
        for sname, choices in bound.choice_tables:
            if int(raw[sname]) not in choices:
                raise DecodeError(
                    f"{bound.name}.{sname} = {raw[sname]} is not a defined choice", reason="choice"
                )
        return bound.name, raw

    def decode_columns(
        self, key: tuple[int, bool], payloads: bytes, n: int
    ) -> tuple[str, dict[str, np.ndarray], np.ndarray, Counter[str]]:
        """:meth:`decode_signals` of ``n`` frames of one message at once, for a log's or a
        collector's columns: ``key`` is (arbitration id, extended), ``payloads`` the data
        bytes of the frames (each of the message's length), back to back.  Returns its DBC
        name, one array per signal holding the frames :meth:`decode_signals` accepts (the
        same values), which frames those are (a boolean mask), and the count of the others
        by :attr:`DecodeError.reason` (``range``, ``choice``).  Messages the fast path cannot
        express go frame by frame through :meth:`decode_signals`."""
        bound = self._by_key.get(key)
        if bound is None:
            raise DecodeError(f"unknown frame ID 0x{key[0]:X}", reason="unknown_id")
        layout = bound.layout
        if layout is None:
            return self._decode_columns_slowly(bound, key, payloads, n)
        cols = dict(zip(layout.names, layout.unpack_columns(payloads, n), strict=True))
        ok = np.ones(n, dtype=bool)
        rejected: Counter[str] = Counter()
        for _fname, sname, lo, hi, _unit in bound.limits:
            v = cols[sname]
            bad = ok & ~((v >= lo) & (v <= hi))  # NaN compares false: out of range
            rejected["range"] += int(bad.sum())
            ok &= ~bad
        for sname, choices in bound.choice_tables:
            bad = ok & ~np.isin(cols[sname], np.fromiter(choices, dtype=np.int64))
            rejected["choice"] += int(bad.sum())
            ok &= ~bad
        if not ok.all():
            cols = {k: v[ok] for k, v in cols.items()}
        return bound.name, cols, ok, +rejected

    def _decode_columns_slowly(
        self, bound: _Bound, key: tuple[int, bool], payloads: bytes, n: int
    ) -> tuple[str, dict[str, np.ndarray], np.ndarray, Counter[str]]:
        rejected: Counter[str] = Counter()
        rows: dict[str, list[Any]] = {}
        ok = np.zeros(n, dtype=bool)
        size = bound.length
        for j, i in enumerate(range(0, n * size, size)):
            msg = can.Message(
                arbitration_id=key[0],
                is_extended_id=key[1],
                data=payloads[i : i + size],
                dlc=size,
            )
            try:
                _name, values = self.decode_signals(msg)
            except DecodeError as err:
                rejected[err.reason] += 1
                continue
            ok[j] = True
            for k, v in values.items():
                rows.setdefault(k, []).append(v)
        return bound.name, {k: np.asarray(v) for k, v in rows.items()}, ok, rejected

    def _validated(self, msg: can.Message) -> tuple[_Bound, dict[str, Any] | None]:
        """Look up, length-, CRC- and range-check ``msg``; ``None`` values for an RTR request."""
        bound = self._by_key.get((msg.arbitration_id, msg.is_extended_id))
        if bound is None:
            width = 8 if msg.is_extended_id else 3
            raise DecodeError(
                f"unknown frame ID 0x{msg.arbitration_id:0{width}X}"
                f"{' (extended)' if msg.is_extended_id else ''}",
                reason="unknown_id",
            )
        if msg.is_remote_frame:
            if not bound.requestable:
                raise DecodeError(
                    f"{bound.name}: remote frame for a message that cannot be requested",
                    reason="rtr",
                )
            return bound, None
        if msg.is_error_frame:
            raise DecodeError(f"{bound.name}: error frame", reason="error_frame")
        data = msg.data
        if len(data) != bound.length or msg.dlc != bound.length:
            raise DecodeError(
                f"{bound.name}: {len(data)} data bytes (DLC {msg.dlc}), expected {bound.length}",
                reason="length",
            )
        try:
            if bound.layout is not None:
                raw = bound.layout.unpack(data)
            else:
                raw = bound.message.decode(bytes(data), decode_choices=False, scaling=True)
        except Exception as err:
            raise DecodeError(f"{bound.name}: {err}", reason="malformed") from err
        for _fname, sname, lo, hi, unit in bound.limits:
            v = raw[sname]
            if not (lo <= v <= hi):  # also catches NaN
                raise DecodeError(
                    f"{bound.name}.{sname} = {v} {unit} is outside [{lo}, {hi}]".replace("  ", " "),
                    reason="range",
                )
        return bound, raw

    def describe_signals(self, name: str) -> list[dict[str, Any]]:
        """Signals of DBC message ``name`` with unit, bounds and choices (for log schemas)."""
        m = self.db.get_message_by_name(name)
        return [
            {
                "name": s.name,
                "unit": s.unit or "",
                "minimum": s.minimum,
                "maximum": s.maximum,
                "choices": {int(k): str(v) for k, v in (s.choices or {}).items()},
                # a bit field: the choices name its bits, a value may combine them
                "flags": s.name in _FLAG_ENUMS,
                "is_float": s.is_float,
                "comment": s.comment or "",
            }
            for s in m.signals
        ]

    def all_messages(self) -> list[tuple[type, Node | None, str]]:
        """Every (payload class, node, DBC name) the codec knows."""
        return [(b.cls, b.node, b.name) for b in self._by_key.values()]


def payload_fields(payload: Payload) -> Mapping[str, Any]:
    """The payload's fields as a plain dict (enums as ints), for logs."""
    return {
        f.name: (int(v) if isinstance(v := getattr(payload, f.name), enum.IntEnum | bool) else v)
        for f in dataclasses.fields(payload)
    }
