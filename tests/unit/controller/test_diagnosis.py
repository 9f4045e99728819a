"""The filter bank identifies each fault from encoder positions and noisy pose fixes.

A synthetic chair (exact kinematics at 1 ms, wheel radii per fault) drives a winding path
with the nominal wheel speeds; the bank gets its encoder positions at 100 Hz and pose
fixes with the localizer's noise at 10 Hz, as the controller does.
"""

from __future__ import annotations

import dataclasses
import math
import random
from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from controller.config import EstimationParams, GeometryParams
from controller.diagnosis import Diagnosis, DiagnosisParams, FaultBank
from controller.estimation import Estimation
from controller.odometry import arc_step
from controller.types import Pose, wrap_angle
from dbc.codec import DBC_PATH, Codec, HostDiagnosis, Hypothesis, Node, PoseFix

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


def _ride_with_flat_left(est: Estimation) -> None:
    """25 s of a weaving ride, the left tire going flat to 0.26 m from 3 s; 10 Hz fixes."""
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


def test_estimation_feeds_the_diagnosed_radii_into_odometry() -> None:
    """The loop's Estimation: after a diagnosed flat left tire, odometry uses its radius."""
    est = Estimation(GeometryParams(), Pose(0.0, 0.0, 0.0))
    _ride_with_flat_left(est)
    # the EKF's differential scale was rebased with the radii: the diagnosis explains the drift
    assert abs(est.ekf.scale) < 0.03
    d = est.diagnosis
    assert d.hypothesis == Hypothesis.FLAT_LEFT and d.probability > 0.9
    assert est.odometry.r_left_m == pytest.approx(0.26, abs=0.004)
    assert est.odometry.r_right_m == R0
    frame = est.diagnosis_frame()
    assert frame.hypothesis == Hypothesis.FLAT_LEFT
    assert frame.radius_left_m == pytest.approx(0.26, abs=0.004)
    rec = est.diagnosis_record()
    assert rec["hypothesis"] == "flat-left" and set(rec["p"]) >= {"none", "flat-left", "slip"}
    assert rec["wheel_scale"] == est.ekf.scale


def test_new_radii_rebase_the_ekfs_differential_scale() -> None:
    est = Estimation(GeometryParams(), Pose(0.0, 0.0, 0.0))
    est.ekf.rebase_scale(1.0, 0.9)
    d = est.ekf.scale
    r = GeometryParams().wheel_radius_m
    assert est.set_radii(0.95 * r, 1.05 * r)
    assert est.ekf.scale == pytest.approx((1 + d / 2) / 1.05 - (1 - d / 2) / 0.95)
    assert not est.set_radii(-1.0, r)  # refused by odometry: delta untouched
    assert est.ekf.scale == pytest.approx((1 + d / 2) / 1.05 - (1 - d / 2) / 0.95)


def test_without_feedback_the_ekf_learns_the_flat_tires_heading_drift() -> None:
    # the left wheel travels 0.26 / 0.30 = 0.867 of what odometry says: a differential scale
    # delta = 0.133 turns the heading as the tire does
    off = EstimationParams(diagnosis_feedback=False)
    est = Estimation(GeometryParams(), Pose(0.0, 0.0, 0.0), settings=off)
    _ride_with_flat_left(est)
    assert est.odometry.r_left_m == est.odometry.r_right_m  # nothing fed back
    assert est.ekf.scale == pytest.approx(0.133, abs=0.03)
    pose_only = dataclasses.replace(off, wheel_scale_state=False)
    est = Estimation(GeometryParams(), Pose(0.0, 0.0, 0.0), settings=pose_only)
    _ride_with_flat_left(est)
    assert est.ekf.scale == 0.0


def test_the_diagnosis_frame_is_saturated_into_the_contracts_ranges(tmp_path) -> None:
    old = "SG_ Radius_Left_Est : 24|16@1+ (1E-005,0) [0|0.65535]"
    text = DBC_PATH.read_text()
    assert old in text
    path = tmp_path / "narrow.dbc"
    path.write_text(text.replace(old, "SG_ Radius_Left_Est : 24|16@1+ (1E-005,0) [0|0.5]"))
    codec = Codec(path)
    est = Estimation(GeometryParams(), Pose(0.0, 0.0, 0.0), codec=codec)
    est._diagnosis = Diagnosis(Hypothesis.FLAT_LEFT, math.nan, (0.0,) * 6, 0.61, math.inf)
    frame = est.diagnosis_frame()
    assert frame == HostDiagnosis(Hypothesis.FLAT_LEFT, 0.0, 0.5, 0.0)
    codec.encode(frame, Node.HOST)  # inside every range: no EncodeError
    # the project's contract: its own range, 0.65535 m
    est = Estimation(GeometryParams(), Pose(0.0, 0.0, 0.0))
    est._diagnosis = Diagnosis(Hypothesis.FLAT_LEFT, 1.5, (0.0,) * 6, 0.61, 0.7)
    assert est.diagnosis_frame() == HostDiagnosis(Hypothesis.FLAT_LEFT, 1.0, 0.61, 0.65535)


def _series(events: list[tuple[float, int, int, int, int]], diag: list[tuple[float, int, float]]):
    """A decoded bus log with Bench_Fault_Event (t, id, type, side, state) and Host_Diagnosis."""
    from tools.metrics.tracking import BusSeries

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
    from tools.metrics.diagnosis import diagnosis_summary

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
    from tools.metrics.diagnosis import diagnosis_summary

    events = [(5.0, 1, 2, 1, 1)]  # bump left from 5 s, never cleared
    diag = [(k * 0.1, 0 if k < 80 else 1, 0.95) for k in range(150)]  # flat-left instead
    s = diagnosis_summary(_series(events, diag))
    assert s["injected"] == "bump-left"
    assert s["identified"] == "flat-left"
    assert s["detection_delay_s"] is None
    assert s["false_alarm_fraction"] == 0.0


# ------------------------------------------- every step against filterpy and the model


def _scripted_drive() -> list[tuple[str, float, float, float]]:
    """Encoder positions (100 Hz) and fixes (10 Hz) of a chair that rests, drives without a
    fault, then with a flat left tire, a bump on the right wheel, slip, a deflating right tire,
    and rests again; with a non-finite position, a drive reboot (position jump), fixes lost for
    1.5 s, a fix between ticks, outliers and a non-finite fix.  ``("p", left, right, 0)`` is
    an encoder sample (revolutions), ``("c", x, y, heading)`` a fix, ``("P", ...)`` a filter's
    covariance replaced and another's scaled in place (from outside the bank)."""

    def rho(side: str, t: float, theta: float, start: dict[str, float]) -> float:
        if 5.0 <= t < 9.0 and side == "left":
            return 0.26 + 0.04 * math.exp(-(t - 5.0))
        if 9.0 <= t < 13.0 and side == "right":
            return R0 + 0.015 * math.sin(theta - start.setdefault("bump", theta))
        if 13.0 <= t < 17.0:
            return R0 * 0.88
        if t >= 17.0 and side == "right":
            return 0.27
        return R0

    rng = random.Random(11)
    x = y = 0.0
    phi = 3.0  # the heading crosses +-pi
    th = {"left": 0.0, "right": 0.0}
    start: dict[str, float] = {}
    events: list[tuple[str, float, float, float]] = [("p", 0.0, 0.0, 0.0)]
    dt = 0.001
    for k in range(1, 22_001):
        t = k * dt
        moving = 1.0 < t < 20.0
        v = 0.8 * min(1.0, (t - 1.0) / 2.0) if moving else 0.0
        w = 0.5 * math.sin(0.4 * t) if moving else 0.0
        ds = {}
        for side, sgn in (("left", -1.0), ("right", 1.0)):
            dth = (v + sgn * B * w) / R0 * dt
            ds[side] = rho(side, t, th[side], start) * dth
            th[side] += dth
        dphi = (ds["right"] - ds["left"]) / (2 * B)
        d = 0.5 * (ds["right"] + ds["left"])
        x += d * math.cos(phi + 0.5 * dphi)
        y += d * math.sin(phi + 0.5 * dphi)
        phi += dphi
        if k % 10 == 0:
            events.append(("p", th["left"] / TWO_PI, th["right"] / TWO_PI, 0.0))
            if k == 3_210:
                events.append(("p", math.nan, 0.0, 0.0))
            if k == 10_330:  # a drive rebooted: its position restarts elsewhere
                events.append(("p", th["left"] / TWO_PI + 40.0, th["right"] / TWO_PI, 0.0))
        if k % 100 == 0 or k == 6_050:
            if 11_000 <= k < 12_500:
                continue  # fixes lost: the bank flushes every 10 intervals on its own
            h = math.remainder(phi + rng.gauss(0, 0.01), TWO_PI)
            if k == 7_000:
                events.append(("P", 0.0, 0.0, 0.0))
            events.append(("c", x + rng.gauss(0, 0.02), y + rng.gauss(0, 0.02), h))
            if k in (8_000, 21_000):
                events.append(("c", x + 4.0, y - 3.0, h))  # outlier (the second at rest)
            if k == 15_000:
                events.append(("c", x, math.inf, h))
    return events


def _wheel_travel(
    hyp: Hypothesis, par: np.ndarray, th_l: float, dth_l: float, th_r: float, dth_r: float
) -> tuple[float, float]:
    """Ground travel of each wheel under ``hyp`` (the module docstring's table)."""
    nominal_l, nominal_r = R0 * dth_l, R0 * dth_r
    if hyp == Hypothesis.FLAT_LEFT:
        return par[0] * dth_l, nominal_r
    if hyp == Hypothesis.FLAT_RIGHT:
        return nominal_l, par[0] * dth_r
    if hyp == Hypothesis.SLIP:
        return (1.0 - par[0]) * nominal_l, (1.0 - par[0]) * nominal_r
    if hyp in (Hypothesis.BUMP_LEFT, Hypothesis.BUMP_RIGHT):
        a, b = par
        left = hyp == Hypothesis.BUMP_LEFT
        th0, dth = (th_l, dth_l) if left else (th_r, dth_r)
        # int (r0 + a cos theta + b sin theta) dtheta over the interval
        ecc = R0 * dth + a * (math.sin(th0 + dth) - math.sin(th0))
        ecc += b * (math.cos(th0) - math.cos(th0 + dth))
        return (ecc, nominal_r) if left else (nominal_l, ecc)
    return nominal_l, nominal_r


def _motion(
    hyp: Hypothesis, x: np.ndarray, intervals: list[tuple[float, float, float, float]]
) -> tuple[np.ndarray, float, list[tuple[float, float, float]]]:
    """Pose after ``intervals`` (exact arcs), distance, and (heading, ds_l, ds_r) per arc."""
    px, py, phi = x[:3]
    dist = 0.0
    arcs = []
    for th_l, dth_l, th_r, dth_r in intervals:
        dl, dr = _wheel_travel(hyp, x[3:], th_l, dth_l, th_r, dth_r)
        arcs.append((phi, dl, dr))
        px, py, phi, _, _ = arc_step(px, py, phi, dl, dr, B)
        dist += 0.5 * (abs(dl) + abs(dr))
    return np.array([px, py, phi]), dist, arcs


def _projected(hyp: Hypothesis, par: np.ndarray, p: DiagnosisParams) -> np.ndarray:
    """The hypothesis' admissible parameters (module docstring), by projection."""
    par = par.copy()
    if hyp in (Hypothesis.FLAT_LEFT, Hypothesis.FLAT_RIGHT):
        par[0] = min(max(par[0], p.flat_min_radius_m), R0 - p.flat_min_deflection_m)
    elif hyp == Hypothesis.SLIP:
        par[0] = min(max(par[0], p.slip_min_ratio), p.slip_max_ratio)
    elif hyp in (Hypothesis.BUMP_LEFT, Hypothesis.BUMP_RIGHT):
        amp = math.hypot(*par)
        lo, hi = p.bump_min_amplitude_m, p.bump_max_amplitude_m
        if amp < 1e-12:
            par[:] = lo, 0.0
        elif not lo <= amp <= hi:
            par *= min(max(amp, lo), hi) / amp
    return par


def _walk_per_m(hyp: Hypothesis, p: DiagnosisParams) -> float:
    if hyp in (Hypothesis.FLAT_LEFT, Hypothesis.FLAT_RIGHT):
        return p.flat_walk_m2_per_m
    if hyp == Hypothesis.SLIP:
        return p.slip_walk_per_m
    return p.bump_walk_m2_per_m


def _close(actual: np.ndarray, expected: np.ndarray, rel: float) -> None:
    """Equal to ``rel`` of the largest entry of ``expected`` (covariances mix scales)."""
    assert np.shape(actual) == np.shape(expected)
    err = float(np.abs(np.subtract(actual, expected)).max())
    assert err <= rel * float(np.abs(expected).max()), (err, actual, expected)


def _reference_predict(
    f: Any, x: np.ndarray, P: np.ndarray, intervals: list, p: DiagnosisParams
) -> tuple[np.ndarray, np.ndarray]:
    """Check one filter's covariance step against filterpy's predict and the motion model;
    returns the state after it (from the reference)."""
    from filterpy.kalman import ExtendedKalmanFilter

    hyp, n = f.hyp, len(x)
    pose, dist, arcs = _motion(hyp, x, intervals)
    # the mean: exact arcs with the hypothesis' wheel travel; parameters unchanged
    assert np.abs(f.x_prior[:2] - pose[:2]).max() < 1e-12
    assert abs(wrap_angle(f.x_prior[2] - pose[2])) < 1e-12
    assert np.array_equal(f.x_prior[3:], x[3:])
    # F: the Jacobian of that motion (central differences; the filter's is to first order
    # in the heading change of each interval)
    F = np.eye(n)
    for k in range(2, n):
        h = 1e-6 if k == 2 else 1e-7
        dx = np.zeros(n)
        dx[k] = h
        a, _, _ = _motion(hyp, x + dx, intervals)
        b, _, _ = _motion(hyp, x - dx, intervals)
        diff = a - b
        diff[2] = wrap_angle(diff[2])
        F[:3, k] = diff / (2 * h)
    np.testing.assert_allclose(f.F, F, rtol=1e-3, atol=1e-7)
    # Q: each arc's wheel noise (variance per metre of each wheel's travel) through the arc's
    # Jacobian w.r.t. the two wheel travels, plus the parameters' random walk per metre
    Q = np.zeros((n, n))
    for phi, dl, dr in arcs:
        J = np.zeros((3, 2))
        for j, (hl, hr) in enumerate(((1e-9, 0.0), (0.0, 1e-9))):
            a = np.array(arc_step(0.0, 0.0, phi, dl + hl, dr + hr, B)[:3])
            b = np.array(arc_step(0.0, 0.0, phi, dl - hl, dr - hr, B)[:3])
            diff = a - b
            diff[2] = wrap_angle(diff[2])
            J[:, j] = diff / (2e-9)
        Q[:3, :3] += J @ np.diag([abs(dl), abs(dr)]) @ J.T * p.wheel_noise_m2_per_m
    Q[3:, 3:] = np.eye(n - 3) * _walk_per_m(hyp, p) * dist
    _close(f.Q[:3, :3], Q[:3, :3], 1e-4)
    np.testing.assert_allclose(f.Q[3:, 3:], Q[3:, 3:], rtol=1e-12, atol=0)
    # P' = F P F' + Q: filterpy's predict with the filter's F and Q
    ref = ExtendedKalmanFilter(dim_x=n, dim_z=3)
    ref.x, ref.P, ref.F, ref.Q = x.copy(), P.copy(), f.F, f.Q
    x_pred = np.concatenate([pose, x[3:]])
    x_pred[2] = wrap_angle(x_pred[2])

    def predict_x(u: object = 0) -> None:
        ref.x = x_pred.copy()

    ref.predict_x = predict_x
    ref.predict()
    _close(f.P_prior, ref.P_prior, 1e-13)
    return (
        np.concatenate([x_pred[:3], _projected(hyp, x_pred[3:], p)]),
        0.5 * (ref.P + ref.P.T),
    )


def _reference_mix(
    states: list[tuple[np.ndarray, np.ndarray]],
    prob: np.ndarray,
    prior: np.ndarray,
    eps: float,
    prior_cov: list[np.ndarray],
) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """IMM mixing of the pose block (see FaultBank._mix), with loops; returns states and c."""
    n = len(states)
    c = (1.0 - eps) * prob + eps * prior
    if eps <= 0.0:
        return states, c
    out = []
    for j, (xj, Pj) in enumerate(states):
        mu = np.array(
            [((1.0 - eps) * (i == j) + eps * prior[j]) * prob[i] / c[j] for i in range(n)]
        )
        keep = mu[j]
        if keep > 1.0 - 1e-9:
            out.append((xj, Pj))
            continue
        d = np.array([xi[:3] - xj[:3] for xi, _ in states])
        d[:, 2] = [wrap_angle(a) for a in d[:, 2]]
        mean_d = mu @ d
        pc = sum(
            m * (Pi[:3, :3] + np.outer(di - mean_d, di - mean_d))
            for m, (_, Pi), di in zip(mu, states, d, strict=True)
        )
        x = xj.copy()
        x[:3] += mean_d
        x[2] = wrap_angle(x[2])
        P = Pj.copy()
        P[:3, :3] = 0.5 * (pc + pc.T)
        if len(x) > 3:
            P[3:, 3:] = keep * P[3:, 3:] + (1.0 - keep) * prior_cov[j]
            P[:3, 3:] *= math.sqrt(keep)
            P[3:, :3] *= math.sqrt(keep)
            if np.linalg.eigvalsh(P).min() <= 0.0:
                P[:3, 3:] = P[3:, :3] = 0.0
        out.append((x, P))
    return out, c


def test_every_step_of_the_bank_is_filterpys_predict_and_update_and_imm_mixing() -> None:
    """The bank through rest, fault-free driving, each fault, outliers and non-finite input:
    after every call each filter's state is what filterpy's predict (with the model's F, Q
    and mean, checked against the exact arcs) and update give from its state before the
    call, followed by the documented probability update and IMM mixing."""
    from filterpy.kalman import ExtendedKalmanFilter

    p = DiagnosisParams()
    bank = FaultBank(B, R0, p, pose=Pose(0.0, 0.0, 3.0))
    prior = bank.prior.copy()
    prior_cov = [np.diag(f.initial_params()[1]) for f in bank.filters]
    prob, c = prior.copy(), prior.copy()
    R = np.diag([p.fix_pos_std_m**2, p.fix_pos_std_m**2, p.fix_heading_std_rad**2])
    last: tuple[float, float] | None = None
    pending: list[tuple[float, float, float, float]] = []
    travel = 0.0
    seen = {"flush": 0, "fix": 0, "outlier": 0, "mixed": 0}
    for kind, a, b, h in _scripted_drive():
        if kind == "P":
            bank.filters[2].P = bank.filters[2].P * 1.5  # replaced
            bank.filters[4].P *= 1.2  # changed in place
            continue
        pre = [(f.x.copy(), f.P.copy(), f.P_prior) for f in bank.filters]
        intervals = pending
        flush = False
        if kind == "p":
            ret = bank.predict(a, b)
            if not (math.isfinite(a) and math.isfinite(b)):
                assert not ret
                continue
            th = (a * TWO_PI, b * TWO_PI)
            if last is not None and max(abs(th[0] - last[0]), abs(th[1] - last[1])) * R0 <= 0.5:
                pending = [*pending, (last[0], th[0] - last[0], last[1], th[1] - last[1])]
                travel += 0.5 * R0 * (abs(th[0] - last[0]) + abs(th[1] - last[1]))
                assert ret
            else:
                assert not ret
            intervals, last = pending, th
            flush = len(pending) == p.max_pending_intervals
        else:
            ret = bank.correct(a, b, h)
            flush = math.isfinite(b) and bool(pending)
        if flush:
            pending = []
            seen["flush"] += 1
        states = []
        for f, (x, P, P_prior) in zip(bank.filters, pre, strict=True):
            assert (f.P_prior is not P_prior) == flush
            states.append(_reference_predict(f, x, P, intervals, p) if flush else (x, P))
        if kind == "c" and math.isfinite(b):
            refs = []
            for x, P in states:
                n = len(x)
                ref = ExtendedKalmanFilter(dim_x=n, dim_z=3)
                ref.x, ref.P, ref.R = x.copy(), P.copy(), R
                ref.update(
                    np.array([a, b, h]),
                    HJacobian=lambda _x, n=n: np.eye(3, n),
                    Hx=lambda x_: x_[:3],
                    residual=lambda z, zx: np.array(
                        [z[0] - zx[0], z[1] - zx[1], wrap_angle(z[2] - zx[2])]
                    ),
                )
                refs.append(ref)
            if min(r.mahalanobis**2 for r in refs) > p.outlier_chi2:
                assert not ret
                seen["outlier"] += 1
            else:
                assert ret
                seen["fix"] += 1
                ll = np.array([r.log_likelihood for r in refs])
                np.testing.assert_allclose(bank.last_log_likelihoods, ll, rtol=0, atol=1e-9)
                states = []
                for f, ref in zip(bank.filters, refs, strict=True):
                    for name in ("y", "S", "SI", "K"):
                        _close(getattr(f, name), getattr(ref, name), 1e-10)
                    x = ref.x.copy()
                    x[2] = wrap_angle(x[2])
                    x[3:] = _projected(f.hyp, x[3:], p)
                    states.append((x, 0.5 * (ref.P + ref.P.T)))
                if travel >= p.min_travel_m:
                    logp = np.log(np.maximum(c, 1e-300)) + ll
                    post = np.exp(logp - logp.max())
                    prob = post / post.sum()
                    eps = 1.0 - math.exp(-p.switch_rate_per_m * travel)
                    mixed, c = _reference_mix(states, prob, prior, eps, prior_cov)
                    seen["mixed"] += sum(m is not s for m, s in zip(mixed, states, strict=True))
                    states = mixed
                travel = 0.0
        for f, (x, P) in zip(bank.filters, states, strict=True):
            dx = f.x - x
            dx[2] = wrap_angle(dx[2])
            assert np.abs(dx).max() < 1e-9 and -math.pi < f.x[2] <= math.pi, (f.x, x)
            _close(f.P, P, 1e-9)
        assert np.abs(bank.prob - prob).max() < 1e-12, (bank.prob, prob)
        if not (flush or kind == "c"):
            continue
        # the outputs: most likely hypothesis, radii (its own, or the probability-weighted
        # mean below radius_feed_probability), parameters
        d = bank.diagnosis()
        top = int(np.argmax(prob))
        assert d.hypothesis == top and d.probabilities == pytest.approx(tuple(prob), abs=1e-12)
        radii = [bank.filters[i].radii() for i in range(len(prob))]
        if prob[top] < p.radius_feed_probability:
            radii = [tuple(float(w) * np.array(r)) for w, r in zip(prob, radii, strict=True)]
            expected = tuple(np.sum(radii, axis=0))
        else:
            expected = radii[top]
        assert bank.radii() == pytest.approx(expected, abs=1e-12)
        assert (d.radius_left_m, d.radius_right_m) == bank.radii()
        assert bank.parameters() == {
            n: list(f.x[3:])
            for n, f in zip(
                ("none", "flat-left", "flat-right", "bump-left", "bump-right", "slip"),
                bank.filters,
                strict=True,
            )
        }
    assert (bank.fixes_outlier, bank.nonfinite_count, bank.numerical_failures) == (2, 2, 0)
    assert bank.fixes_used == seen["fix"] and seen["outlier"] == 2
    assert seen["flush"] > seen["fix"] and seen["mixed"] > 0


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_a_filter_whose_step_is_not_finite_keeps_its_state() -> None:
    """A covariance step or a fix that is not finite for one filter: that filter keeps its
    state (counted), the others go on."""
    bank = FaultBank(B, R0, DiagnosisParams(switch_rate_per_m=0.0))  # no mixing
    bank.predict(0.0, 0.0)
    for k in range(1, 11):
        bank.predict(0.01 * k, 0.012 * k)
    f = bank.filters[3]
    f.P = f.P.copy()
    f.P[3, 3] = math.inf
    x, P = f.x.copy(), f.P.copy()
    others = [g.x.copy() for g in bank.filters]
    for k in range(11, 21):
        bank.predict(0.01 * k, 0.012 * k)
    assert bank.numerical_failures == 1
    assert not np.isfinite(f.P_prior).all()
    assert np.array_equal(f.x, x) and np.array_equal(f.P, P)
    assert all(g is f or g.x[0] > o[0] for g, o in zip(bank.filters, others, strict=True))
    pose = bank.filters[0].x
    assert bank.correct(float(pose[0]), float(pose[1]), float(pose[2]))
    assert bank.numerical_failures == 2  # the update of that filter is not finite either
    assert np.array_equal(f.x, x) and np.array_equal(f.P, P)
    assert all(np.isfinite(g.P).all() for g in bank.filters if g is not f)


def test_headings_stay_wrapped_when_a_fix_pulls_them_across_pi() -> None:
    bank = FaultBank(B, R0, pose=Pose(1.0, 2.0, math.pi - 1e-4))
    bank.predict(3.0, 3.0)
    bank.predict(3.0, 3.0)  # at rest: no mixing, the update itself is what the filters hold
    assert bank.correct(1.0, 2.0, -math.pi + 1e-4)
    for f in bank.filters:
        assert -math.pi < f.x[2] < -math.pi + 1e-4
