"""ISO 2631-1 whole-body vibration frequency weighting and the comfort figures built on it.

This module owns the weighting filters of ISO 2631-1:1997 Annex A and the quantities the
planner and the evaluation compute with them:

* ``Wd`` for the horizontal axes (x fore-aft, y lateral) and ``Wk`` for the vertical axis (z)
  of a seated person, each the product of the standard's band-limiting high-pass (f1, Q1=1/√2)
  and low-pass (f2, Q2=1/√2), the acceleration-velocity transition
  ``(1 + p/ω3) / (1 + p/(Q4 ω4) + p²/ω4²)`` and the upward step
  ``(1 + p/(Q5 ω5) + p²/ω5²) / (1 + p/(Q6 ω6) + p²/ω6²) · (ω5/ω6)²``;
* their discretization: every section is transformed with the bilinear transform after
  pre-warping its own corner frequency (so each corner lands exactly where the standard puts
  it), as second-order sections.  The 100 Hz band limit is dropped when it is above 0.45 fs
  (at the 100 Hz control rate it cannot be represented, and below 20 Hz it changes the
  weighting by less than 0.01 %);
* :func:`weighted_rms` (Eq. 1 of the standard), :func:`running_rms` / MTVV (§6.3.3, τ = 1 s)
  and :func:`vector_value` (Eq. 9, ``a_v = sqrt(kx² awx² + ky² awy² + kz² awz²)``).

Pure computation on arrays; used by the planner (comfort bound on the reference) and by the
evaluation (comfort of the measured motion).
"""

from __future__ import annotations

import importlib
import math
import sys
import types
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np


def _scoreatpercentile(*args: Any, **kwargs: Any) -> Any:
    """scipy.stats.scoreatpercentile, imported at its first call (see :func:`_signal`)."""
    stats = importlib.import_module("scipy.stats")
    return stats.scoreatpercentile(*args, **kwargs)


def _signal() -> types.ModuleType:
    """``scipy.signal``, imported without loading ``scipy.stats``.

    Every process that plans a route filters with scipy.signal (the comfort bound), and
    ``import scipy.signal`` imports ``scipy.stats`` for the one function its peak finding takes
    from it, ``scoreatpercentile``: 0.5 of the 0.7 s that the import cost each controller,
    bench and ``run`` process on a 2-core machine.  While scipy.signal is imported,
    ``scipy.stats`` is a stand-in whose ``scoreatpercentile`` loads the real module at its first
    call; then the stand-in is removed, so that ``import scipy.stats`` anywhere else gets the
    real module.  A scipy whose scipy.signal takes more from scipy.stats gets the plain import;
    ``tests/unit/controller/test_comfort.py`` checks the stand-in with the tested scipy.
    """
    loaded = sys.modules.get("scipy.signal")
    if loaded is not None:
        return loaded
    if "scipy.stats" in sys.modules:  # loaded already: nothing to save
        return importlib.import_module("scipy.signal")
    standin = types.ModuleType(
        "scipy.stats",
        "stand-in for scipy.stats while scipy.signal is imported (controller.comfort)",
    )
    standin.scoreatpercentile = _scoreatpercentile  # type: ignore[attr-defined]
    sys.modules["scipy.stats"] = standin
    try:
        return importlib.import_module("scipy.signal")
    except ImportError:  # a scipy that takes more from scipy.stats: the plain import
        sys.modules.pop("scipy.signal", None)
        _drop_standin(standin)
        return importlib.import_module("scipy.signal")
    finally:
        _drop_standin(standin)


def _drop_standin(standin: types.ModuleType) -> None:
    if sys.modules.get("scipy.stats") is standin:
        del sys.modules["scipy.stats"]
    scipy = sys.modules.get("scipy")
    if scipy is not None and scipy.__dict__.get("stats") is standin:
        del scipy.__dict__["stats"]  # ``scipy.stats`` then loads the real one


# scipy.signal is imported in the functions that filter (:func:`_signal`): the planner imports
# this module, and every part of a run starts 0.8 s sooner without it

_Q_BAND = 1.0 / math.sqrt(2.0)
_INF = math.inf

#: Highest usable fraction of the sampling rate for a weighting corner.
MAX_CORNER_FRACTION = 0.45


@dataclass(frozen=True, slots=True)
class Weighting:
    """Corner frequencies (Hz) and quality factors of one ISO 2631-1 weighting (Table A.2).

    ``inf`` marks a section the weighting does not have.
    """

    name: str
    f1_hz: float
    f2_hz: float
    f3_hz: float
    f4_hz: float
    q4: float
    f5_hz: float = _INF
    q5: float = 1.0
    f6_hz: float = _INF
    q6: float = 1.0


WD = Weighting("Wd", 0.4, 100.0, 2.0, 2.0, 0.63)
WK = Weighting("Wk", 0.4, 100.0, 12.5, 12.5, 0.63, 2.37, 0.91, 3.35, 0.91)

#: Weighting per measurement axis for a seated person (ISO 2631-1 Table 1).
AXIS_WEIGHTING: dict[str, Weighting] = {"x": WD, "y": WD, "z": WK}


def weighting_for(axis: str) -> Weighting:
    """The weighting of ``axis`` ("x", "y" or "z")."""
    try:
        return AXIS_WEIGHTING[axis]
    except KeyError as err:
        raise ValueError(f"axis must be one of 'x', 'y', 'z', got {axis!r}") from err


def _sections(
    w: Weighting, warp: Callable[[float], float], band_limit: bool = True
) -> tuple[list[complex], list[complex], float]:
    """Zeros, poles and gain of ``w`` in the Laplace domain.

    Corner frequencies ω (rad/s) are mapped by ``warp`` (identity for the analog definition,
    pre-warping for the bilinear transform); ``band_limit=False`` omits the f2 low-pass.
    """
    zeros: list[complex] = []
    poles: list[complex] = []
    gain = 1.0

    def quad_roots(om: float, q: float) -> list[complex]:
        return [complex(r) for r in np.roots([1.0, om / q, om * om])]

    # high-pass p²/(p² + ω1/Q p + ω1²)
    w1 = warp(2 * math.pi * w.f1_hz)
    zeros += [0j, 0j]
    poles += quad_roots(w1, _Q_BAND)
    # low-pass ω2²/(p² + ω2/Q p + ω2²)
    if band_limit:
        w2 = warp(2 * math.pi * w.f2_hz)
        poles += quad_roots(w2, _Q_BAND)
        gain *= w2 * w2
    # transition (1 + p/ω3)/(1 + p/(Q4 ω4) + p²/ω4²) = (ω4²/ω3)(p + ω3)/(p² + ω4/Q4 p + ω4²)
    if math.isfinite(w.f4_hz):
        w4 = warp(2 * math.pi * w.f4_hz)
        poles += quad_roots(w4, w.q4)
        gain *= w4 * w4
        if math.isfinite(w.f3_hz):
            w3 = warp(2 * math.pi * w.f3_hz)
            zeros.append(complex(-w3))
            gain /= w3
    # upward step, with its (ω5/ω6)² factor the monic ratio (p² + ω5/Q5 p + ω5²)/(p² + ...)
    if math.isfinite(w.f5_hz):
        zeros += quad_roots(warp(2 * math.pi * w.f5_hz), w.q5)
        poles += quad_roots(warp(2 * math.pi * w.f6_hz), w.q6)
    return zeros, poles, gain


def analog_factor(w: Weighting, f_hz: float | np.ndarray) -> np.ndarray:
    """|W(j 2π f)| of the standard's continuous-time definition (the tabulated factors)."""
    signal = _signal()

    z, p, k = _sections(w, lambda om: om)
    f = np.atleast_1d(np.asarray(f_hz, dtype=float))
    _, h = signal.freqs_zpk(z, p, k, worN=2 * np.pi * f)
    return np.abs(h)


@lru_cache(maxsize=64)
def weighting_sos(w: Weighting, fs_hz: float) -> np.ndarray:
    """Second-order sections of ``w`` discretized at ``fs_hz`` (pre-warped bilinear)."""
    signal = _signal()

    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise ValueError(f"sampling rate must be positive and finite, got {fs_hz}")
    nyq_limit = MAX_CORNER_FRACTION * fs_hz

    def warp(om: float) -> float:
        f = om / (2 * math.pi)
        if f >= nyq_limit:
            raise ValueError(
                f"{w.name}: corner {f:g} Hz needs a sampling rate above {f / MAX_CORNER_FRACTION:g}"
                f" Hz, got {fs_hz:g} Hz"
            )
        return 2.0 * fs_hz * math.tan(om / (2.0 * fs_hz))

    z, p, k = _sections(w, warp, band_limit=w.f2_hz < nyq_limit)
    zd, pd, kd = signal.bilinear_zpk(z, p, k, fs_hz)
    return signal.zpk2sos(zd, pd, kd)


def digital_factor(w: Weighting, fs_hz: float, f_hz: float | np.ndarray) -> np.ndarray:
    """|W| of the discretized filter at ``f_hz`` (to check the discretization)."""
    signal = _signal()

    f = np.atleast_1d(np.asarray(f_hz, dtype=float))
    _, h = signal.sosfreqz(weighting_sos(w, float(fs_hz)), worN=f, fs=fs_hz)
    return np.abs(h)


def _as_signal(sig: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(sig, dtype=float)
    if a.ndim != 1:
        raise ValueError(f"{what} must be a 1-D time history, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        bad = int(np.count_nonzero(~np.isfinite(a)))
        raise ValueError(f"{what} has {bad} non-finite samples; clean or interpolate them first")
    return a


def weight(sig: np.ndarray, fs_hz: float, axis: str = "x") -> np.ndarray:
    """The frequency-weighted acceleration time history a_w(t) of ``sig`` (m/s², at rest before)."""
    signal = _signal()

    a = _as_signal(sig, "acceleration")
    sos = weighting_sos(weighting_for(axis), float(fs_hz))
    if a.size == 0:
        return a
    return signal.sosfilt(sos, a)


def weighted_rms(sig: np.ndarray, fs_hz: float, axis: str = "x") -> float:
    """ISO 2631-1 weighted r.m.s. acceleration (m/s²) of ``sig`` sampled at ``fs_hz``.

    The filter starts from rest (zero state), which is exact for a signal that starts at rest,
    and the mean square is taken over the whole signal (the measurement period).
    """
    a = _as_signal(sig, "acceleration")
    if a.size == 0:
        return 0.0
    aw = weight(a, fs_hz, axis)
    return float(np.sqrt(np.mean(aw * aw)))


def running_rms(aw: np.ndarray, fs_hz: float, tau_s: float = 1.0) -> np.ndarray:
    """Running r.m.s. of an already weighted signal (ISO 2631-1 Eq. 2, exponential, τ = 1 s)."""
    signal = _signal()

    a = _as_signal(aw, "weighted acceleration")
    if a.size == 0:
        return a
    alpha = 1.0 / (tau_s * fs_hz)
    ms = signal.lfilter([alpha], [1.0, alpha - 1.0], a * a)
    return np.sqrt(np.maximum(ms, 0.0))


def mtvv(aw: np.ndarray, fs_hz: float, tau_s: float = 1.0) -> float:
    """Maximum transient vibration value: the peak of :func:`running_rms` (m/s²)."""
    r = running_rms(aw, fs_hz, tau_s)
    return float(r.max()) if r.size else 0.0


def vector_value(
    awx: float, awy: float, awz: float = 0.0, *, kx: float = 1.0, ky: float = 1.0, kz: float = 1.0
) -> float:
    """Vibration total value ``sqrt(kx² awx² + ky² awy² + kz² awz²)`` (ISO 2631-1 Eq. 9).

    For comfort of a seated person §8.2 uses k = 1 on every axis; §7.2 (health) uses
    kx = ky = 1.4.
    """
    return math.sqrt((kx * awx) ** 2 + (ky * awy) ** 2 + (kz * awz) ** 2)
