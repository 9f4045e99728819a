"""The wire's message types: the nodes, the value tables (enumerations) and one frozen
dataclass per message of ``wheelchair.dbc`` (``EncoderEstimates``, ``SetInputVel``,
``BenchStep`` ...), each declared with :func:`message` (the DBC message it is) and each
field naming the DBC signal that carries it (:func:`signal`): the one place that maps
fields to signals.  :class:`dbc.codec.Codec` reads this mapping, checks it against the
loaded DBC and packs and unpacks the payloads; ``dbc.codec`` re-exports every name here.
"""

from __future__ import annotations

import dataclasses
import enum
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

from dbc.runtime.frozen import fast_init

__all__ = [
    "CHOICE_ENUMS",
    "DRIVES",
    "FLAG_ENUMS",
    "NODE_PREFIX",
    "ODRIVE_06_CMDS",
    "ODRIVE_06_FREE_CMDS",
    "SIGNAL",
    "SPECS",
    "VALUES",
    "Address",
    "AxisError",
    "AxisState",
    "BenchEnd",
    "BenchStep",
    "BenchStepAck",
    "BusVoltageCurrent",
    "ClearErrors",
    "Cmd",
    "ControlMode",
    "EncoderCount",
    "EncoderEstimates",
    "EnterDfuMode",
    "Estop",
    "FaultAction",
    "FaultCommand",
    "FaultEvent",
    "FaultSide",
    "FaultState",
    "FaultType",
    "Frame",
    "GetError",
    "Heartbeat",
    "HostAuth",
    "HostDiagnosis",
    "HostHeartbeat",
    "HostState",
    "Hypothesis",
    "InputMode",
    "Iq",
    "MessageSpec",
    "Node",
    "Payload",
    "PoseFix",
    "Powers",
    "ProcedureResult",
    "Reboot",
    "RebootAction",
    "RecordAck",
    "Request",
    "RxSdo",
    "SdoEndpoint",
    "SdoOpcode",
    "SetAbsolutePosition",
    "SetAxisState",
    "SetControllerMode",
    "SetInputPos",
    "SetInputTorque",
    "SetInputVel",
    "SetInputVelAuth",
    "SetLimits",
    "SetPosGain",
    "SetTrajAccelLimits",
    "SetTrajInertia",
    "SetTrajVelLimit",
    "SetVelDerivativeGain",
    "SetVelGains",
    "SetWatchdog",
    "StopReason",
    "Temperature",
    "Torques",
    "TruthContact",
    "TruthPose",
    "TruthTwist",
    "TruthWheels",
    "TxSdo",
    "Version",
    "message",
    "payload_fields",
    "signal",
]


# --------------------------------------------------------------------------- nodes


class Node(enum.IntEnum):
    """CAN node IDs (the upper 6 bits of an 11-bit ODrive CAN Simple ID)."""

    LEFT = 1
    RIGHT = 2
    LOCALIZER = 3
    HOST = 8


DRIVES: tuple[Node, Node] = (Node.LEFT, Node.RIGHT)

NODE_PREFIX = {
    Node.LEFT: "Left",
    Node.RIGHT: "Right",
    Node.LOCALIZER: "Localizer",
    Node.HOST: "Host",
}


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
    """ODrive 0.6 axis states: Heartbeat's Axis_State, Set_Axis_State's Axis_Requested_State."""

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
    """Set_Controller_Mode's Control_Mode (ODrive 0.6); the host uses VELOCITY_CONTROL."""

    VOLTAGE_CONTROL = 0
    TORQUE_CONTROL = 1
    VELOCITY_CONTROL = 2
    POSITION_CONTROL = 3


class InputMode(enum.IntEnum):
    """Set_Controller_Mode's Input_Mode (ODrive 0.6); the host uses PASSTHROUGH."""

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
    """Host_Heartbeat's Host_State: the controller's state machine."""

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
    """Host_Diagnosis's Hypothesis: the fault bank's hypotheses (docs/faults.md § 4)."""

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
    """Bench_Fault_*'s Side: the wheel(s) a fault acts on (0 = none; on a clear, any)."""

    NONE = 0
    LEFT = 1
    RIGHT = 2
    BOTH = 3


class FaultAction(enum.IntEnum):
    """Bench_Fault_Command's Fault_Action: clear or inject the fault."""

    CLEAR = 0
    INJECT = 1


class FaultState(enum.IntEnum):
    """Bench_Fault_Event's Fault_State: cleared, active, or the command was refused."""

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
class MessageSpec:
    """A payload class's binding to the DBC, as :func:`message` declared it (the codec's input)."""

    cls: type
    cmd: int | None  # command ID (lower 5 bits); None for bench frames
    suffix: str  # DBC message name without node prefix
    nodes: tuple[Node, ...] | None  # None: a bench frame on a fixed extended ID
    fields: tuple[tuple[str, str], ...]  # (dataclass field, DBC signal), in field order
    requestable: bool = False  # drives answer an RTR with this message
    #: (DBC signal, the enumeration its value table must match)
    enums: tuple[tuple[str, type[enum.Enum]], ...] = ()


#: Every message type, in declaration order (filled by :func:`message`).
SPECS: list[MessageSpec] = []

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
        out = fast_init(dataclass(frozen=True, slots=True)(cls))
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
        SPECS.append(MessageSpec(out, cmd, suffix, nodes, tuple(fields), requestable, tuple(enums)))
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
    """ODrive Heartbeat (drive, 100 ms): axis error bits and state, procedure result, traj. done."""

    axis_error: int = signal("Axis_Error", values=AxisError)
    axis_state: AxisState = signal("Axis_State")
    procedure_result: ProcedureResult = signal("Procedure_Result", default=ProcedureResult.SUCCESS)
    trajectory_done: bool = signal("Trajectory_Done_Flag", default=False)


@message("Estop", Cmd.ESTOP, DRIVES)
class Estop:
    """ODrive Estop (anyone, no MAC): latch ESTOP_REQUESTED, ramp the wheel to zero, disarm."""


@message("Get_Error", Cmd.GET_ERROR, DRIVES, requestable=True)
class GetError:
    """ODrive Get_Error (drive, on RTR): active error bits and the reason of the last disarm."""

    active_errors: int = signal("Active_Errors", values=AxisError)
    disarm_reason: int = signal("Disarm_Reason", values=AxisError)


@message("Set_Axis_State", Cmd.SET_AXIS_STATE, DRIVES)
class SetAxisState:
    """ODrive Set_Axis_State (host): CLOSED_LOOP_CONTROL arms the axis, IDLE disarms it."""

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
    """ODrive Get_Encoder_Estimates (drive, 10 ms): wheel position (rev) and velocity (rev/s)."""

    pos_rev: float = signal("Pos_Estimate")
    vel_revps: float = signal("Vel_Estimate")


@message("Get_Encoder_Count", Cmd.GET_ENCODER_COUNT, DRIVES, requestable=True)
class EncoderCount:
    """Get_Encoder_Count (extension; drive, on RTR): raw motor encoder count, count mod cpr."""

    shadow_count: int = signal("Shadow_Count")
    count_in_cpr: int = signal("Count_In_Cpr")


@message("Set_Controller_Mode", Cmd.SET_CONTROLLER_MODE, DRIVES)
class SetControllerMode:
    """ODrive Set_Controller_Mode (host, at arming): the control mode and the input mode."""

    control_mode: ControlMode = signal("Control_Mode")
    input_mode: InputMode = signal("Input_Mode")


@message("Set_Input_Vel", Cmd.SET_INPUT_VEL, DRIVES)
class SetInputVel:
    """ODrive Set_Input_Vel (host, 10 ms, without auth): wheel speed (rev/s), torque FF (N*m)."""

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
    """ODrive Set_Input_Torque: torque setpoint (motor N*m, TORQUE_CONTROL); not emulated."""

    input_torque_nm: float = signal("Input_Torque")


@message("Set_Traj_Vel_Limit", Cmd.SET_TRAJ_VEL_LIMIT, DRIVES)
class SetTrajVelLimit:
    """ODrive Set_Traj_Vel_Limit: trapezoidal planner's velocity limit (rev/s); not emulated."""

    traj_vel_limit_revps: float = signal("Traj_Vel_Limit")


@message("Set_Traj_Accel_Limits", Cmd.SET_TRAJ_ACCEL_LIMITS, DRIVES)
class SetTrajAccelLimits:
    """ODrive Set_Traj_Accel_Limits: trapezoidal planner's limits (rev/s^2); not emulated."""

    traj_accel_limit_revps2: float = signal("Traj_Accel_Limit")
    traj_decel_limit_revps2: float = signal("Traj_Decel_Limit")


@message("Set_Traj_Inertia", Cmd.SET_TRAJ_INERTIA, DRIVES)
class SetTrajInertia:
    """ODrive Set_Traj_Inertia: the trajectory planner's inertia feed-forward; not emulated."""

    traj_inertia: float = signal("Traj_Inertia")  # N*m/(rev/s^2)


@message("Set_Absolute_Position", Cmd.SET_ABSOLUTE_POSITION, DRIVES)
class SetAbsolutePosition:
    """ODrive Set_Absolute_Position: set the axis' position estimate (rev); not emulated."""

    position_rev: float = signal("Position")


@message("Set_Pos_Gain", Cmd.SET_POS_GAIN, DRIVES)
class SetPosGain:
    """ODrive Set_Pos_Gain: the position loop's gain ((rev/s)/rev); not emulated."""

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
    """ODrive Enter_DFU_Mode: enter the firmware-update boot loader; not emulated."""


@message("Set_Limits", Cmd.SET_LIMITS, DRIVES)
class SetLimits:
    """ODrive Set_Limits (host, at arming): velocity limit (rev/s) and current limit (A)."""

    velocity_limit_revps: float = signal("Velocity_Limit")
    current_limit_a: float = signal("Current_Limit")


@message("Set_Vel_Derivative_Gain", Cmd.SET_VEL_DERIVATIVE_GAIN, DRIVES)
class SetVelDerivativeGain:
    """Set_Vel_Derivative_Gain (extension; host): the velocity PID's D gain, its cut-off (Hz)."""

    vel_derivative_gain: float = signal("Vel_Derivative_Gain")
    derivative_cutoff_hz: float = signal("Vel_Derivative_Cutoff")


@message("Get_Iq", Cmd.GET_IQ, DRIVES, requestable=True)
class Iq:
    """ODrive Get_Iq (drive, 100 ms): motor current setpoint and measurement (A)."""

    setpoint_a: float = signal("Iq_Setpoint")
    measured_a: float = signal("Iq_Measured")


@message("Get_Temperature", Cmd.GET_TEMPERATURE, DRIVES, requestable=True)
class Temperature:
    """ODrive Get_Temperature (drive, on RTR): FET and motor temperature (degC)."""

    fet_degc: float = signal("FET_Temperature")
    motor_degc: float = signal("Motor_Temperature")


@message("Reboot", Cmd.REBOOT, DRIVES)
class Reboot:
    """ODrive Reboot (host): reboot, after saving or erasing the configuration, or into DFU mode."""

    action: RebootAction = signal("Action", default=RebootAction.REBOOT)


@message("Get_Bus_Voltage_Current", Cmd.GET_BUS_VOLTAGE_CURRENT, DRIVES, requestable=True)
class BusVoltageCurrent:
    """ODrive Get_Bus_Voltage_Current (drive, 100 ms): DC bus voltage (V) and current (A)."""

    voltage_v: float = signal("Bus_Voltage")
    current_a: float = signal("Bus_Current")


@message("Clear_Errors", Cmd.CLEAR_ERRORS, DRIVES)
class ClearErrors:
    """ODrive Clear_Errors (host, at arming): clear latched errors; Identify blinks the LED."""

    identify: bool = signal("Identify", default=False)


@message("Set_Vel_Gains", Cmd.SET_VEL_GAINS, DRIVES)
class SetVelGains:
    """ODrive Set_Vel_Gains (host): velocity loop P (N*m/(rev/s)) and I (N*m/rev) gains."""

    vel_gain: float = signal("Vel_Gain")
    vel_integrator_gain: float = signal("Vel_Integrator_Gain")


@message("Set_Watchdog", Cmd.SET_WATCHDOG, DRIVES)
class SetWatchdog:
    """Set_Watchdog (extension; host, at arming): watchdog, stop ramp, auth, host timeout."""

    timeout_ms: int = signal("Watchdog_Timeout")
    stop_decel_revps2: float = signal("Stop_Decel")
    require_auth: bool = signal("Require_Auth")
    host_timeout_ms: int = signal("Host_Timeout", default=0)
    require_neutral: bool = signal("Require_Neutral", default=False)


@message("Pose_Fix", 0x08, (Node.LOCALIZER,))
class PoseFix:
    """Localizer_Pose_Fix (localizer, 100 ms): axle midpoint's world position (m), heading (rad)."""

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
    """Host_Diagnosis (host, 100 ms): fault bank's top hypothesis, its probability, radii (m)."""

    hypothesis: Hypothesis = signal("Hypothesis")
    probability: float = signal("Probability")
    radius_left_m: float = signal("Radius_Left_Est")
    radius_right_m: float = signal("Radius_Right_Est")


@message("Heartbeat", 0x1E, (Node.HOST,))
class HostHeartbeat:
    """Host_Heartbeat (host, 100 ms and on a change): state, alive counter, route time, reason."""

    state: HostState = signal("Host_State")
    alive_counter: int = signal("Alive_Counter")
    route_time_s: float = signal("Route_Time", default=0.0)
    stop_reason: int = signal("Stop_Reason", default=0)


@message("Bench_Step")
class BenchStep:
    """Bench_Step (bench, 10 ms): physics integrated and frames due sent up to Sim_Time (ns)."""

    sim_time_ns: int = signal("Sim_Time")


@message("Bench_Step_Ack")
class BenchStepAck:
    """Bench_Step_Ack (host, lock-step only): its tick at Sim_Time (ns) is complete."""

    sim_time_ns: int = signal("Sim_Time")


@message("Bench_Truth_Pose")
class TruthPose:
    """Bench_Truth_Pose (bench, 10 ms): true pose of the axle midpoint (m, rad); evaluation only."""

    x_m: float = signal("X")
    y_m: float = signal("Y")
    heading_rad: float = signal("Heading")


@message("Bench_Truth_Twist")
class TruthTwist:
    """Bench_Truth_Twist (bench, 10 ms): the chair's true speed (m/s) and yaw rate (rad/s)."""

    v_mps: float = signal("V")
    omega_radps: float = signal("Omega")


@message("Bench_Truth_Wheels")
class TruthWheels:
    """Bench_Truth_Wheels (bench, 100 ms): true rolling radii (m), wheel angular speeds (rad/s)."""

    radius_left_m: float = signal("Radius_Left")
    radius_right_m: float = signal("Radius_Right")
    omega_left_radps: float = signal("Omega_Left")
    omega_right_radps: float = signal("Omega_Right")


@message("Bench_End")
class BenchEnd:
    """Bench_End (bench): the run ends at Sim_Time (ns)."""

    sim_time_ns: int = signal("Sim_Time")


@message("Bench_Record_Ack")
class RecordAck:
    """A recorder has written everything up to ``Bench_Step(sim_time_ns)``."""

    sim_time_ns: int = signal("Sim_Time")


@message("Bench_Truth_Contact")
class TruthContact:
    """Bench_Truth_Contact (bench, 100 ms): each wheel's true slip ratio, contact radius (m)."""

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
    for spec in SPECS:
        for sname, enum_cls in spec.enums:
            if issubclass(enum_cls, kind) and out.setdefault(sname, enum_cls) is not enum_cls:
                raise TypeError(f"signal {sname}: {out[sname]} and {enum_cls} both declared")
    return out


#: Enumerations whose members must match a DBC choice table, by signal name.
CHOICE_ENUMS: dict[str, type[enum.IntEnum]] = _enums_by_signal(enum.IntEnum)
#: Bit-field signals: their value table names each bit (as ODrive's DBC does), and any
#: combination of bits is a valid value (a newer firmware may set bits this table lacks).
FLAG_ENUMS: dict[str, type[enum.IntFlag]] = _enums_by_signal(enum.IntFlag)


def payload_fields(payload: Payload) -> Mapping[str, Any]:
    """The payload's fields as a plain dict (enums as ints), for logs."""
    return {
        f.name: (int(v) if isinstance(v := getattr(payload, f.name), enum.IntEnum | bool) else v)
        for f in dataclasses.fields(payload)
    }
