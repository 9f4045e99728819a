"""ODrive 0.6 endpoints that travel in RxSdo/TxSdo, and how their values sit in ``Value``.

RxSdo reads (Opcode 0) or writes (1) one endpoint of a drive's object tree by its numeric
ID; the drive answers a read with TxSdo carrying the same ``Endpoint_ID``.  ``Value`` is the
four payload bytes 4..7, which the DBC declares as one unsigned 32-bit integer: a ``float``
endpoint travels as the bits of an IEEE 754 float32, a narrower integer or a ``bool`` in the
low bytes.  :func:`to_value` and :func:`from_value` convert, :data:`ODRIVE_ENDPOINTS` names
the endpoints the emulated drives answer.

The IDs are those of ODrive's ``flat_endpoints.json`` for a single-axis 0.6 board (ODrive
Pro / S1), as reproduced in a public CAN Simple client's endpoint map (an npm package's
``endpointIdMap``; it does not state the firmware release).  ODrive numbers its endpoints
per firmware release and board, so a host talking to a real drive should take the IDs from
that firmware's own ``flat_endpoints.json``; the emulated drives and this table only have
to agree with each other.  The project's own endpoints (:class:`dbc.codec.SdoEndpoint`,
0xFF00 and up) lie above ODrive's range.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

_F32 = struct.Struct("<f")


class ValueKind(enum.Enum):
    """How an endpoint's value is carried in the 32-bit ``Value`` signal."""

    FLOAT = "float"  # IEEE 754 float32 bits
    UINT = "uint"  # unsigned, at most 32 bits
    INT = "int"  # two's complement, 32 bits
    BOOL = "bool"  # 0 or 1


@dataclass(frozen=True)
class Endpoint:
    """One endpoint: its ODrive path, numeric ID and value kind."""

    path: str
    id: int
    kind: ValueKind


def _table(*rows: tuple[str, int, ValueKind]) -> dict[str, Endpoint]:
    return {path: Endpoint(path, eid, kind) for path, eid, kind in rows}


_F, _U, _B = ValueKind.FLOAT, ValueKind.UINT, ValueKind.BOOL

#: The ODrive 0.6 endpoints the emulated drives answer RxSdo reads for, by path.
ODRIVE_ENDPOINTS: dict[str, Endpoint] = _table(
    ("vbus_voltage", 1, _F),
    ("ibus", 2, _F),
    ("hw_version_major", 6, _U),
    ("hw_version_minor", 7, _U),
    ("hw_version_variant", 8, _U),
    ("fw_version_major", 10, _U),
    ("fw_version_minor", 11, _U),
    ("fw_version_revision", 12, _U),
    ("fw_version_unreleased", 14, _U),
    ("axis0.active_errors", 175, _U),
    ("axis0.disarm_reason", 176, _U),
    ("axis0.current_state", 180, _U),
    ("axis0.pos_estimate", 182, _F),
    ("axis0.vel_estimate", 183, _F),
    ("axis0.config.watchdog_timeout", 200, _F),
    ("axis0.config.enable_watchdog", 201, _B),
    ("axis0.config.can.node_id", 229, _U),
    ("axis0.config.motor.phase_resistance", 255, _F),
    ("axis0.config.motor.torque_constant", 259, _F),
    ("axis0.config.motor.current_soft_max", 271, _F),
    ("axis0.motor.fet_thermistor.temperature", 333, _F),
    ("axis0.motor.motor_thermistor.temperature", 334, _F),
    ("axis0.motor.torque_estimate", 350, _F),
    ("axis0.motor.mechanical_power", 351, _F),
    ("axis0.motor.electrical_power", 352, _F),
    ("axis0.controller.input_vel", 368, _F),
    ("axis0.controller.input_torque", 369, _F),
    ("axis0.controller.vel_setpoint", 371, _F),
    ("axis0.controller.torque_setpoint", 372, _F),
    ("axis0.controller.config.control_mode", 382, _U),
    ("axis0.controller.config.input_mode", 383, _U),
    ("axis0.controller.config.vel_gain", 385, _F),
    ("axis0.controller.config.vel_integrator_gain", 386, _F),
    ("axis0.controller.config.vel_limit", 388, _F),
    ("axis0.controller.config.vel_ramp_rate", 390, _F),
)

#: The same endpoints by ID.
BY_ID: dict[int, Endpoint] = {e.id: e for e in ODRIVE_ENDPOINTS.values()}


def to_value(kind: ValueKind, v: float | int | bool) -> int:
    """``v`` as the raw 32-bit ``Value`` of an endpoint of ``kind``.

    Raises ``ValueError`` naming the kind and the value when it does not fit (a negative or
    wider than 32-bit unsigned, an integer outside int32, a float32 overflow).
    """
    if kind is ValueKind.FLOAT:
        try:
            return int.from_bytes(_F32.pack(float(v)), "little")
        except OverflowError as err:
            raise ValueError(f"{v!r} does not fit a float32") from err
    if kind is ValueKind.BOOL:
        return 1 if v else 0
    i = int(v)
    if i != v:
        raise ValueError(f"{v!r} is not an integer ({kind.value} endpoint)")
    if kind is ValueKind.UINT:
        if not 0 <= i <= 0xFFFF_FFFF:
            raise ValueError(f"{i} does not fit a uint32")
        return i
    if not -(2**31) <= i < 2**31:
        raise ValueError(f"{i} does not fit an int32")
    return i & 0xFFFF_FFFF


def from_value(kind: ValueKind, raw: int) -> float | int | bool:
    """The value of an endpoint of ``kind`` from its raw 32-bit ``Value``."""
    raw = int(raw) & 0xFFFF_FFFF
    if kind is ValueKind.FLOAT:
        return float(_F32.unpack(raw.to_bytes(4, "little"))[0])
    if kind is ValueKind.BOOL:
        return raw != 0
    if kind is ValueKind.INT and raw & 0x8000_0000:
        return raw - (1 << 32)
    return raw
