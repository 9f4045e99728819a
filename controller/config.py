"""The controller process's parameters: geometry it believes, loop, limits, drive set-up.

Defaults live in ``controller/controller.toml``; a deployment may pass its own
file (``wheelchair-hil control --config``).  Each tracking law's gains are in
``controller/gains.toml``, one section per controller, loaded by the registry;
they are the same for every scenario.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dbc.runtime import params
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import param, section

if TYPE_CHECKING:
    from dbc.nodemap import NodeMap

CONFIG_PATH = Path(__file__).with_name("controller.toml")


@dataclass(frozen=True)
class GeometryParams:
    """The chair's geometry as the controller believes it: wheel radius and separation."""

    wheel_radius_m: float = param(
        0.30, unit="m", lo=0.05, hi=1.0, doc="nominal rolling radius the controller believes"
    )
    wheel_separation_m: float = param(
        0.56, unit="m", lo=0.2, hi=2.0, doc="distance between the wheel contact points (2b)"
    )

    @property
    def half_track_m(self) -> float:
        """Half the wheel separation (the paper's b), in m."""
        return 0.5 * self.wheel_separation_m


@dataclass(frozen=True)
class LoopParams:
    """The control loop: period, arming, the route's end, the clock and the host heartbeat."""

    period_s: float = param(0.01, unit="s", lo=0.001, hi=0.1, doc="control period T")
    arming_timeout_s: float = param(
        2.0,
        unit="s",
        lo=0.1,
        hi=60.0,
        doc="both drives must confirm CLOSED_LOOP_CONTROL within this time",
    )
    wait_for_fix_s: float = param(
        0.5,
        unit="s",
        lo=0.0,
        hi=10.0,
        doc="how long arming waits for a first pose fix to initialise the estimate (0: start from the route start)",
    )
    end_settle_s: float = param(
        0.5,
        unit="s",
        lo=0.0,
        hi=10.0,
        doc="time at rest after the route end before the drives are idled",
    )
    end_speed_tol_mps: float = param(
        0.02,
        unit="m/s",
        lo=0.0,
        hi=0.5,
        doc="after the route end: commanded and estimated speed below this count as at rest",
    )
    end_omega_tol_radps: float = param(
        0.05,
        unit="rad/s",
        lo=0.0,
        hi=1.0,
        doc="after the route end: commanded turn rate below this counts as at rest",
    )
    end_timeout_s: float = param(
        5.0,
        unit="s",
        lo=0.0,
        hi=60.0,
        doc="after the route end the chair is stopped and idled at the latest after this time",
    )
    host_heartbeat_period_s: float = param(
        0.1, unit="s", lo=0.01, hi=1.0, doc="Host_Heartbeat period"
    )
    clock: str = param(
        "lockstep",
        unit="",
        choices=("lockstep", "realtime"),
        doc="the loop's clock where the command line names none: lockstep (the bench's "
        "Bench_Step frames) or realtime (the wall clock: a chair's drives send no Bench_Step)",
    )
    lockstep_idle_timeout_s: float = param(
        10.0,
        unit="s",
        lo=0.1,
        hi=600.0,
        doc="lock-step: give up when no Bench_Step arrives for this long (wall)",
    )
    lockstep_start_timeout_s: float = param(
        120.0,
        unit="s",
        lo=0.1,
        hi=3600.0,
        doc="lock-step: wait this long (wall) for the first Bench_Step, a bench still "
        "starting (a one-CPU UML guest imports the stack in ~15 s per process)",
    )
    disable_gc: bool = param(
        True, unit="", doc="freeze and disable the cyclic garbage collector while the loop runs"
    )


@dataclass(frozen=True)
class LimitParams:
    """Limits on the command: speeds, accelerations, jerk, turn rate, wheel speed, safe stop."""

    v_max_mps: float = param(1.5, unit="m/s", lo=0.1, hi=3.0, doc="forward speed limit")
    v_reverse_max_mps: float = param(
        0.5, unit="m/s", lo=0.0, hi=3.0, doc="reverse speed limit (magnitude)"
    )
    accel_max_mps2: float = param(
        1.0, unit="m/s^2", lo=0.05, hi=5.0, doc="speed-magnitude increase limit"
    )
    decel_max_mps2: float = param(
        1.5, unit="m/s^2", lo=0.05, hi=5.0, doc="speed-magnitude decrease limit"
    )
    jerk_max_mps3: float = param(
        20.0, unit="m/s^3", lo=0.1, hi=500.0, doc="limit on the change of acceleration"
    )
    omega_max_radps: float = param(2.0, unit="rad/s", lo=0.1, hi=10.0, doc="turn-rate limit")
    alpha_max_radps2: float = param(
        6.0, unit="rad/s^2", lo=0.1, hi=100.0, doc="turn-rate change limit"
    )
    wheel_max_radps: float = param(
        5.5,
        unit="rad/s",
        lo=0.5,
        hi=50.0,
        doc="wheel speed limit; both wheels are scaled together to keep the curvature",
    )
    safe_stop_decel_mps2: float = param(
        1.0, unit="m/s^2", lo=0.1, hi=5.0, doc="deceleration of a controller-initiated safe stop"
    )


@dataclass(frozen=True)
class BusParams:
    """The chair's CAN bus, as python-can opens it (the command line's --bus/--channel/--bitrate
    override it; empty: python-can's own configuration, CAN_INTERFACE / can.conf)."""

    interface: str = param(
        "",
        unit="",
        doc="python-can interface: socketcan on a chair (a USB or SPI adapter as can0), or pcan, "
        "kvaser, slcan, gs_usb, ...; empty: from the command line or python-can's config",
    )
    channel: str = param(
        "", unit="", doc="the interface's channel (socketcan: can0); empty: default"
    )
    bitrate: int = param(
        500_000,
        unit="bit/s",
        choices=(125_000, 250_000, 500_000, 1_000_000),
        doc="the bus bitrate, the drives' too (ODrive can.config.baud_rate); 500 kbit/s nominal",
    )
    localizer_node_id: int = param(
        3,
        unit="",
        lo=0,
        hi=62,
        doc="CAN node ID of the localization node (its Pose_Fix); the contract names it 3, "
        "another is translated at the bus (dbc/nodemap.py), e.g. where drives take 3 and 4",
    )


@dataclass(frozen=True)
class DriveSetupParams:
    """What the controller pushes to each drive when arming."""

    left_node_id: int = param(
        1,
        unit="",
        lo=0,
        hi=62,
        doc="CAN node ID of the left drive (ODrive axis0.config.can.node_id); the wire "
        "contract dbc/wheelchair.dbc names it 1, another is translated at the bus "
        "(dbc/nodemap.py); not the host's 8, nor another node's",
    )
    right_node_id: int = param(
        2,
        unit="",
        lo=0,
        hi=62,
        doc="CAN node ID of the right drive; the contract names it 2, like the left one",
    )

    vel_gain: float = param(
        80.0,
        unit="Nm/(rev/s)",
        lo=0.0,
        hi=100.0,
        doc="velocity P gain (motor torque per wheel rev/s)",
    )
    vel_integrator_gain: float = param(
        400.0, unit="Nm/rev", lo=0.0, hi=1000.0, doc="velocity I gain"
    )
    vel_derivative_gain: float = param(
        0.0, unit="Nm/(rev/s^2)", lo=0.0, hi=100.0, doc="velocity D gain (extension frame)"
    )
    derivative_cutoff_hz: float = param(
        50.0, unit="Hz", lo=1.0, hi=500.0, doc="cut-off of the drive's derivative filter"
    )
    velocity_limit_revps: float = param(
        1.0,
        unit="rev/s",
        lo=0.1,
        hi=20.0,
        doc="drive velocity limit (wheel): above the limiter's wheel limit, so it never clips a "
        "legitimate command, and the most a wrong one can ask for (1.0 rev/s = 1.9 m/s)",
    )
    current_limit_a: float = param(40.0, unit="A", lo=1.0, hi=200.0, doc="drive current limit")
    watchdog_timeout_ms: int = param(
        100, unit="ms", lo=0, hi=10000, doc="drive setpoint watchdog (0 disables)"
    )
    stop_decel_revps2: float = param(
        0.53,
        unit="rev/s^2",
        lo=0.01,
        hi=65.0,
        doc="drive's coordinated stop deceleration (1.0 m/s^2 at a 0.30 m rim)",
    )
    require_auth: bool = param(
        True,
        unit="",
        doc="authenticate every setpoint and command (SecOC style: freshness and truncated MAC, "
        "docs/safety.md) and make the drives accept only those; off: a stock ODrive, plain "
        "Set_Input_Vel and no MAC",
    )
    require_neutral_start: bool = param(
        True,
        unit="",
        doc="drives refuse setpoints after arming until a neutral (zero) one has arrived",
    )
    host_timeout_ms: int = param(
        300,
        unit="ms",
        lo=0,
        hi=10000,
        doc="drives stop when Host_Heartbeat is missing this long (0 disables); 3 heartbeats",
    )
    push_gains: bool = param(
        False,
        unit="",
        doc="push these velocity-loop gains when arming (otherwise keep the drive's own)",
    )


@dataclass(frozen=True)
class AuthParams:
    """The host's key and the wire-contract check (docs/safety.md § 1a)."""

    key_file: str = param(
        "../dbc/keys/TEST-ONLY-secoc.key",
        unit="",
        doc="the key shared with the drives (hex, >= 128 bits; relative paths: to the config "
        "file's directory). The default is the repository's public TEST key: a chair names its own",
    )
    check_contract: bool = param(
        True,
        unit="",
        doc="before arming, read each drive's wire-contract hash and write the host's; a "
        "mismatch refuses to arm (off for a stock ODrive, which has no such endpoint)",
    )
    contract_timeout_s: float = param(
        2.0,
        unit="s",
        lo=0.1,
        hi=60.0,
        doc="the drives must report their contract hash this soon after the first request (a "
        "drive that has not is asked again every 0.5 s)",
    )


@dataclass(frozen=True)
class SafetyParams:
    """Thresholds of the safety monitors: lost drives, stale or implausible feedback, obedience."""

    heartbeat_missed_max: int = param(
        3,
        unit="periods",
        lo=1,
        hi=100,
        doc="a drive is lost after this many missed 100 ms heartbeats",
    )
    encoder_stale_periods: int = param(
        3,
        unit="periods",
        lo=1,
        hi=100,
        doc="encoder estimates older than this many control periods trigger a safe stop",
    )
    max_wheel_accel_radps2: float = param(
        60.0,
        unit="rad/s^2",
        lo=1.0,
        hi=10000.0,
        doc="a wheel speed jump beyond this is not physical: safe stop",
    )
    stuck_encoder_s: float = param(
        0.5,
        unit="s",
        lo=0.05,
        hi=10.0,
        doc="encoder position frozen while motion is commanded this long: safe stop",
    )
    stuck_command_radps: float = param(
        0.5,
        unit="rad/s",
        lo=0.01,
        hi=20.0,
        doc="commanded wheel speed above which a frozen encoder counts as stuck",
    )
    obey_window_s: float = param(
        0.3,
        unit="s",
        lo=0.02,
        hi=5.0,
        doc="plausibility: a wheel's measured speed must lie within the span of what the host "
        "commanded it over this last window (the drive's response lag)",
    )
    obey_margin_revps: float = param(
        0.05,
        unit="rev/s",
        lo=0.005,
        hi=1.0,
        doc="plausibility: how far outside that span a wheel may be (0.05 rev/s = 9.4 cm/s rim)",
    )
    obey_time_s: float = param(
        0.1,
        unit="s",
        lo=0.01,
        hi=5.0,
        doc="plausibility: a divergence must last this long before the coordinated Estop",
    )
    twist_margin_mps: float = param(
        0.1,
        unit="m/s",
        lo=0.0,
        hi=2.0,
        doc="plausibility: measured chair speed above limits.v_max_mps by more than this diverges",
    )
    max_path_error_m: float = param(
        1.0,
        unit="m",
        lo=0.05,
        hi=100.0,
        doc="the estimated position farther than this from the reference's point while "
        "tracking: safe stop (OFF_PATH); a chair a metre off its path has left a corridor",
    )
    twist_margin_radps: float = param(
        0.2,
        unit="rad/s",
        lo=0.0,
        hi=5.0,
        doc="plausibility: measured yaw rate above limits.omega_max_radps by more than this "
        "diverges",
    )


@dataclass(frozen=True)
class MotorParams:
    """The wheel motors and the load as the controller believes them.

    Used to tune the drives' velocity loops (``controller.inner_loop``); the defaults
    match the bench's ``firmware_sim/chair.toml`` (a test keeps them in step).  The
    controller cannot read the bench: a real chair's deployment file states its own.
    """

    torque_constant_nm_per_a: float = param(
        0.13,
        unit="N*m/A",
        lo=0.005,
        hi=2.0,
        doc="K, torque constant (= back-EMF constant, V*s/rad)",
    )
    resistance_ohm: float = param(
        0.4, unit="ohm", lo=0.01, hi=20.0, lo_open=True, doc="R, armature resistance"
    )
    inductance_h: float = param(
        0.001, unit="H", lo=1e-5, hi=0.1, lo_open=True, doc="L, armature inductance (L/R = epsilon)"
    )
    gear_ratio: float = param(32.0, unit="1", lo=1.0, hi=200.0, doc="N, motor turns per wheel turn")
    gear_efficiency: float = param(0.9, unit="1", lo=0.3, hi=1.0, doc="eta, gearbox efficiency")
    reflected_inertia_kgm2: float = param(
        6.0,
        unit="kg*m^2",
        lo=0.01,
        hi=100.0,
        lo_open=True,
        doc="inertia one drive accelerates, referred to its wheel shaft: wheel and rotor through the "
        "gearbox plus the chair's share when driving straight, I_w + r^2 m / 2 (0.14 + 0.09 * 65)",
    )

    @property
    def epsilon_s(self) -> float:
        """The electrical time constant L/R: the paper's small parameter epsilon."""
        return self.inductance_h / self.resistance_ohm

    @property
    def torque_gain(self) -> float:
        """Wheel N*m per motor N*m (eta N)."""
        return self.gear_efficiency * self.gear_ratio


@dataclass(frozen=True)
class BodyParams:
    """The chair's rigid-body dynamics as the controller believes them (paper Eq. inertia).

    The model-based laws (ROBUST's equivalent control, ADAPTIVE's prediction model) use them;
    the defaults match the bench's ``firmware_sim/chair.toml`` ``[chair]`` (a test keeps them
    in step).  A real chair's deployment file states its own, occupant included.
    """

    mass_kg: float = param(
        130.0, unit="kg", lo=10.0, hi=500.0, doc="m, chair with occupant (the paper's m_c + 2 m_w)"
    )
    yaw_inertia_kgm2: float = param(
        15.0, unit="kg*m^2", lo=0.5, hi=200.0, doc="I, about the vertical axis through P0"
    )
    wheel_inertia_kgm2: float = param(
        0.14,
        unit="kg*m^2",
        lo=0.0,
        hi=10.0,
        doc="I_w, one drive wheel with its rotor reflected through the gearbox, about its axle",
    )
    com_offset_m: float = param(
        0.10,
        unit="m",
        lo=-1.0,
        hi=1.0,
        doc="d, centre of mass ahead of the axle midpoint P0 (the m_c d phi' terms of Eq. velocity)",
    )


@dataclass(frozen=True)
class PerceivedFlatParams:
    """A flat tire as a *sensor* fault (the paper's flat tire: "perceiving a continuous wheel
    radius decrease"): the wheel keeps its radius, the odometry reads its rotation as if the
    radius decayed like the bench's flat tire (``controller.sensor_faults``)."""

    side: str = param("left", unit="", choices=("left", "right", "both"), doc="which wheel")
    onset_s: float = param(
        0.0, unit="s", lo=0.0, hi=86400.0, doc="simulation time at which the perception begins"
    )
    duration_s: float = param(
        0.0, unit="s", lo=0.0, hi=86400.0, doc="how long it lasts; 0 = to the end of the run"
    )
    to_radius_m: float = param(
        0.26, unit="m", lo=0.05, hi=1.0, doc="radius the perceived wheel decays to"
    )
    time_constant_s: float = param(
        2.0, unit="s", lo=0.0, hi=600.0, doc="exponential decay time constant (0 = a step)"
    )


@dataclass(frozen=True)
class EstimationParams:
    """How the pose estimate uses the fault diagnosis, and sensor faults injected into it."""

    diagnosis_feedback: bool = param(
        True,
        unit="",
        doc="after each fix, odometry believes the filter bank's diagnosed wheel radii "
        "(off: it keeps the nominal geometry.wheel_radius_m)",
    )
    wheel_scale_state: bool = param(
        True,
        unit="",
        doc="the pose EKF learns the wheels' differential scale from the fixes (a soft or "
        'worn tire\'s heading drift; docs/planner.md "EKF"); off: a pose-only filter '
        "that the fixes cut back every 0.1 s",
    )
    perceived_flats: tuple[PerceivedFlatParams, ...] = param(
        (),
        unit="",
        doc="sensor faults injected into odometry and the filter bank ([[estimation."
        "perceived_flats]]); for evaluation in the paper's fault setting, empty on a chair",
    )


@dataclass(frozen=True)
class ControllerConfig:
    """The controller's whole configuration, one section per concern (``controller.toml``)."""

    geometry: GeometryParams = section(
        GeometryParams, "chair geometry as the controller believes it"
    )
    bus: BusParams = section(BusParams, "the chair's CAN bus")
    loop: LoopParams = section(LoopParams, "control loop")
    limits: LimitParams = section(LimitParams, "command limits")
    drives: DriveSetupParams = section(DriveSetupParams, "drive set-up pushed when arming")
    safety: SafetyParams = section(SafetyParams, "safety monitors")
    auth: AuthParams = section(AuthParams, "authentication key and wire-contract check")
    motor: MotorParams = section(
        MotorParams, "wheel motors and load as the controller believes them"
    )
    body: BodyParams = section(
        BodyParams, "the chair's mass and inertia as the controller believes them"
    )
    estimation: EstimationParams = section(
        EstimationParams, "diagnosis feedback into odometry; injected sensor faults"
    )


def load_config(
    path: str | Path | None = None, overrides: Mapping[str, Any] | None = None
) -> ControllerConfig:
    """Load the controller configuration (defaults file unless ``path``), then ``overrides``."""
    p = Path(path) if path is not None else CONFIG_PATH
    table = params.load_toml(p)
    cfg = params.load(ControllerConfig, table, source=str(p))
    if overrides:
        cfg = params.replace(cfg, overrides, source=f"{p} (overrides)")
    key = Path(cfg.auth.key_file)
    if not key.is_absolute():
        # relative to the file that names it; the default, to controller/
        named = "key_file" in (table.get("auth") or {}) or "key_file" in (
            (overrides or {}).get("auth") or {}
        )
        key = ((p.parent if named else CONFIG_PATH.parent) / key).resolve()
        cfg = params.replace(cfg, {"auth": {"key_file": str(key)}}, source=str(p))
    node_map(cfg, source=str(p))  # the nodes' IDs: in range, distinct, none the host's
    return cfg


def node_map(cfg: ControllerConfig, source: str = "configuration") -> NodeMap:
    """The drives' and the localizer's configured node IDs against the contract's
    (dbc/nodemap.py)."""
    from dbc.codec import Node  # the codec loads cantools: not for every reader of a config
    from dbc.nodemap import NodeMap

    d = cfg.drives
    ids = {Node.LEFT: d.left_node_id, Node.RIGHT: d.right_node_id}
    try:
        return NodeMap(ids | {Node.LOCALIZER: cfg.bus.localizer_node_id})
    except ConfigError as err:
        raise ConfigError(f"{source}: {err}") from None
