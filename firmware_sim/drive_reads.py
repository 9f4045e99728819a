"""What an emulated drive answers when asked: RTR requests and RxSdo endpoint reads.

An ODrive 0.6 answers an RTR for any Get_* message (and for Address) and an RxSdo read of its
endpoints; :func:`answers` and :func:`endpoint_reads` give, for one
:class:`~firmware_sim.drive.DriveNode`, the function that makes each answer from the drive's
state at the time of asking (:data:`dbc.endpoints.ODRIVE_ENDPOINTS` lists the endpoints; the
project's own two, the contract hash and the freshness, are the drive's).  Also what the
emulated drives say they are (:data:`EMULATED_VERSION`, :data:`EMULATED_SERIAL_BASE`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from dbc.codec import (
    Address,
    BusVoltageCurrent,
    EncoderCount,
    EncoderEstimates,
    GetError,
    Iq,
    Powers,
    Temperature,
    Torques,
    Version,
)
from dbc.endpoints import ODRIVE_ENDPOINTS
from firmware_sim.encoder import wrap_int32

if TYPE_CHECKING:
    from firmware_sim.drive import DriveNode

#: What the emulated drives report in Get_Version (and the version endpoints): CAN protocol
#: version 2, the hardware triplet of an ODrive Pro (4.4, variant 58), firmware 0.6.10 (the
#: release whose CAN Simple definition the DBC follows).
EMULATED_VERSION = Version(2, 4, 4, 58, 0, 6, 10, 0)

#: The emulated drives' 48-bit serial numbers are this plus their node ID (Address).
EMULATED_SERIAL_BASE = 0x3A5E_0000_0000


def answers(d: DriveNode) -> dict[type, Callable[[], Any]]:
    """The payload ``d`` answers an RTR for, by the requested payload class."""
    return {
        GetError: lambda: GetError(d.active_errors, d.disarm_reason),
        EncoderEstimates: d.encoder_estimates,
        EncoderCount: lambda: EncoderCount(
            wrap_int32(d.encoder.shadow_count), d.encoder.count_in_cpr
        ),
        Iq: lambda: Iq(d.iq_setpoint_a, d.wheel.current_a),
        Temperature: lambda: Temperature(d.fet_degc, d.motor_degc),
        BusVoltageCurrent: lambda: BusVoltageCurrent(d.bus_voltage_v, d.bus_current_a),
        Version: lambda: EMULATED_VERSION,
        Address: lambda: Address(int(d.node), d.serial_number),
        Torques: lambda: Torques(
            d.torque_constant_nm_per_a * d.iq_setpoint_a, d.torque_estimate_nm()
        ),
        Powers: lambda: Powers(d.bus_voltage_v * d.bus_current_a, d.mechanical_power_w()),
    }


def endpoint_reads(d: DriveNode) -> dict[int, Callable[[], float | int | bool]]:
    """The value of every ODrive endpoint ``d`` emulates, by endpoint ID (every one of
    :data:`~dbc.endpoints.ODRIVE_ENDPOINTS`).  The configuration (``d.rt``) is read at the
    time of asking: a reboot replaces it."""
    v = EMULATED_VERSION
    reads: dict[str, Callable[[], float | int | bool]] = {
        "vbus_voltage": lambda: d.bus_voltage_v,
        "ibus": lambda: d.bus_current_a,
        "hw_version_major": lambda: v.hw_version_major,
        "hw_version_minor": lambda: v.hw_version_minor,
        "hw_version_variant": lambda: v.hw_version_variant,
        "fw_version_major": lambda: v.fw_version_major,
        "fw_version_minor": lambda: v.fw_version_minor,
        "fw_version_revision": lambda: v.fw_version_revision,
        "fw_version_unreleased": lambda: v.fw_version_unreleased,
        "axis0.active_errors": lambda: d.active_errors,
        "axis0.disarm_reason": lambda: d.disarm_reason,
        "axis0.current_state": lambda: int(d.state),
        "axis0.pos_estimate": lambda: d.encoder.pos_rev,
        "axis0.vel_estimate": lambda: d.encoder.vel_revps,
        "axis0.config.watchdog_timeout": lambda: d.rt.wd_timeout_ms / 1000.0,
        "axis0.config.enable_watchdog": lambda: d.rt.wd_timeout_ms > 0,
        "axis0.config.can.node_id": lambda: int(d.node),
        "axis0.config.motor.phase_resistance": lambda: d.phase_resistance_ohm,
        "axis0.config.motor.torque_constant": lambda: d.torque_constant_nm_per_a,
        "axis0.config.motor.current_soft_max": lambda: d.rt.current_limit_a,
        "axis0.motor.fet_thermistor.temperature": lambda: d.fet_degc,
        "axis0.motor.motor_thermistor.temperature": lambda: d.motor_degc,
        "axis0.motor.torque_estimate": d.torque_estimate_nm,
        "axis0.motor.mechanical_power": d.mechanical_power_w,
        "axis0.motor.electrical_power": lambda: d.bus_voltage_v * d.bus_current_a,
        "axis0.controller.input_vel": lambda: d.input_vel_revps,
        "axis0.controller.input_torque": lambda: d.input_torque_ff_nm,
        "axis0.controller.vel_setpoint": lambda: d.vel_setpoint_revps,
        "axis0.controller.torque_setpoint": lambda: d.torque_constant_nm_per_a * d.iq_setpoint_a,
        "axis0.controller.config.control_mode": lambda: int(d.control_mode),
        "axis0.controller.config.input_mode": lambda: int(d.rt.input_mode),
        "axis0.controller.config.vel_gain": lambda: d.rt.kp,
        "axis0.controller.config.vel_integrator_gain": lambda: d.rt.ki,
        "axis0.controller.config.vel_limit": lambda: d.rt.vel_limit_revps,
        "axis0.controller.config.vel_ramp_rate": lambda: d.rt.vel_ramp_rate_revps2,
    }
    return {ODRIVE_ENDPOINTS[path].id: read for path, read in reads.items()}
