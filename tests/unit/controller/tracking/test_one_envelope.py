"""One envelope: the chair's limits (``LimitParams``) bind every registered controller alike.

No law declares a limit of its own; each receives the chair's limits and saturates with
them wherever it saturates internally, and the node's limiter shapes every law's output
with the same limits.  With deliberately tight limits and a large initial error each law
reaches the bound (the chair's limit binds, not a tighter private one), and changing the
limits changes every law's saturated command alike.
"""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Any

import pytest

from controller.config import GeometryParams, LimitParams
from controller.limits import CommandLimiter, LimitedCommand
from controller.tracking import registry
from controller.types import ReferenceSample, StateEstimate, TwistCommand

GEOM = GeometryParams()
B, R = GEOM.half_track_m, GEOM.wheel_radius_m
DT = 0.01
NAMES = registry.names()

#: Names a limit would have (and every LimitParams field).
ENVELOPE_NAME = re.compile(
    r"^(v_min|v_max|v_reverse|accel_max|decel_max|jerk_max|omega_max|alpha_max|wheel_max)"
)

#: Tight chair limits: a rim speed of 0.75 m/s, so the speed limit (0.6 m/s) is reachable
#: straight ahead and the wheel limit binds when turning fast.
TIGHT = LimitParams(
    v_max_mps=0.6, v_reverse_max_mps=0.2, accel_max_mps2=0.4, decel_max_mps2=0.6,
    jerk_max_mps3=4.0, omega_max_radps=0.8, alpha_max_radps2=1.0, wheel_max_radps=2.5,
)  # fmt: skip
#: Other limits: faster, turning faster, a wider wheel limit.
OTHER = dataclasses.replace(TIGHT, v_max_mps=0.9, omega_max_radps=1.2, wheel_max_radps=3.5)

#: What each law saturates internally with the chair's limits: the box of speed and turn
#: rate, their rates (acceleration, deceleration, turn acceleration), the jerk of its
#: acceleration, the wheel speed.  BASELINE saturates nothing: the limiter alone does.
INTERNAL: dict[str, frozenset[str]] = {
    "baseline": frozenset(),
    "robust": frozenset({"box", "rates"}),
    "adaptive": frozenset({"box", "rates"}),
    "antifragile": frozenset({"box", "rates", "jerk", "wheel"}),
    "resilient": frozenset({"wheel"}),
}


def _saturation(name: str) -> frozenset[str]:
    law = registry.gains_section(name)  # a variant saturates as its law does
    assert law in INTERNAL, f"{law}: state what it saturates internally in INTERNAL"
    return INTERNAL[law]


class Line:
    """A virtual robot on the x axis at 0.5 m/s."""

    duration_s = 30.0

    def sample(self, t: float) -> ReferenceSample:
        return ReferenceSample(t, 0.5 * t, 0.0, 0.0, 0.5, 0.0)


def _run(
    name: str, limits: LimitParams, start: tuple[float, float, float], seconds: float
) -> tuple[list[TwistCommand], list[LimitedCommand], list[dict[str, float]]]:
    """The law and the limiter in closed loop with a chair whose wheels lag by 30 ms."""
    traj = Line()
    ctl = registry.create(name, GEOM, traj, limits=limits)
    lim = CommandLimiter(limits, B, R)
    x, y, h = start
    v = w = 0.0
    ctl.reset(StateEstimate(0.0, x, y, h, 0.0, 0.0), 0.0)
    raws, outs, internals = [], [], []
    for k in range(int(seconds / DT)):
        t = k * DT
        raw = ctl.step(t, DT, traj.sample(t), StateEstimate(t, x, y, h, v, w))
        out = lim.apply(raw, DT)
        raws.append(raw)
        outs.append(out)
        internals.append(dict(ctl.internals()))
        for _ in range(5):
            v += (out.v_mps - v) * (DT / 5) / 0.03
            w += (out.omega_radps - w) * (DT / 5) / 0.03
            x, y, h = x + v * math.cos(h) * DT / 5, y + v * math.sin(h) * DT / 5, h + w * DT / 5
    return raws, outs, internals


def _wheel_radps(c: TwistCommand | LimitedCommand) -> float:
    return (abs(c.v_mps) + B * abs(c.omega_radps)) / R


def _check_rates(cmds: list[Any], limits: LimitParams, who: str) -> None:
    """Speeding up within accel_max, slowing down within decel_max, the turn rate's change
    within alpha_max, per tick (from rest); except where the command is at the wheel limit,
    which wins over the rates (both wheels scaled down together)."""
    tol = 1e-9
    v0 = w0 = 0.0
    for k, c in enumerate(cmds):
        dv, dw = c.v_mps - v0, c.omega_radps - w0
        if _wheel_radps(c) < limits.wheel_max_radps - tol:
            speeding_up = abs(c.v_mps) > abs(v0)
            a_max = limits.accel_max_mps2 if speeding_up else limits.decel_max_mps2
            assert abs(dv) <= a_max * DT + tol, f"{who}: tick {k}: dv {dv}"
            assert abs(dw) <= limits.alpha_max_radps2 * DT + tol, f"{who}: tick {k}: dw {dw}"
        v0, w0 = c.v_mps, c.omega_radps


def _check_box_and_wheel(
    cmds: list[Any], limits: LimitParams, who: str, *, box: bool = True, wheel: bool = True
) -> None:
    tol = 1e-9
    for k, c in enumerate(cmds):
        if box:
            assert -limits.v_reverse_max_mps - tol <= c.v_mps <= limits.v_max_mps + tol, (who, k)
            assert abs(c.omega_radps) <= limits.omega_max_radps + tol, (who, k)
        if wheel:
            assert _wheel_radps(c) <= limits.wheel_max_radps + tol, (who, k)


# ------------------------------------------------------------------ (a) no private limits


def _field_names(cls: type) -> list[str]:
    """Every field of a Params dataclass, its sections' fields included (dotted)."""
    out = []
    for f in dataclasses.fields(cls):
        typ = f.type if isinstance(f.type, type) else None
        default = f.default_factory() if callable(f.default_factory) else f.default
        if dataclasses.is_dataclass(default) and not isinstance(default, type):
            out += [f"{f.name}.{n}" for n in _field_names(type(default))]
        elif typ is not None and dataclasses.is_dataclass(typ):
            out += [f"{f.name}.{n}" for n in _field_names(typ)]
        else:
            out.append(f.name)
    return out


@pytest.mark.parametrize("name", NAMES)
def test_no_controller_declares_a_limit_of_its_own(name: str) -> None:
    names = _field_names(registry.controller_class(name).Params)
    limit_fields = {f.name for f in dataclasses.fields(LimitParams)}
    own = [n for n in names if ENVELOPE_NAME.match(n.rsplit(".", 1)[-1])]
    assert own == [], f"{name} declares limits of its own: {own}"
    assert not limit_fields & {n.rsplit(".", 1)[-1] for n in names}


@pytest.mark.parametrize("name", NAMES)
def test_every_controller_receives_the_chairs_limits(name: str) -> None:
    assert registry.create(name, GEOM, Line(), limits=TIGHT).limits is TIGHT  # type: ignore[attr-defined]


# ------------------------------------------------------------------ (b) tight limits bind


@pytest.mark.parametrize("name", NAMES)
def test_tight_limits_bound_the_law_and_the_limited_command_and_the_law_reaches_them(
    name: str,
) -> None:
    """1 m behind, 0.4 m right of a reference at 0.5 m/s, turned 0.5 rad away, at rest."""
    sat = _saturation(name)
    raws, outs, internals = _run(name, TIGHT, (-1.0, -0.4, 0.5), 10.0)
    assert all(math.isfinite(c.v_mps) and math.isfinite(c.omega_radps) for c in raws)
    # the command sent: always inside the chair's limits
    _check_box_and_wheel(outs, TIGHT, f"{name} limited")
    _check_rates(outs, TIGHT, f"{name} limited")
    # the law's own command: inside them wherever it saturates
    if sat:
        _check_box_and_wheel(raws, TIGHT, f"{name} raw", box="box" in sat, wheel="wheel" in sat)
    if "rates" in sat:
        _check_rates(raws, TIGHT, f"{name} raw")
    if "jerk" in sat:  # the acceleration's change, except where the speed limit cuts it
        acc = [i["a_c_mps2"] for i in internals]
        for k, (a0, a1) in enumerate(zip([0.0, *acc], acc, strict=False)):
            if raws[k].v_mps not in (TIGHT.v_max_mps, -TIGHT.v_reverse_max_mps):
                assert abs(a1 - a0) <= TIGHT.jerk_max_mps3 * DT + 1e-9, (name, k)
    # ... and it reaches them: the chair's limit binds, not a tighter one of its own
    v_top = max(c.v_mps for c in (raws if "box" in sat else outs))
    assert v_top == pytest.approx(TIGHT.v_max_mps, abs=1e-12)
    if "wheel" in sat:
        assert max(_wheel_radps(c) for c in raws) == pytest.approx(TIGHT.wheel_max_radps)
    if name == "antifragile":
        assert max(abs(c.omega_radps) for c in raws) == pytest.approx(TIGHT.omega_max_radps)
        acc = [i["a_c_mps2"] for i in internals]
        assert max(acc) == pytest.approx(TIGHT.accel_max_mps2)
        assert min(acc) >= -TIGHT.decel_max_mps2 - 1e-12


# ------------------------------------------------------------------ (c) the same for all


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("limits", [TIGHT, OTHER], ids=["tight", "other"])
def test_changing_the_limits_changes_every_laws_saturated_command_alike(
    name: str, limits: LimitParams
) -> None:
    """3 m behind on the path, at rest: every law asks for more speed than the chair may
    have; its command sent settles at the speed limit, whichever law and limits."""
    raws, outs, _ = _run(name, limits, (-3.0, 0.0, 0.0), 5.0)
    tail = outs[-100:]  # the last second
    assert {c.v_mps for c in tail} == {limits.v_max_mps}
    assert max(abs(c.omega_radps) for c in tail) < 1e-12
    if "box" in _saturation(name):  # the law's own command is the same
        assert {c.v_mps for c in raws[-100:]} == {limits.v_max_mps}
