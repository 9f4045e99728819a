"""What a 30 % heavier believed chair changes in each law's commands.

ADAPTIVE predicts with the dynamic model (force over mass, moment over inertia, the
``m d`` couplings): its commands move.  ROBUST divides its torques by ``alpha`` and ``beta``
and multiplies them back into the twist the velocity-controlled drives follow, so the
believed mass and inertia cancel (docs/controllers.md, "the law is kinematic at its
output").  The other laws take no body at all.
"""

from __future__ import annotations

import dataclasses
import inspect

import pytest

from controller.config import BodyParams, GeometryParams
from controller.tracking import registry
from controller.types import StateEstimate

from .trajectories import Circle

GEOM = GeometryParams()
NOMINAL = BodyParams()
HEAVY = dataclasses.replace(
    NOMINAL, mass_kg=1.3 * NOMINAL.mass_kg, yaw_inertia_kgm2=1.3 * NOMINAL.yaw_inertia_kgm2
)


def _commands(name: str, body: BodyParams) -> list[tuple[float, float]]:
    """50 ticks from a state off the reference (behind, right, turned, slow)."""
    traj = Circle()
    ctl = registry.create(name, GEOM, traj, body=body)
    t0 = 3.0
    ref = traj.sample(t0)
    est = StateEstimate(
        t0, ref.x_m + 0.05, ref.y_m - 0.04, ref.heading_rad + 0.1, ref.v_mps - 0.1,
        ref.omega_radps + 0.05,
    )  # fmt: skip
    ctl.reset(est, t0)
    out = []
    for k in range(50):
        t = t0 + 0.01 * k
        cmd = ctl.step(t, 0.01, traj.sample(t), dataclasses.replace(est, t_s=t))
        out.append((cmd.v_mps, cmd.omega_radps))
    return out


def _largest_change(name: str) -> float:
    a, b = _commands(name, NOMINAL), _commands(name, HEAVY)
    return max(max(abs(x[0] - y[0]), abs(x[1] - y[1])) for x, y in zip(a, b, strict=True))


def test_a_heavier_believed_chair_changes_adaptives_commands() -> None:
    change = _largest_change("adaptive")
    print(f"\nADAPTIVE: largest command change with a 30 % heavier believed chair {change:.3g}")
    assert change > 0.01  # m/s or rad/s


def test_a_heavier_believed_chair_changes_no_command_of_robust() -> None:
    # declared: alpha, beta cancel between the torques and the twist set-point
    change = _largest_change("robust")
    print(f"\nROBUST: largest command change with a 30 % heavier believed chair {change:.3g}")
    assert change == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("name", ["baseline", "antifragile", "resilient"])
def test_the_kinematic_laws_take_no_believed_body(name: str) -> None:
    assert "body" not in inspect.signature(registry.controller_class(name)).parameters
