"""ISO 2631-1 weighting: tabulated factors, discretization, weighted rms, vector value."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from controller import comfort
from controller.comfort import WD, WK

ROOT = Path(__file__).resolve().parents[3]

# ISO 2631-1:1997 Table 3 (factors x 1000 in the standard), at the nominal band centres
WD_TABLE = {0.5: 0.853, 1.0: 1.011, 2.0: 0.890, 4.0: 0.512, 8.0: 0.253, 16.0: 0.125}
WK_TABLE = {0.5: 0.418, 1.0: 0.482, 2.0: 0.531, 4.0: 0.967, 8.0: 1.036, 16.0: 0.768}


@pytest.mark.parametrize(("w", "table"), [(WD, WD_TABLE), (WK, WK_TABLE)])
def test_analog_weighting_matches_the_standards_table(w, table) -> None:
    f = np.array(list(table))
    np.testing.assert_allclose(comfort.analog_factor(w, f), list(table.values()), rtol=0.01)


@pytest.mark.parametrize(("w", "table"), [(WD, WD_TABLE), (WK, WK_TABLE)])
def test_discretized_weighting_matches_the_table_at_1khz(w, table) -> None:
    f = np.array(list(table))
    np.testing.assert_allclose(
        comfort.digital_factor(w, 1000.0, f), list(table.values()), rtol=0.01
    )


def test_discretized_wd_is_accurate_at_the_100hz_control_rate() -> None:
    # the 100 Hz band limit is dropped there; below 10 Hz the error stays within 2.5 %
    f = np.array([0.5, 1.0, 2.0, 4.0, 8.0])
    np.testing.assert_allclose(
        comfort.digital_factor(WD, 100.0, f), [WD_TABLE[x] for x in f], rtol=0.025
    )


def test_a_1hz_sine_has_weighted_rms_amplitude_over_root2_times_w() -> None:
    fs, amp = 100.0, 0.7
    t = np.arange(0.0, 120.0, 1 / fs)
    a = amp * np.sin(2 * np.pi * 1.0 * t)
    expected = amp / math.sqrt(2) * WD_TABLE[1.0]
    assert comfort.weighted_rms(a, fs, "x") == pytest.approx(expected, rel=0.005)
    assert comfort.weighted_rms(a, fs, "y") == pytest.approx(expected, rel=0.005)
    assert comfort.weighted_rms(a, fs, "z") == pytest.approx(
        amp / math.sqrt(2) * WK_TABLE[1.0], rel=0.005
    )


def test_weighting_removes_a_constant_acceleration() -> None:
    # the band-limiting high-pass: a steady 1 m/s^2 carries no vibration after it settles
    fs = 100.0
    aw = comfort.weight(np.ones(int(60 * fs)), fs, "x")
    assert abs(aw[-int(10 * fs) :]).max() < 1e-3


def test_vector_value_combines_axes_with_their_factors() -> None:
    assert comfort.vector_value(0.3, 0.4) == pytest.approx(0.5)
    assert comfort.vector_value(0.3, 0.4, kx=1.4, ky=1.4) == pytest.approx(0.7)
    assert comfort.vector_value(0.0, 0.0, 0.2) == pytest.approx(0.2)


def test_running_rms_and_mtvv_see_a_transient_the_overall_rms_dilutes() -> None:
    fs = 100.0
    t = np.arange(0.0, 60.0, 1 / fs)
    a = np.where((t > 30) & (t < 32), np.sin(2 * np.pi * 2.0 * t), 0.0)
    aw = comfort.weight(a, fs, "x")
    overall = float(np.sqrt(np.mean(aw**2)))
    peak = comfort.mtvv(aw, fs)
    assert peak > 3 * overall
    assert peak == pytest.approx(WD_TABLE[2.0] / math.sqrt(2), rel=0.15)


def test_bad_inputs_are_clear_errors() -> None:
    with pytest.raises(ValueError, match="axis"):
        comfort.weighted_rms(np.zeros(10), 100.0, "w")
    with pytest.raises(ValueError, match="non-finite"):
        comfort.weighted_rms(np.array([0.0, np.nan]), 100.0)
    with pytest.raises(ValueError, match=r"Wk: corner 12\.5 Hz needs a sampling rate above"):
        comfort.weighted_rms(np.zeros(10), 20.0, "z")
    assert comfort.weighted_rms(np.zeros(0), 100.0) == 0.0
    assert comfort.mtvv(np.zeros(0), 100.0) == 0.0


def test_planning_filters_without_loading_scipy_stats_and_scipy_stats_stays_whole() -> None:
    """controller.comfort imports scipy.signal with scipy.stats stood in (0.5 s of every
    planning process's start); the stand-in's one function gives what the real one gives, and
    ``import scipy.stats`` afterwards is the real module."""
    probe = (
        "import sys, numpy as np\n"
        "from controller import comfort\n"
        "aw = comfort.weight(np.sin(np.arange(500) / 10.0), 100.0, 'x')\n"
        "assert 'scipy.signal' in sys.modules and 'scipy.stats' not in sys.modules\n"
        "import scipy.signal._peak_finding as pf\n"
        "got = pf.scoreatpercentile([1.0, 2.0, 3.0, 4.0], 50)\n"
        "import scipy.stats\n"
        "assert hasattr(scipy.stats, 'norm'), scipy.stats\n"
        "assert got == scipy.stats.scoreatpercentile([1.0, 2.0, 3.0, 4.0], 50) == 2.5\n"
        "print(float(aw.sum()))\n"
    )
    res = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=False, cwd=ROOT
    )
    assert res.returncode == 0, res.stderr
    # the same numbers as with scipy.stats loaded first
    first = probe.replace(
        "from controller import comfort\n",
        "import scipy.stats\nfrom controller import comfort\n",
        1,
    )
    first = first.replace(" and 'scipy.stats' not in sys.modules", "")
    res2 = subprocess.run(
        [sys.executable, "-c", first], capture_output=True, text=True, check=False, cwd=ROOT
    )
    assert res2.returncode == 0, res2.stderr
    assert res.stdout == res2.stdout
