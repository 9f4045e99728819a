"""Bench configuration: every physical and drive parameter, declared once.

Each section is a frozen dataclass whose fields are declared with
:func:`dbc.runtime.params.param` (unit, documentation, bounds).  The defaults live twice
on purpose, and a test keeps them equal: here (so that ``BenchConfig()`` is
usable without a file) and in ``chair.toml`` next to this module, where every
value carries a comment with its unit and source.  :func:`load_bench_config`
reads ``chair.toml`` and merges a scenario's override table into it::

    cfg = load_bench_config({"chair.mass_kg": 150.0}, source="scenarios/heavy.toml")

Overrides may be dotted keys (``"chair.mass_kg"``), nested tables
(``{"chair": {"mass_kg": 150.0}}``) or both; unknown keys, wrong types and
out-of-bound values raise :class:`~dbc.errors.ConfigError` naming the source, the
key and the bound.  Cross-field rules (a period that is not a multiple of the
bench step, say) are checked here too, so a bad configuration fails before
anything moves.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from dbc.codec import InputMode, Node
from dbc.nodemap import NodeMap
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import load, load_toml, param, replace, section

CHAIR_TOML = Path(__file__).with_name("chair.toml")

#: Standard gravity (m/s^2); a physical constant, not a parameter.
GRAVITY_MPS2 = 9.80665


@dataclass(frozen=True, slots=True)
class ChairParams:
    """Rigid-body parameters of the chair (the paper's Eq. inertia and Eq. velocity)."""

    wheel_radius_m: float = param(
        0.30, unit="m", doc="nominal rolling radius r of each drive wheel", lo=0.05, hi=0.6
    )
    wheel_separation_m: float = param(
        0.56, unit="m", doc="distance 2b between the drive wheels' contact points", lo=0.2, hi=1.5
    )
    mass_kg: float = param(130.0, unit="kg", doc="total mass m with occupant", lo=20.0, hi=400.0)
    yaw_inertia_kgm2: float = param(
        15.0,
        unit="kg*m^2",
        doc="yaw inertia I of the whole chair about the vertical axis through P0",
        lo=0.5,
        hi=100.0,
    )
    wheel_inertia_kgm2: float = param(
        0.14,
        unit="kg*m^2",
        doc="spin inertia I_w of one wheel about its axle, reflected rotor and gears included",
        lo=0.0,
        hi=5.0,
    )
    com_offset_m: float = param(
        0.10,
        unit="m",
        doc="distance d from P0 forward to the centre of mass (negative = behind the axle)",
        lo=-0.5,
        hi=0.5,
    )
    rolling_resistance_coeff: float = param(
        0.015,
        unit="1",
        doc="rolling resistance force / weight for the whole chair (drive wheels + casters)",
        lo=0.0,
        hi=0.2,
    )
    rolling_speed_eps_radps: float = param(
        0.05,
        unit="rad/s",
        doc="wheel speed over which rolling resistance rises smoothly (tanh) to its full value",
        lo=1e-4,
        hi=5.0,
        lo_open=True,
    )

    @property
    def half_track_m(self) -> float:
        """b: half the wheel separation."""
        return 0.5 * self.wheel_separation_m


@dataclass(frozen=True, slots=True)
class MotorParams:
    """Brushed DC wheel motor, gearbox and supply (the paper's Eq. dcmotor)."""

    torque_constant_nm_per_a: float = param(
        0.13,
        unit="N*m/A",
        doc="torque constant K, equal to the back-EMF constant in V*s/rad (SI)",
        lo=0.005,
        hi=2.0,
    )
    resistance_ohm: float = param(
        0.4, unit="ohm", doc="armature resistance R", lo=0.01, hi=20.0, lo_open=True
    )
    inductance_h: float = param(
        0.001, unit="H", doc="armature inductance L", lo=1e-5, hi=0.1, lo_open=True
    )
    gear_ratio: float = param(
        32.0, unit="1", doc="gear ratio N (motor turns per wheel turn)", lo=1.0, hi=200.0
    )
    gear_efficiency: float = param(
        0.9, unit="1", doc="gearbox efficiency eta (wheel torque = eta*N*K*i)", lo=0.3, hi=1.0
    )
    bus_voltage_v: float = param(24.0, unit="V", doc="DC bus voltage", lo=6.0, hi=60.0)
    max_current_a: float = param(
        60.0,
        unit="A",
        doc="hardware current limit of the drive; Set_Limits cannot exceed it",
        lo=1.0,
        hi=200.0,
    )


@dataclass(frozen=True, slots=True)
class ThermalParams:
    """First-order thermal models behind Get_Temperature."""

    ambient_degc: float = param(25.0, unit="degC", doc="ambient temperature", lo=-30.0, hi=60.0)
    motor_thermal_resistance_kpw: float = param(
        1.5, unit="K/W", doc="motor winding to ambient thermal resistance", lo=0.01, hi=50.0
    )
    motor_thermal_time_constant_s: float = param(
        600.0, unit="s", doc="motor winding thermal time constant", lo=1.0, hi=1e5
    )
    fet_loss_ohm: float = param(
        0.01, unit="ohm", doc="equivalent loss resistance of the power stage", lo=0.0, hi=1.0
    )
    fet_thermal_resistance_kpw: float = param(
        5.0, unit="K/W", doc="power stage to ambient thermal resistance", lo=0.01, hi=50.0
    )
    fet_thermal_time_constant_s: float = param(
        60.0, unit="s", doc="power stage thermal time constant", lo=1.0, hi=1e5
    )


@dataclass(frozen=True, slots=True)
class EncoderParams:
    """Incremental quadrature encoder on the motor shaft and the drive's PLL estimator."""

    cpr: int = param(8192, unit="counts/rev", doc="counts per motor revolution", lo=16, hi=1 << 20)
    pll_bandwidth_radps: float = param(
        400.0,
        unit="rad/s",
        doc="bandwidth of the position/velocity PLL (ODrive's encoder.bandwidth)",
        lo=10.0,
        hi=1000.0,
    )


@dataclass(frozen=True, slots=True)
class DriveParams:
    """Power-on configuration of an emulated ODrive axis (Set_* frames change it at run time)."""

    control_rate_hz: int = param(
        1000, unit="Hz", doc="rate of the velocity PID and current command", choices=(1000,)
    )
    vel_gain: float = param(
        80.0,
        unit="N*m/(rev/s)",
        doc="proportional gain: motor torque per wheel rev/s of error (ODrive vel_gain)",
        lo=0.0,
        hi=100.0,
    )
    vel_integrator_gain: float = param(
        400.0,
        unit="N*m/rev",
        doc="integral gain: motor torque per wheel rev of integrated error",
        lo=0.0,
        hi=1000.0,
    )
    vel_derivative_gain: float = param(
        0.0,
        unit="N*m/(rev/s^2)",
        doc="derivative gain on the measured wheel acceleration (project extension)",
        lo=0.0,
        hi=100.0,
    )
    vel_derivative_cutoff_hz: float = param(
        100.0,
        unit="Hz",
        doc="cut-off of the first-order derivative filter; 0 = unfiltered difference",
        lo=0.0,
        hi=500.0,
    )
    vel_limit_revps: float = param(
        0.9, unit="rev/s", doc="wheel speed setpoint limit", lo=0.0, hi=20.0
    )
    current_limit_a: float = param(25.0, unit="A", doc="motor current limit", lo=0.0, hi=200.0)
    input_mode: str = param(
        InputMode.PASSTHROUGH.name,
        unit="",
        doc="power-on input mode of VELOCITY_CONTROL",
        choices=(InputMode.PASSTHROUGH.name, InputMode.VEL_RAMP.name),
    )
    vel_ramp_rate_revps2: float = param(
        2.0, unit="rev/s^2", doc="setpoint slew rate in VEL_RAMP input mode", lo=0.0, hi=100.0
    )
    watchdog_timeout_ms: int = param(
        0, unit="ms", doc="setpoint watchdog timeout at power-on; 0 = off", lo=0, hi=10000
    )
    watchdog_stop_decel_revps2: float = param(
        2.0,
        unit="rev/s^2",
        doc="deceleration of the stop ramp after a watchdog expiry; 0 = brake at once",
        lo=0.0,
        hi=65.535,
    )
    require_auth: bool = param(
        True,
        unit="",
        doc="power-on (non-volatile) authentication requirement: only frames authenticated with "
        "the key (dbc/secoc.py) move the wheel or change the configuration; false emulates a "
        "stock ODrive",
    )
    key_file: str = param(
        "../dbc/keys/TEST-ONLY-secoc.key",
        unit="",
        doc="the drives' authentication key file (relative paths: to firmware_sim/); the "
        "default is the repository's public test key",
    )
    check_contract: bool = param(
        True,
        unit="",
        doc="refuse to arm unless the host has written the same wire-contract hash "
        "(RxSdo endpoint 0xFF00) since power-on",
    )
    host_timeout_ms: int = param(
        0, unit="ms", doc="host heartbeat timeout (stored, not acted on yet); 0 = off", lo=0
    )
    stop_speed_revps: float = param(
        0.01,
        unit="rev/s",
        doc="estimated speed below which a stop ramp counts as finished and the axis idles",
        lo=0.0,
        hi=1.0,
    )
    stop_settle_ms: int = param(
        500,
        unit="ms",
        doc="after the stop ramp reached zero, idle at the latest this long later",
        lo=0,
        hi=10000,
    )
    boot_time_ms: int = param(
        50, unit="ms", doc="silence after Reboot before the node talks again", lo=0, hi=10000
    )
    brake_torque_nm: float = param(
        50.0,
        unit="N*m",
        doc="holding brake torque at the wheel while the axis is not in closed loop",
        lo=0.0,
        hi=500.0,
    )
    brake_speed_eps_radps: float = param(
        0.02,
        unit="rad/s",
        doc="wheel speed over which the brake torque rises smoothly (tanh)",
        lo=1e-3,
        hi=10.0,
        lo_open=True,
    )
    left_node_id: int = param(
        1,
        unit="",
        doc="CAN node ID the left drive talks and listens as (ODrive axis0.config.can.node_id); "
        "the wire contract's is 1, any other emulates a misconfigured drive",
        lo=0,
        hi=62,
    )
    right_node_id: int = param(
        2,
        unit="",
        doc="CAN node ID of the right drive; the wire contract's is 2",
        lo=0,
        hi=62,
    )


@dataclass(frozen=True, slots=True)
class LocalizerParams:
    """Optional localization node (node 3 by the contract) sending noisy pose fixes of P0."""

    enabled: bool = param(True, unit="", doc="whether the localization node is on the bus")
    node_id: int = param(
        3,
        unit="",
        doc="CAN node ID it talks as; the wire contract's is 3 (another: a chair whose drives "
        "took 3, its controller's bus.localizer_node_id the same)",
        lo=0,
        hi=62,
    )
    rate_hz: float = param(
        10.0,
        unit="Hz",
        doc="pose fix rate; its period must be a multiple of the bench step",
        lo=0.1,
        hi=100.0,
    )
    sigma_xy_m: float = param(
        0.02, unit="m", doc="standard deviation of the x and y noise", lo=0.0, hi=10.0
    )
    sigma_heading_rad: float = param(
        0.01, unit="rad", doc="standard deviation of the heading noise", lo=0.0, hi=1.0
    )


@dataclass(frozen=True, slots=True)
class BenchParams:
    """Time base of the bench and its lock-step protocol."""

    step_ms: int = param(10, unit="ms", doc="bench step T: the controller period", choices=(10,))
    physics_substeps: int = param(
        1, unit="1", doc="RK4 physics steps per drive control tick", lo=1, hi=64
    )
    ack_timeout_s: float = param(
        1.0,
        unit="s",
        doc="lock-step: longest wall-clock wait for a Bench_Step_Ack after the handshake",
        lo=0.0,
        hi=60.0,
    )
    handshake_timeout_s: float = param(
        10.0,
        unit="s",
        doc="lock-step: longest wall-clock wait for the first Bench_Step_Ack",
        lo=0.01,
        hi=600.0,
    )
    handshake_resend_ms: int = param(
        100, unit="ms", doc="lock-step: Bench_Step(0) repeat period during the handshake", lo=1
    )
    give_up_after_missed_acks: int = param(
        5,
        unit="1",
        doc="consecutive missed acks after which the bench stops waiting until an ack returns",
        lo=1,
        hi=1_000_000,
    )
    recorder_window_steps: int = param(
        0,
        unit="steps",
        doc="lock-step: never run more than this many steps ahead of the last Bench_Record_Ack "
        "(0: do not wait for a recorder); 'run' sets it so that a slow recorder slows the run "
        "instead of losing frames",
        lo=0,
        hi=100_000,
    )
    recorder_timeout_s: float = param(
        5.0,
        unit="s",
        doc="lock-step: longest wall-clock wait for the recorder; after it the bench stops waiting",
        lo=0.01,
        hi=600.0,
    )


@dataclass(frozen=True, slots=True)
class BenchConfig:
    """Everything the bench needs: chair, motors, drives, encoders, localizer, time base."""

    chair: ChairParams = section(ChairParams, "rigid-body parameters of the chair")
    motor: MotorParams = section(MotorParams, "wheel motor, gearbox and supply")
    thermal: ThermalParams = section(ThermalParams, "thermal models")
    encoder: EncoderParams = section(EncoderParams, "motor encoder and PLL")
    drive: DriveParams = section(DriveParams, "power-on drive configuration")
    localizer: LocalizerParams = section(LocalizerParams, "localization node")
    bench: BenchParams = section(BenchParams, "bench time base and lock-step protocol")

    @property
    def step_ns(self) -> int:
        """The bench step T (the controller period), in ns."""
        return self.bench.step_ms * 1_000_000

    @property
    def tick_ns(self) -> int:
        """Period of the drives' control loop."""
        return 1_000_000_000 // self.drive.control_rate_hz

    @property
    def localizer_period_ns(self) -> int:
        """Period of the localizer's pose fixes, in ns."""
        return round(1e9 / self.localizer.rate_hz)

    @property
    def key_path(self) -> Path:
        """The drives' key file, relative paths taken from ``firmware_sim/``."""
        p = Path(self.drive.key_file)
        return p if p.is_absolute() else CHAIR_TOML.parent / p


@cache
def _defaults_table() -> dict[str, Any]:
    return load_toml(CHAIR_TOML)


def default_config() -> BenchConfig:
    """The configuration in ``chair.toml``."""
    return _validate(load(BenchConfig, _defaults_table(), source=str(CHAIR_TOML)), str(CHAIR_TOML))


def load_bench_config(
    overrides: Mapping[str, Any] | None = None, *, source: str, prefix: str = ""
) -> BenchConfig:
    """``chair.toml`` with a scenario's ``overrides`` merged in and validated.

    ``source`` names where the overrides come from (a scenario file) and
    ``prefix`` the table that holds them there (e.g. ``"bench"``), both only for
    error messages.
    """
    base = default_config()
    if not overrides:
        return base
    nested = _nest(overrides, source=source, prefix=prefix)
    return _validate(replace(base, nested, source=source, prefix=prefix), source, prefix)


def _nest(table: Mapping[str, Any], *, source: str, prefix: str) -> dict[str, Any]:
    """Turn ``{"chair.mass_kg": 1}`` and ``{"chair": {...}}`` into one nested table."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        if not isinstance(key, str) or not key:
            raise ConfigError(f"{source}: override key {key!r} must be a non-empty string")
        parts = key.split(".")
        node = out
        for i, part in enumerate(parts[:-1]):
            nxt = node.setdefault(part, {})
            if not isinstance(nxt, dict):
                dotted = ".".join(p for p in (prefix, *parts[: i + 1]) if p)
                raise ConfigError(f"{source}: {dotted} is given both as a value and a table")
            node = nxt
        leaf = parts[-1]
        if isinstance(value, Mapping):
            sub = _nest(value, source=source, prefix=f"{prefix}.{key}" if prefix else key)
            existing = node.setdefault(leaf, {})
            if not isinstance(existing, dict):
                raise ConfigError(f"{source}: {key} is given both as a value and a table")
            existing.update(sub)
        else:
            if isinstance(node.get(leaf), dict):
                raise ConfigError(f"{source}: {key} is given both as a value and a table")
            node[leaf] = value
    return out


def _validate(cfg: BenchConfig, source: str, prefix: str = "") -> BenchConfig:
    """Cross-field rules that single-parameter bounds cannot express."""

    def key(k: str) -> str:
        return f"{prefix}.{k}" if prefix else k

    step_ns = cfg.step_ns
    if step_ns % cfg.tick_ns:
        raise ConfigError(
            f"{source}: {key('bench.step_ms')} = {cfg.bench.step_ms} is not a multiple of the "
            f"drive control period {cfg.tick_ns / 1e6:g} ms ({key('drive.control_rate_hz')})"
        )
    if cfg.localizer.enabled:
        period = 1e9 / cfg.localizer.rate_hz
        k = period / step_ns
        if abs(k - round(k)) > 1e-9 or round(k) < 1:
            raise ConfigError(
                f"{source}: {key('localizer.rate_hz')} = {cfg.localizer.rate_hz} gives a period "
                f"of {period / 1e6:g} ms, which is not a multiple of the bench step "
                f"{cfg.bench.step_ms} ms"
            )
    if cfg.drive.current_limit_a > cfg.motor.max_current_a:
        raise ConfigError(
            f"{source}: {key('drive.current_limit_a')} = {cfg.drive.current_limit_a} is above "
            f"{key('motor.max_current_a')} = {cfg.motor.max_current_a} (A)"
        )
    try:  # the rules of every side's node map (dbc/nodemap.py)
        bench_node_map(cfg, key)
    except ConfigError as err:
        raise ConfigError(f"{source}: {err}") from None
    if not math.isfinite(cfg.chair.half_track_m) or cfg.chair.half_track_m <= 0.0:
        raise ConfigError(f"{source}: {key('chair.wheel_separation_m')} must be positive")
    return cfg


def bench_node_map(cfg: BenchConfig, key: Callable[[str], str] = str) -> NodeMap:
    """The node IDs the bench's drives and localizer talk as (``key``: a setting's name)."""
    d = cfg.drive
    return NodeMap(
        {
            Node.LEFT: d.left_node_id,
            Node.RIGHT: d.right_node_id,
            Node.LOCALIZER: cfg.localizer.node_id,
        },
        keys={
            Node.LEFT: key("drive.left_node_id"),
            Node.RIGHT: key("drive.right_node_id"),
            Node.LOCALIZER: key("localizer.node_id"),
        },
    )
