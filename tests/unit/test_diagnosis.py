"""The filter bank identifies each fault from encoder positions and noisy pose fixes.

A synthetic chair (exact kinematics at 1 ms, wheel radii per fault) drives a winding path
with the nominal wheel speeds; the bank gets its encoder positions at 100 Hz and pose
fixes with the localizer's noise at 10 Hz, as the controller does.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest

from controller.config import GeometryParams
from controller.diagnosis import FaultBank
from controller.estimation import Estimation
from controller.types import Pose
from dbc.codec import Hypothesis, Node, PoseFix

R0 = 0.30
B = 0.28
TWO_PI = 2.0 * math.pi
#: rho(side, t_s, theta): rolling radius of a wheel at time t and wheel angle theta
Radius = Callable[[str, float, float], float]


def nominal(_side: str, _t: float, _theta: float) -> float:
    return R0


def flat(side: str, onset: float, to: float = 0.26, tau: float = 2.0, end: float = 1e9) -> Radius:
    def rho(s: str, t: float, _theta: float) -> float:
        if s != side or t < onset or t >= end:
            return R0
        return to + (R0 - to) * math.exp(-(t - onset) / tau)

    return rho


def bump(side: str, onset: float, a: float = 0.015) -> Radius:
    start: dict[str, float] = {}

    def rho(s: str, t: float, theta: float) -> float:
        if s != side or t < onset:
            return R0
        th0 = start.setdefault(s, theta)
        return R0 + a * math.sin(theta - th0)

    return rho


def slip(onset: float, ratio: float = 0.1, end: float = 1e9) -> Radius:
    def rho(_s: str, t: float, _theta: float) -> float:
        return R0 * (1.0 - ratio) if onset <= t < end else R0

    return rho


@dataclass
class Trace:
    t: np.ndarray  # fix times, s
    hyp: np.ndarray  # most likely hypothesis after each fix
    p: np.ndarray  # its probability
    bank: FaultBank


def simulate(rho: Radius, seconds: float, *, seed: int = 1, rest_until: float = 1.0) -> Trace:
    """Drive the synthetic chair and feed the bank like the controller does."""
    rng = random.Random(seed)
    x = y = phi = 0.0
    th = {"left": 0.0, "right": 0.0}
    bank = FaultBank(B, R0, pose=Pose(0.0, 0.0, 0.0))
    bank.predict(0.0, 0.0)
    ts, hyps, ps = [], [], []
    dt = 0.001
    for k in range(1, round(seconds / dt) + 1):
        t = k * dt
        moving = t > rest_until
        v = 0.8 * min(1.0, (t - rest_until) / 2.0) if moving else 0.0
        w = 0.4 * math.sin(0.25 * t) if moving else 0.0
        ds = {}
        for side, sgn in (("left", -1.0), ("right", 1.0)):
            dth = (v + sgn * B * w) / R0 * dt
            ds[side] = rho(side, t, th[side]) * dth
            th[side] += dth
        dphi = (ds["right"] - ds["left"]) / (2 * B)
        d = 0.5 * (ds["right"] + ds["left"])
        x += d * math.cos(phi + 0.5 * dphi)
        y += d * math.sin(phi + 0.5 * dphi)
        phi += dphi
        if k % 10 == 0:
            bank.predict(th["left"] / TWO_PI, th["right"] / TWO_PI)
        if k % 100 == 0:
            h = math.atan2(math.sin(phi), math.cos(phi))
            bank.correct(
                x + rng.gauss(0, 0.02),
                y + rng.gauss(0, 0.02),
                math.remainder(h + rng.gauss(0, 0.01), TWO_PI),
            )
            d_ = bank.diagnosis()
            ts.append(t)
            hyps.append(int(d_.hypothesis))
            ps.append(d_.probability)
    return Trace(np.array(ts), np.array(hyps), np.array(ps), bank)


def confirmed_from(tr: Trace, hyp: Hypothesis, t0: float, t1: float = math.inf) -> float | None:
    """Time from t0 until ``hyp`` stays on top with p >= 0.9 up to t1 (None if it never does)."""
    idx = np.flatnonzero((tr.t >= t0) & (tr.t < t1))
    ok = (tr.hyp[idx] == int(hyp)) & (tr.p[idx] >= 0.9)
    if not ok[-1]:
        return None
    bad = np.flatnonzero(~ok)
    first = idx[bad[-1] + 1] if bad.size else idx[0]
    return float(tr.t[first] - t0)


def test_without_a_fault_the_nominal_hypothesis_stays_on_top() -> None:
    tr = simulate(nominal, 60.0)
    assert (tr.hyp == int(Hypothesis.NOMINAL)).all()
    assert tr.p[-1] > 0.9
    assert tr.bank.radii() == (R0, R0)


@pytest.mark.parametrize(
    ("rho", "expected"),
    [
        (flat("left", 20.0), Hypothesis.FLAT_LEFT),
        (flat("right", 20.0), Hypothesis.FLAT_RIGHT),
        (bump("left", 20.0), Hypothesis.BUMP_LEFT),
        (bump("right", 20.0), Hypothesis.BUMP_RIGHT),
        (slip(20.0), Hypothesis.SLIP),
    ],
    ids=["flat-left", "flat-right", "bump-left", "bump-right", "slip"],
)
def test_each_fault_is_identified_within_five_seconds_of_its_onset(
    rho: Radius, expected: Hypothesis
) -> None:
    tr = simulate(rho, 45.0)
    before = tr.t < 20.0
    assert (tr.hyp[before] == int(Hypothesis.NOMINAL)).all()  # no false alarm
    delay = confirmed_from(tr, expected, 20.0)
    assert delay is not None and delay <= 5.0


def test_the_bank_estimates_the_flat_tires_radius_and_feeds_it_as_the_radius() -> None:
    tr = simulate(flat("right", 10.0, to=0.265), 30.0)
    rl, rr = tr.bank.radii()
    assert rl == R0
    assert rr == pytest.approx(0.265, abs=0.004)
    assert tr.bank.parameters()["flat-right"][0] == pytest.approx(0.265, abs=0.004)


def test_the_bank_estimates_slip_and_the_bump_amplitude() -> None:
    tr = simulate(slip(10.0, ratio=0.15), 30.0)
    rl, rr = tr.bank.radii()
    assert rl == rr == pytest.approx(R0 * 0.85, abs=0.005)
    tr = simulate(bump("left", 10.0, a=0.015), 30.0)
    a, b = tr.bank.parameters()["bump-left"]
    assert math.hypot(a, b) == pytest.approx(0.015, abs=0.003)
    assert tr.bank.radii() == (R0, R0)  # on average the eccentric wheel rolls on r0


def test_the_bank_returns_to_nominal_after_a_fault_clears() -> None:
    tr = simulate(slip(10.0, ratio=0.1, end=20.0), 35.0)
    assert confirmed_from(tr, Hypothesis.SLIP, 10.0, 20.0) is not None
    back = confirmed_from(tr, Hypothesis.NOMINAL, 20.0)
    assert back is not None and back <= 5.0


def test_probabilities_do_not_move_at_rest_and_outliers_are_ignored() -> None:
    bank = FaultBank(B, R0, pose=Pose(1.0, 2.0, 0.3))
    bank.predict(5.0, 5.0)
    rng = random.Random(3)
    for _ in range(50):
        bank.predict(5.0, 5.0)
        assert bank.correct(1.0 + rng.gauss(0, 0.02), 2.0 + rng.gauss(0, 0.02), 0.3)
    assert np.allclose(bank.prob, bank.prior)
    before = bank.prob.copy()
    assert not bank.correct(11.0, 2.0, 0.3)  # 10 m off: no hypothesis explains it
    assert bank.fixes_outlier == 1
    assert np.array_equal(bank.prob, before)


def test_non_finite_input_is_counted_and_ignored() -> None:
    bank = FaultBank(B, R0)
    assert not bank.predict(math.nan, 0.0)
    assert not bank.correct(0.0, math.inf, 0.0)
    assert bank.nonfinite_count == 2
    d = bank.diagnosis()
    assert d.hypothesis == Hypothesis.NOMINAL and math.isfinite(d.probability)


def test_a_jump_of_the_encoder_position_is_not_integrated() -> None:
    bank = FaultBank(B, R0)
    bank.predict(0.0, 0.0)
    bank.predict(100.0, 100.0)  # a drive rebooted: its position restarted elsewhere
    bank.correct(0.0, 0.0, 0.0)
    assert all(abs(f.x[0]) < 1e-9 for f in bank.filters)


def test_estimation_feeds_the_diagnosed_radii_into_odometry() -> None:
    """The loop's Estimation: after a diagnosed flat left tire, odometry uses its radius."""
    geo = GeometryParams()
    est = Estimation(geo, Pose(0.0, 0.0, 0.0))
    drives = {n: SimpleNamespace(pos_rev=0.0, encoder_msgs=0) for n in (Node.LEFT, Node.RIGHT)}
    link = SimpleNamespace(drives=drives)
    rho = flat("left", 3.0, tau=0.5)
    rng = random.Random(5)
    x = y = phi = 0.0
    th = {"left": 0.0, "right": 0.0}
    for k in range(1, 2501):  # 25 s at 100 Hz, the controller's tick
        t = k * 0.01
        v, w = 0.6, 0.2 * math.sin(0.3 * t)
        ds = {}
        for side, sgn in (("left", -1.0), ("right", 1.0)):
            dth = (v + sgn * B * w) / R0 * 0.01
            ds[side] = rho(side, t, th[side]) * dth
            th[side] += dth
            d = drives[Node.LEFT if side == "left" else Node.RIGHT]
            d.pos_rev = th[side] / TWO_PI
            d.encoder_msgs += 1
        dphi = (ds["right"] - ds["left"]) / (2 * B)
        dd = 0.5 * (ds["right"] + ds["left"])
        x += dd * math.cos(phi + 0.5 * dphi)
        y += dd * math.sin(phi + 0.5 * dphi)
        phi += dphi
        est.update(link, round(t * 1e9))  # type: ignore[arg-type]
        if k % 10 == 0:
            fix = PoseFix(x + rng.gauss(0, 0.02), y + rng.gauss(0, 0.02), phi + rng.gauss(0, 0.01))
            est.fuse_fix(fix, initialise=False)
    d = est.diagnosis
    assert d.hypothesis == Hypothesis.FLAT_LEFT and d.probability > 0.9
    assert est.odometry.r_left_m == pytest.approx(0.26, abs=0.004)
    assert est.odometry.r_right_m == R0
    frame = est.diagnosis_frame()
    assert frame.hypothesis == Hypothesis.FLAT_LEFT
    assert frame.radius_left_m == pytest.approx(0.26, abs=0.004)
    rec = est.diagnosis_record()
    assert rec["hypothesis"] == "flat-left" and set(rec["p"]) >= {"none", "flat-left", "slip"}


def _series(events: list[tuple[float, int, int, int, int]], diag: list[tuple[float, int, float]]):
    """A decoded bus log with Bench_Fault_Event (t, id, type, side, state) and Host_Diagnosis."""
    from tools.metrics import BusSeries

    ev = np.array(events, dtype=float).reshape(-1, 5)
    dg = np.array(diag, dtype=float).reshape(-1, 3)
    return BusSeries(
        {
            "Bench_Fault_Event": {
                "t": (ev[:, 0] * 1e9).astype(np.int64),
                "Fault_Id": ev[:, 1].astype(int),
                "Fault_Type": ev[:, 2].astype(int),
                "Side": ev[:, 3].astype(int),
                "Fault_State": ev[:, 4].astype(int),
            },
            "Host_Diagnosis": {
                "t": np.round(dg[:, 0] * 1e9).astype(np.int64),
                "Hypothesis": dg[:, 1].astype(int),
                "Probability": dg[:, 2],
            },
        },
        {},
        {},
    )


def test_the_summary_measures_delay_identification_and_false_alarms() -> None:
    from tools.diagnosis_metrics import diagnosis_summary

    # flat right (type 1, side 2) from 10 s to 20 s; slip (type 3, both) from 30 s on
    events = [(10.0, 1, 1, 2, 1), (20.0, 1, 1, 2, 0), (30.0, 2, 3, 3, 1)]
    diag = []
    for k in range(400):
        t = k * 0.1
        if t < 5.0:
            h, p = 0, 0.95
        elif t < 5.5:
            h, p = 5, 0.6  # a false alarm (on top, whatever its probability)
        elif t < 12.0:
            h, p = 0, 0.9
        elif t < 12.5:
            h, p = 2, 0.95
        elif t < 13.0:
            h, p = 2, 0.85  # dips below 0.9: detection counts from after the dip
        elif t < 20.0:
            h, p = 2, 0.99
        elif t < 33.0:
            h, p = 0, 0.99  # the recovery after 20 s is not fault-free time until 25 s
        else:
            h, p = 5, 0.97
        diag.append((t, h, p))
    s = diagnosis_summary(_series(events, diag))
    assert s["injected"] == "flat-right+slip"
    assert s["identified"] == "flat-right+slip"
    flat, slip_ = s["faults"]
    assert flat["detection_delay_s"] == pytest.approx(3.0)
    assert slip_["detection_delay_s"] == pytest.approx(3.0)
    assert s["detection_delay_s"] == pytest.approx(3.0)
    # fault-free: [0, 10) and [25, 30): 150 samples, 5 with SLIP on top
    assert s["false_alarm_fraction"] == pytest.approx(5 / 150)


def test_a_fault_the_bank_never_confirms_is_reported_as_missed() -> None:
    from tools.diagnosis_metrics import diagnosis_summary

    events = [(5.0, 1, 2, 1, 1)]  # bump left from 5 s, never cleared
    diag = [(k * 0.1, 0 if k < 80 else 1, 0.95) for k in range(150)]  # flat-left instead
    s = diagnosis_summary(_series(events, diag))
    assert s["injected"] == "bump-left"
    assert s["identified"] == "flat-left"
    assert s["detection_delay_s"] is None
    assert s["false_alarm_fraction"] == 0.0
