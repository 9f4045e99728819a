"""Localization node: rate, seeded Gaussian noise, heading wrap."""

from __future__ import annotations

import math
import statistics
from typing import Any

import pytest

from dbc.codec import Node, PoseFix
from firmware_sim.config import LocalizerParams, load_bench_config
from firmware_sim.localizer import Localizer
from firmware_sim.sim import ChairSim

MS = 1_000_000


def fixes(loc: Localizer, steps: int, pose: tuple[float, float, float]) -> list[tuple[int, Any]]:
    got: list[tuple[int, Any]] = []
    for k in range(steps):
        out: list[tuple[Any, Node | None]] = []
        loc.emit_due(k * 10 * MS, *pose, out)
        got.extend((k * 10 * MS, p) for p, _n in out)
    return got


def test_fixes_come_at_the_configured_rate_from_node_3() -> None:
    loc = Localizer(LocalizerParams(rate_hz=20.0), 50 * MS, seed=1)
    out: list[tuple[Any, Node | None]] = []
    loc.emit_due(0, 1.0, 2.0, 0.5, out)
    assert out[0][1] == Node.LOCALIZER
    times = [t for t, _ in fixes(Localizer(LocalizerParams(), 100 * MS, seed=1), 100, (0, 0, 0))]
    assert times == [k * 100 * MS for k in range(10)]


def test_noise_has_the_configured_standard_deviations() -> None:
    params = LocalizerParams(sigma_xy_m=0.05, sigma_heading_rad=0.02)
    got = [p for _t, p in fixes(Localizer(params, 10 * MS, seed=3), 4000, (10.0, -5.0, 1.0))]
    assert statistics.fmean(p.x_m for p in got) == pytest.approx(10.0, abs=0.005)
    assert statistics.stdev(p.x_m for p in got) == pytest.approx(0.05, rel=0.06)
    assert statistics.stdev(p.y_m for p in got) == pytest.approx(0.05, rel=0.06)
    assert statistics.stdev(p.heading_rad for p in got) == pytest.approx(0.02, rel=0.06)


def test_the_same_seed_gives_the_same_fixes_and_another_seed_does_not() -> None:
    def run(seed: int) -> list[PoseFix]:
        return [
            p for _t, p in fixes(Localizer(LocalizerParams(), 10 * MS, seed=seed), 50, (0, 0, 0))
        ]

    assert run(5) == run(5)
    assert run(5) != run(6)


def test_headings_are_wrapped_to_minus_pi_pi() -> None:
    params = LocalizerParams(sigma_heading_rad=0.1)
    got = [p for _t, p in fixes(Localizer(params, 10 * MS, seed=0), 500, (0.0, 0.0, 7 * math.pi))]
    assert all(-math.pi < p.heading_rad <= math.pi for p in got)
    assert min(abs(p.heading_rad) for p in got) > 2.5  # near +-pi, not near 0


def test_the_sim_fixes_the_axle_midpoint_and_can_switch_the_localizer_off() -> None:
    cfg = load_bench_config(
        {"localizer.sigma_xy_m": 0.0, "localizer.sigma_heading_rad": 0.0}, source="t"
    )
    sim = ChairSim(cfg, initial_pose=(1.5, -2.0, 0.25))
    out: list[tuple[Any, Node | None]] = []
    sim.emit_due(out)
    (fix,) = [p for p, n in out if n == Node.LOCALIZER]
    assert (fix.x_m, fix.y_m, fix.heading_rad) == (1.5, -2.0, 0.25)
    off = ChairSim(load_bench_config({"localizer.enabled": False}, source="t"))
    out.clear()
    off.emit_due(out)
    assert all(n != Node.LOCALIZER for _p, n in out)
