"""How one run of a campaign departs from its scenario file: the Monte-Carlo draws and applying them.

:class:`Variation` is one run's departure (replicate, seed, fault amplitude and onset, mass,
sensor noise, initial pose, one fault alone, a random cascade); :func:`draw_variation` and
:func:`draw_cascade` draw the Monte-Carlo replicates with common random numbers (every
controller and scenario sees the same draws of a replicate); :func:`apply_variation` gives
the scenario as the run sees it.  docs/evaluation.md states the ranges (plan.MC_*).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from dbc.runtime import params as params_mod
from firmware_sim.config import load_bench_config
from firmware_sim.faultspec import FaultSpec
from tools.evaluation.plan import (
    MC_AMPLITUDE_SPREAD,
    MC_CASCADE_FACTOR,
    MC_CASCADE_LAST_S,
    MC_CASCADE_WINDOW_S,
    MC_MASS_SPREAD,
    MC_NOISE_RANGE,
    MC_OFFSET_M,
    MC_OFFSET_RAD,
    MC_ONSET_SHIFT_S,
    EvaluationError,
)


@dataclass(frozen=True)
class Variation:
    """How one run departs from its scenario file.  The default is the nominal run.

    ``replicate`` 0 is the nominal condition; replicates >= 1 are Monte-Carlo draws
    (:func:`draw_variation`).  ``seed`` None keeps the campaign's base seed.
    """

    replicate: int = 0
    seed: int | None = None
    amplitude_factor: float = 1.0
    onset_shift_s: float = 0.0
    mass_factor: float = 1.0
    noise_factor: float = 1.0
    initial_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    only_fault: int | None = None
    #: per fault of the schedule: (onset_s, duration_s, amplitude factor), replacing the
    #: schedule's timing and the common onset shift and amplitude (:func:`draw_cascade`)
    cascade: tuple[tuple[float, float, float], ...] | None = None

    def tag(self) -> str:
        """A short, content-derived name for the run's directory."""
        parts = []
        if self.cascade is not None:
            parts.append("random")
        if self.replicate:
            parts.append(f"r{self.replicate:02d}")
        if self.amplitude_factor != 1.0:
            parts.append(f"x{self.amplitude_factor:g}")
        if self.only_fault is not None:
            parts.append(f"only{self.only_fault + 1}")
        return "-".join(parts) or "nominal"


#: The nominal run: the scenario file as it is.
NOMINAL = Variation()


def draw_variation(base_seed: int, replicate: int, *, vary_amplitude: bool = True) -> Variation:
    """Monte-Carlo replicate ``replicate`` (>= 1) of a campaign seeded with ``base_seed``.

    Every draw is made in a fixed order whatever is used, so replicate ``r`` has the same
    mass, noise, onset, initial pose and seed in every scenario and for every controller
    (common random numbers), with or without the amplitude draw.
    """
    if replicate < 1:
        raise ValueError(f"Monte-Carlo replicates start at 1, got {replicate}")
    rng = np.random.default_rng([base_seed, replicate])
    seed = int(rng.integers(1, 2**31 - 1))
    noise = float(rng.uniform(*MC_NOISE_RANGE))
    onset = float(rng.uniform(-MC_ONSET_SHIFT_S, MC_ONSET_SHIFT_S))
    amplitude = float(rng.uniform(1.0 - MC_AMPLITUDE_SPREAD, 1.0 + MC_AMPLITUDE_SPREAD))
    along, left = (float(v) for v in rng.uniform(-MC_OFFSET_M, MC_OFFSET_M, size=2))
    heading = float(rng.uniform(-MC_OFFSET_RAD, MC_OFFSET_RAD))
    mass = float(rng.uniform(1.0 - MC_MASS_SPREAD, 1.0 + MC_MASS_SPREAD))
    return Variation(
        replicate=replicate,
        seed=seed,
        amplitude_factor=amplitude if vary_amplitude else 1.0,
        onset_shift_s=onset,
        mass_factor=mass,
        noise_factor=noise,
        initial_offset=(along, left, heading),
    )


def draw_cascade(base_seed: int, replicate: int, n_faults: int) -> Variation:
    """Monte-Carlo replicate ``replicate`` of the cascaded run: :func:`draw_variation`'s
    draws (noise, mass, initial pose, seed), and faults at random moments with random
    magnitudes, in the schedule's order (plan.MC_CASCADE_*)."""
    base = draw_variation(base_seed, replicate, vary_amplitude=False)
    rng = np.random.default_rng([base_seed, replicate, 13])
    onsets = np.sort(rng.uniform(*MC_CASCADE_WINDOW_S, size=n_faults))
    last = float(rng.uniform(*MC_CASCADE_LAST_S))
    factors = rng.uniform(*MC_CASCADE_FACTOR, size=n_faults)
    ends = [*onsets[1:], onsets[-1] + last] if n_faults else []
    cascade = tuple(
        (float(t0), float(t1 - t0), float(k))
        for t0, t1, k in zip(onsets, ends, factors, strict=True)
    )
    return dataclasses.replace(base, onset_shift_s=0.0, cascade=cascade)


def stress_of(spec: Any, nominal_radius_m: float) -> float:
    """The amplitude of a fault in its natural unit: radius lost (m), eccentricity (m), ratio."""
    p = spec.params
    if spec.kind == "flat-tire":
        return float(nominal_radius_m - p.to_radius_m)
    if spec.kind == "shaft-bump":
        return float(p.amplitude_m)
    if spec.kind == "slip":
        return float(p.ratio)
    raise EvaluationError(f"fault {spec.kind!r} has no amplitude the evaluation can scale")


def _scaled_fault(
    spec: Any,
    factor: float,
    shift_s: float,
    r0: float,
    source: str,
    duration_s: float | None = None,
) -> Any:

    changes: dict[str, Any] = {"onset_s": max(0.0, spec.params.onset_s + shift_s)}
    if duration_s is not None:
        changes["duration_s"] = duration_s
    if factor != 1.0:
        p = spec.params
        if spec.kind == "flat-tire":
            changes["to_radius_m"] = r0 - factor * (r0 - p.to_radius_m)
        elif spec.kind == "shaft-bump":
            changes["amplitude_m"] = factor * p.amplitude_m
        elif spec.kind == "slip":
            changes["ratio"] = factor * p.ratio
        else:
            raise EvaluationError(f"{source}: fault {spec.kind!r} has no amplitude to scale")
    return FaultSpec(
        spec.kind, params_mod.replace(spec.params, changes, source=source, prefix="faults")
    )


def _merge(base: Mapping[str, Any], extra: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in extra.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def apply_variation(scenario: Any, var: Variation) -> Any:
    """The scenario as the run sees it: faults scaled and shifted, bench and start changed."""

    source = f"{scenario.path} (evaluation variation {var.tag()})"
    bench_cfg = load_bench_config(scenario.bench, source=str(scenario.path), prefix="bench")
    r0 = bench_cfg.chair.wheel_radius_m
    faults = scenario.faults
    if var.only_fault is not None:
        if not 0 <= var.only_fault < len(faults):
            raise EvaluationError(f"{source}: no fault number {var.only_fault + 1}")
        faults = (faults[var.only_fault],)
    if var.amplitude_factor == 0.0:
        faults = ()
    if var.cascade is not None:
        if len(var.cascade) != len(faults):
            raise EvaluationError(
                f"{source}: {len(var.cascade)} random fault times for {len(faults)} faults"
            )
        faults = tuple(
            _scaled_fault(f, k, t0 - f.params.onset_s, r0, source, duration_s=dur)
            for f, (t0, dur, k) in zip(faults, var.cascade, strict=True)
        )
    else:
        faults = tuple(
            _scaled_fault(f, var.amplitude_factor, var.onset_shift_s, r0, source) for f in faults
        )
    bench = dict(scenario.bench)
    if var.mass_factor != 1.0:
        chair = bench_cfg.chair
        bench = _merge(
            bench,
            {
                "chair": {
                    "mass_kg": chair.mass_kg * var.mass_factor,
                    "yaw_inertia_kgm2": chair.yaw_inertia_kgm2 * var.mass_factor,
                }
            },
        )
    if var.noise_factor != 1.0:
        loc = bench_cfg.localizer
        bench = _merge(
            bench,
            {
                "localizer": {
                    "sigma_xy_m": loc.sigma_xy_m * var.noise_factor,
                    "sigma_heading_rad": loc.sigma_heading_rad * var.noise_factor,
                }
            },
        )
    load_bench_config(bench, source=source, prefix="bench")  # fail here, naming the variation
    offset = tuple(
        a + b for a, b in zip(scenario.params.initial_offset, var.initial_offset, strict=True)
    )
    sp = params_mod.replace(
        scenario.params, {"initial_offset": list(offset)}, source=source, prefix="scenario"
    )
    return dataclasses.replace(scenario, params=sp, bench=bench, faults=faults)
