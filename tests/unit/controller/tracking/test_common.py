"""The pieces several tracking laws share (controller/tracking/common.py), and what every law
does with an estimate that is not finite."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from controller.config import load_config
from controller.planner import load_route, plan
from controller.tracking import registry
from controller.tracking.common import PlainPid, inv_cos, path_errors, sat
from controller.types import ReferenceSample, StateEstimate, tracking_error, wrap_angle

ROOT = Path(__file__).resolve().parents[4]
CFG = load_config()
SHORT = plan(load_route(ROOT / "scenarios" / "routes" / "short.toml"))


def _ref(x: float, y: float, h: float) -> ReferenceSample:
    return ReferenceSample(0.0, x, y, h, 0.5, 0.1, 0.0, 0.0)


def test_path_errors_are_the_papers_errors_in_the_desired_frame() -> None:
    ref = _ref(1.0, 2.0, math.pi / 2)  # heading along +y
    est = StateEstimate(0.0, 1.1, 2.3, math.pi / 2 + 0.2, 0.0, 0.0)
    xe, ye, pe = path_errors(ref, est)
    assert xe == pytest.approx(0.3)  # ahead along the path
    assert ye == pytest.approx(-0.1)  # to the right of it
    assert pe == pytest.approx(0.2)
    te = tracking_error(est.x_m, est.y_m, est.heading_rad, ref)
    assert (xe, ye, pe) == (te.x_e_m, te.y_e_m, te.phi_e_rad)
    # the heading error is wrapped
    _, _, pe = path_errors(ref, StateEstimate(0.0, 1.0, 2.0, math.pi / 2 + 2 * math.pi - 0.1, 0, 0))
    assert pe == pytest.approx(-0.1)


def test_wrap_angle_of_a_non_finite_angle_is_nan_instead_of_raising() -> None:
    for a in (math.inf, -math.inf, math.nan):
        assert math.isnan(wrap_angle(a))
    assert wrap_angle(math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)


def test_sat_and_inv_cos() -> None:
    assert (sat(-3.0), sat(-0.25), sat(0.5), sat(7.0)) == (-1.0, -0.25, 0.5, 1.0)
    assert inv_cos(0.5, 0.35) == 2.0
    assert inv_cos(0.35, 0.35) == pytest.approx(1.0 / 0.35)
    # below cos_min the gain fades linearly to zero at 90 degrees, and stays zero beyond
    assert inv_cos(0.175, 0.35) == pytest.approx(0.5 * 0.35 / 0.35**2)
    assert inv_cos(0.0, 0.35) == 0.0 and inv_cos(-0.5, 0.35) == 0.0


def test_plain_pid_gains_reach_the_drives_unchanged() -> None:
    pid = PlainPid(vel_gain=1.0, vel_integrator_gain=2.0, vel_derivative_gain=3.0)
    g = pid.drive_gains()
    assert (g.vel_gain, g.vel_integrator_gain, g.vel_derivative_gain) == (1.0, 2.0, 3.0)
    assert g.derivative_cutoff_hz == pid.derivative_cutoff_hz


#: Kanayama's law has no degraded mode of its own: the node brakes on its non-finite output.
DEGRADING = [n for n in registry.names() if n != "baseline"]


@pytest.mark.parametrize("name", DEGRADING)
@pytest.mark.parametrize(
    "bad",
    [{"heading_rad": math.inf}, {"heading_rad": math.nan}, {"x_m": -math.inf}, {"y_m": math.nan}],
    ids=["heading-inf", "heading-nan", "x-inf", "y-nan"],
)
def test_every_law_degrades_on_a_non_finite_pose_instead_of_raising(
    name: str, bad: dict[str, float]
) -> None:
    ctl = registry.create(name, CFG.geometry, SHORT, motor=CFG.motor, body=CFG.body)
    s0 = SHORT.sample(0.0)
    ctl.reset(StateEstimate(0.0, s0.x_m, s0.y_m, s0.heading_rad, 0.0, 0.0), 0.0)
    good = {"x_m": s0.x_m, "y_m": s0.y_m, "heading_rad": s0.heading_rad}
    est = StateEstimate(1.0, **(good | bad), v_mps=0.0, omega_radps=0.0)
    cmd = ctl.step(1.0, 0.01, SHORT.sample(1.0), est)
    assert math.isfinite(cmd.v_mps) and math.isfinite(cmd.omega_radps)
    assert abs(cmd.v_mps) < 0.05 and abs(cmd.omega_radps) < 0.1  # from rest: nothing drives on


@pytest.mark.parametrize("heading", [math.inf, -math.inf, math.nan])
def test_kanayama_gives_a_non_finite_command_on_a_non_finite_heading_instead_of_raising(
    heading: float,
) -> None:
    """BASELINE has no degraded mode: its non-finite command is the node's NON_FINITE stop."""
    ctl = registry.create("baseline", CFG.geometry, SHORT, motor=CFG.motor, body=CFG.body)
    s0 = SHORT.sample(0.0)
    est = StateEstimate(1.0, s0.x_m, s0.y_m, heading, 0.0, 0.0)
    cmd = ctl.step(1.0, 0.01, SHORT.sample(1.0), est)
    assert not (math.isfinite(cmd.v_mps) and math.isfinite(cmd.omega_radps))
