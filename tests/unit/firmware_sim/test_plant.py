"""Chair physics: kinematics, the paper's dynamic model, motors, energy, integration accuracy."""

from __future__ import annotations

import itertools
import math

import pytest

from dbc.codec import AxisState, Node, SetAxisState, SetInputVel
from firmware_sim.config import GRAVITY_MPS2, BenchConfig, load_bench_config
from firmware_sim.drive import Out
from firmware_sim.plant import Plant, wrap_angle
from firmware_sim.sim import ChairSim

DT = 0.001


def make_plant(**overrides: float) -> Plant:
    cfg = load_bench_config({k: v for k, v in overrides.items()}, source="test")
    return Plant(cfg.chair, cfg.motor, cfg.drive)


def power(p: Plant, u_left_v: float, u_right_v: float) -> None:
    for wheel, u in ((p.left, u_left_v), (p.right, u_right_v)):
        wheel.powered = True
        wheel.brake_engaged = False
        wheel.voltage_v = u


def coast(p: Plant, w_left: float, w_right: float) -> None:
    for wheel, w in ((p.left, w_left), (p.right, w_right)):
        wheel.powered = False
        wheel.brake_engaged = False
        wheel.omega_radps = w


def run(p: Plant, seconds: float, dt: float = DT) -> None:
    for _ in range(round(seconds / dt)):
        p.step(dt)


def test_equal_wheel_speeds_drive_straight_along_the_heading() -> None:
    p = make_plant()
    p.heading_rad = 0.3
    power(p, 12.0, 12.0)
    run(p, 3.0)
    assert p.heading_rad == pytest.approx(0.3, abs=1e-12)
    assert math.atan2(p.y_m, p.x_m) == pytest.approx(0.3, abs=1e-9)
    assert p.v_mps > 0.5


def test_a_faster_right_wheel_turns_the_chair_counter_clockwise() -> None:
    p = make_plant()
    power(p, 8.0, 12.0)
    run(p, 2.0)
    assert p.omega_radps > 0.1
    assert p.heading_rad > 0.2
    assert p.y_m > 0.0  # drifting to the left of the initial heading


def test_twist_follows_the_paper_kinematics() -> None:
    p = make_plant()
    coast(p, 2.0, 3.0)
    v, w = p.body_twist()
    r, b = 0.30, 0.28
    assert v == pytest.approx(r * (3.0 + 2.0) / 2)
    assert w == pytest.approx(r * (3.0 - 2.0) / (2 * b))


def test_steady_speed_under_voltage_saturation_is_no_load_speed_minus_losses() -> None:
    cfg = BenchConfig()
    c, m = cfg.chair, cfg.motor
    p = Plant(c, m, cfg.drive)
    power(p, m.bus_voltage_v, m.bus_voltage_v)
    run(p, 4.0)
    kn = m.torque_constant_nm_per_a * m.gear_ratio
    no_load = m.bus_voltage_v / kn
    rolling_torque = 0.5 * c.rolling_resistance_coeff * c.mass_kg * GRAVITY_MPS2 * c.wheel_radius_m
    current = rolling_torque / (m.gear_efficiency * kn)
    expected = (m.bus_voltage_v - m.resistance_ohm * current) / kn
    assert p.right.omega_radps == pytest.approx(expected, rel=1e-4)
    assert p.left.omega_radps == pytest.approx(expected, rel=1e-4)
    assert p.right.current_a == pytest.approx(current, rel=1e-3)
    assert 0.95 * no_load < expected < no_load


def test_coasting_without_losses_conserves_kinetic_energy_while_turning() -> None:
    # The m*d*phi_dot coupling (paper Eq. velocity) does no work: 1/2 w^T Mbar w is constant.
    p = make_plant(**{"chair.rolling_resistance_coeff": 0.0, "chair.com_offset_m": 0.2})
    coast(p, 1.0, 4.0)
    e0 = p.kinetic_energy_j()
    run(p, 10.0)
    assert p.kinetic_energy_j() == pytest.approx(e0, rel=1e-9)
    assert p.right.omega_radps != pytest.approx(4.0, abs=1e-3)  # the coupling did act


def test_rolling_resistance_only_ever_takes_energy_out() -> None:
    p = make_plant()
    coast(p, 2.0, 3.0)
    energies = []
    for _ in range(200):
        run(p, 0.01)
        energies.append(p.kinetic_energy_j())
    assert all(b < a for a, b in itertools.pairwise(energies))


@pytest.mark.parametrize(("d_m", "sign"), [(0.15, 1.0), (-0.15, -1.0)])
def test_spinning_in_place_pulls_the_axle_toward_the_centre_of_mass(
    d_m: float, sign: float
) -> None:
    # m (v_dot - d phi_dot^2) = F: with free wheels the axle accelerates toward the CoM side.
    p = make_plant(**{"chair.rolling_resistance_coeff": 0.0, "chair.com_offset_m": d_m})
    coast(p, -3.0, 3.0)
    run(p, 0.05)
    assert sign * p.v_mps > 0.001


def test_a_shrunken_right_wheel_turns_the_chair_right_at_equal_wheel_speeds() -> None:
    p = make_plant()
    p.right.radius_m = 0.26  # the paper's flat tyre
    coast(p, 3.0, 3.0)
    p.step(DT)
    assert p.omega_radps < 0.0
    assert p.omega_radps == pytest.approx((0.26 - 0.30) * p.right.omega_radps / 0.56, rel=1e-2)


def test_fault_seams_scale_torque_and_contact_radius() -> None:
    p = make_plant()
    power(p, 12.0, 12.0)
    p.right.torque_gain = 0.0
    run(p, 0.2)
    assert p.left.omega_radps > 0.3
    assert p.omega_radps < 0.0  # only the left wheel pushes
    q = make_plant()
    q.left.slip_ratio = 0.5
    q.left.radius_offset_m = 0.02
    assert q.left.rolling_radius_m == pytest.approx(0.32)
    assert q.left.contact_radius_m == pytest.approx(0.16)


def test_the_holding_brake_stops_a_rolling_chair() -> None:
    p = make_plant()
    coast(p, 3.0, 3.0)
    p.left.brake_engaged = p.right.brake_engaged = True
    run(p, 1.0)
    assert abs(p.left.omega_radps) < 0.01
    assert abs(p.right.omega_radps) < 0.01


def test_an_unpowered_motor_carries_no_current() -> None:
    p = make_plant()
    power(p, 12.0, 12.0)
    run(p, 0.1)
    assert p.left.current_a > 1.0
    p.left.powered = False
    p.step(DT)
    assert p.left.current_a == 0.0


def test_wrap_angle_maps_into_minus_pi_to_pi() -> None:
    assert wrap_angle(math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(0.1 - 4 * math.pi) == pytest.approx(0.1)


def _profile_pose(substeps: int, seconds: float = 60.0) -> tuple[float, float, float]:
    cfg = load_bench_config(
        {
            "bench.physics_substeps": substeps,
            **{"drive.require_auth": False, "drive.check_contract": False},
        },
        source="test",
    )
    sim = ChairSim(cfg)
    out: Out = []
    for node in (Node.LEFT, Node.RIGHT):
        sim.handle(node, SetAxisState(AxisState.CLOSED_LOOP_CONTROL), out)
    for k in range(round(seconds * 100)):
        t = k * 0.01
        ramp = min(1.0, t / 3.0)
        left = ramp * (0.35 + 0.15 * math.sin(0.4 * t))
        right = ramp * (0.35 + 0.2 * math.sin(0.25 * t + 1.0))
        if 20.0 <= t < 22.0:  # spin in place
            left, right = -0.2, 0.2
        if 40.0 <= t < 41.0:  # hard stop, current-limited
            left = right = 0.0
        sim.handle(Node.LEFT, SetInputVel(left), out)
        sim.handle(Node.RIGHT, SetInputVel(right), out)
        sim.advance()
    p = sim.plant
    return p.x_m, p.y_m, p.heading_rad


def test_halving_the_physics_step_moves_the_final_pose_by_less_than_a_millimetre() -> None:
    # 60 s through both drives' 1 kHz PID; only the RK4 step changes (1 ms -> 0.5 ms).
    x1, y1, h1 = _profile_pose(1)
    x2, y2, h2 = _profile_pose(2)
    assert math.hypot(x1, y1) > 5.0  # the chair went somewhere
    diff_m = math.hypot(x1 - x2, y1 - y2)
    print(f"\nstep-halving pose difference after 60 s: {diff_m * 1e6:.3f} um")
    assert diff_m < 1e-3
    assert abs(h1 - h2) < 1e-5
