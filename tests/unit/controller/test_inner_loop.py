"""Singular-perturbation tuning of the drives' velocity PID (controller.inner_loop).

The design is checked three ways: the paper's notation, the exact pole map from the
normalized gains to the physical loop, and the gains pushed into the emulated ODrive
(the bench stands in for a real drive here; the controller itself never imports it).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from scipy import signal

from controller.config import MotorParams
from controller.inner_loop import (
    MIN_SEPARATION,
    InnerLoopParams,
    closed_loop_poles,
    design,
    fast_poles,
)
from dbc.codec import (
    AxisState,
    Node,
    SetAxisState,
    SetInputVel,
    SetLimits,
    SetVelDerivativeGain,
    SetVelGains,
)
from dbc.runtime.errors import ConfigError
from firmware_sim.config import load_bench_config
from firmware_sim.sim import ChairSim

TWO_PI = 2.0 * math.pi


def test_the_normalized_gains_follow_the_papers_notation() -> None:
    g = InnerLoopParams(k1=0.17, k2=1.1, ki_hat_per_s=6.0)
    d = design(MotorParams(), g)
    assert d.epsilon_s == pytest.approx(0.001 / 0.4)
    assert d.kp == d.k1 == 0.17  # k1 = Kp
    assert d.kp * d.kd == pytest.approx(d.k2)  # k2 = Kp Kd
    assert d.k3_per_s == pytest.approx(d.kp * d.ki_hat_per_s)  # k3 = Kp K^i
    assert d.ki == pytest.approx(d.epsilon_s * d.ki_hat_per_s)  # Ki = eps K^i
    # motor N*m per wheel rev/s etc.: P = k1 J / (eps eta N), D = (k2 - 1) J / (eta N), I = K^i P
    assert d.drive_gains.vel_gain == pytest.approx(TWO_PI * 0.17 * 6.0 / (0.0025 * 28.8))
    assert d.drive_gains.vel_derivative_gain == pytest.approx(TWO_PI * 0.1 * 6.0 / 28.8)
    assert d.drive_gains.vel_integrator_gain == pytest.approx(6.0 * d.drive_gains.vel_gain)


@pytest.mark.parametrize(
    ("k1", "k2", "ki_hat", "inertia"),
    [(0.17, 1.1, 6.0, 6.0), (0.1, 1.0, 2.0, 9.0), (0.19, 1.4, 10.0, 3.0), (0.05, 2.0, 1.0, 20.0)],
)
def test_the_physical_loop_has_exactly_the_designed_poles(
    k1: float, k2: float, ki_hat: float, inertia: float
) -> None:
    """eps J s^3 + (J + eta N D) s^2 + eta N P s + eta N I, current lag included."""
    motor = MotorParams(reflected_inertia_kgm2=inertia)
    d = design(motor, InnerLoopParams(k1=k1, k2=k2, ki_hat_per_s=ki_hat))
    g, eps, j = motor.torque_gain, motor.epsilon_s, inertia
    gains = d.drive_gains
    p, i, dd = (gains.vel_gain / TWO_PI, gains.vel_integrator_gain / TWO_PI,
                gains.vel_derivative_gain / TWO_PI)  # fmt: skip
    physical = sorted(np.roots([eps * j, j + g * dd, g * p, g * i]), key=lambda z: z.real)
    designed = sorted(d.closed_loop_poles_per_s, key=lambda z: z.real)
    assert np.allclose(physical, designed, rtol=1e-9)
    assert all(z.real < 0.0 for z in designed)


def test_time_scales_separate_and_the_reduced_model_predicts_the_slow_pole() -> None:
    d = design(MotorParams(), InnerLoopParams())
    fast = d.fast_poles_per_s
    assert all(z.real < 0.0 for z in fast)  # Eq. (hurwitz)
    assert d.separation >= MIN_SEPARATION
    slowest_exact = max(z.real for z in d.closed_loop_poles_per_s)
    # the reduced (eps -> 0) model x' = -(k3/k1) x: the integral pole, to O(eps K^i / k1)
    assert slowest_exact == pytest.approx(d.slow_pole_per_s, rel=0.15)
    # the two faster exact poles are the PD (boundary-layer) poles, perturbed by the integral
    exact_fast = sorted((z.real for z in d.closed_loop_poles_per_s), key=abs)[1:]
    assert exact_fast == pytest.approx(sorted((z.real for z in fast), key=abs), rel=0.15)


def test_the_pd_part_is_hurwitz_for_any_believed_inertia() -> None:
    """With P > 0 and D >= 0 a wrong inertia scales k1 and k2 - 1 but never destabilizes."""
    d = design(MotorParams(), InnerLoopParams())
    for true_j in (1.0, 6.0, 8.75, 40.0):
        k1 = d.epsilon_s * d.torque_gain * d.p_nm_per_radps / true_j
        k2 = 1.0 + d.torque_gain * d.d_nm_per_radps2 / true_j
        assert all(z.real < 0.0 for z in fast_poles(k1, k2, d.epsilon_s))
        k3 = d.epsilon_s * d.torque_gain * d.i_nm_per_rad / true_j
        assert all(z.real < 0.0 for z in closed_loop_poles(k1, k2, k3, d.epsilon_s))


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"k2": 0.8}, "k2 = 0.8 < 1"),  # would need a negative derivative gain
        ({"ki_hat_per_s": 40.0}, "ki_hat_per_s"),  # integral as fast as the PD part
        ({"k1": 0.5}, "Vel_Gain"),  # 262 N*m/(rev/s) does not fit the CAN signal
    ],
)
def test_designs_that_break_a_rule_are_refused_at_configure_time(
    change: dict[str, Any], match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        design(MotorParams(), dataclasses.replace(InnerLoopParams(), **change))


def test_the_believed_motor_matches_the_bench_defaults() -> None:
    bench = load_bench_config(None, source="test")
    m, ours = bench.motor, MotorParams()
    assert ours.torque_constant_nm_per_a == m.torque_constant_nm_per_a
    assert ours.resistance_ohm == m.resistance_ohm
    assert ours.inductance_h == m.inductance_h
    assert ours.gear_ratio == m.gear_ratio
    assert ours.gear_efficiency == m.gear_efficiency
    c = bench.chair
    driving = c.wheel_inertia_kgm2 + c.wheel_radius_m**2 * c.mass_kg / 2.0
    assert ours.reflected_inertia_kgm2 == pytest.approx(driving, rel=0.01)


def _step(gains: Any, target_revps: float, spin: bool) -> list[float]:
    sim = ChairSim(
        load_bench_config(
            {"drive.require_auth": False, "drive.check_contract": False}, source="test"
        )
    )  # stock ODrive
    out: list[Any] = []
    for n in (Node.LEFT, Node.RIGHT):
        sim.handle(n, SetLimits(3.0, 40.0), out)
        sim.handle(n, SetVelGains(gains.vel_gain, gains.vel_integrator_gain), out)
        sim.handle(
            n, SetVelDerivativeGain(gains.vel_derivative_gain, gains.derivative_cutoff_hz), out
        )
        sim.handle(n, SetAxisState(AxisState.CLOSED_LOOP_CONTROL), out)
    sim.handle(Node.LEFT, SetInputVel(-target_revps if spin else target_revps), out)
    sim.handle(Node.RIGHT, SetInputVel(target_revps), out)
    samples: list[float] = []
    sim.add_tick_hook(lambda _t, p: samples.append(p.right.omega_radps / TWO_PI))
    for _ in range(60):  # 0.6 s of 10 ms bench steps, 1 kHz inside
        sim.advance()
    return samples


def _rise_overshoot(y: list[float] | np.ndarray, dt: float, target: float) -> tuple[float, float]:
    y = np.asarray(y) / target
    return (int(np.argmax(y >= 0.9)) - int(np.argmax(y >= 0.1))) * dt, float(y.max() - 1.0)


@pytest.mark.parametrize(("spin", "inertia"), [(False, 6.0), (True, 8.75)])
def test_the_designed_gains_give_the_predicted_step_response_on_the_emulated_drive(
    spin: bool, inertia: float
) -> None:
    """Linear-range step (0.02 rev/s): the 1 kHz drive with its PLL behaves like the model."""
    d = design(MotorParams(), InnerLoopParams())
    y = _step(d.drive_gains, 0.02, spin)
    rise, overshoot = _rise_overshoot(y, 0.001, 0.02)
    # the continuous model with the inertia this mode sees (driving / spinning in place)
    g, eps = d.torque_gain, d.epsilon_s
    num = [g * d.p_nm_per_radps, g * d.i_nm_per_rad]
    den = [eps * inertia, inertia + g * d.d_nm_per_radps2, g * d.p_nm_per_radps, num[1]]
    t = np.arange(0.0, 0.6, 1e-4)
    _, ym = signal.step((num, den), T=t)
    m_rise, m_overshoot = _rise_overshoot(ym, 1e-4, 1.0)
    print(f"\nstep {'spin' if spin else 'drive'}: emulated rise {rise * 1e3:.0f} ms, "
          f"overshoot {overshoot:.1%}; model {m_rise * 1e3:.0f} ms, {m_overshoot:.1%}")  # fmt: skip
    assert 0.6 * m_rise < rise < 1.4 * m_rise
    assert overshoot < m_overshoot + 0.02
    assert rise < 0.040 and overshoot < 0.08
    assert y[-1] == pytest.approx(0.02, rel=0.01)  # the slow integral removes the load error
