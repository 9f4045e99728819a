"""The fault-injection suite (docs/safety.md): every case meets its stated criteria.

Each case runs bench and controller in lock-step on the virtual bus (simulation time,
deterministic); the cases live in ``tools.safety.cases``, their criteria in
``tools.safety.criteria``, so that
``wheelchair-hil safety-report`` prints exactly what these tests check.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from tools.cli import main
from tools.safety import cases as sc
from tools.safety import criteria

# make test starts the heaviest files first (tests/conftest.py)
pytestmark = pytest.mark.heavy(seconds=55)


@pytest.mark.parametrize("case", sc.CASES, ids=[c.name for c in sc.CASES])
def test_fault_case_meets_its_criteria(case: sc.SafetyCase) -> None:
    res = criteria.evaluate(case)
    assert res.passed, "\n".join(res.failures)
    if case.expect == sc.STOP:
        assert res.detection_s is not None and res.stop_distance_m is not None
        assert res.no_resume


def test_every_fault_the_issue_names_has_a_case() -> None:
    wanted = {
        "SIGKILL": "controller-sigkill",
        "SIGSTOP": "controller-sigstop",
        "frozen, last frame repeated": "frozen-last-frame-repeated",
        "random loss 1 %": "loss-random-1pct",
        "random loss 10 %": "loss-random-10pct",
        "random loss 30 %": "loss-random-30pct",
        "burst loss N-1": "loss-burst-9-periods",
        "burst loss N": "loss-burst-10-periods",
        "delay beyond N": "delay-15-periods",
        "duplication": "duplication",
        "reordering across the wrap": "reordering",
        "1 flipped bit": "corrupt-1-bit",
        "2 flipped bits": "corrupt-2-bits",
        "3 flipped bits": "corrupt-3-bits",
        "wrong node": "wrong-node",
        "babbling node": "babbling-node-saturating",
        "bus-off": "bus-off-host",
        "drive drops out": "drive-drops-out",
        "drive reboots": "drive-reboots",
        "stuck encoder": "stuck-encoder",
        "NaN setpoint": "law-nan",
        "infinite setpoint": "law-inf",
        "out-of-range setpoint": "law-out-of-range",
        "truncated and oversized frames": "bad-length-frames",
        "non-neutral start": "non-neutral-start",
        "overrun 2": "overrun-2-periods",
        "overrun 5": "overrun-5-periods",
        "overrun 50": "overrun-50-periods",
        "recorder crash": "recorder-crash",
        "fuzz": "fuzz-all-ids",
        "wall-clock jump": "wall-clock-jump",
    }
    missing = {k: v for k, v in wanted.items() if v not in sc.CASES_BY_NAME}
    assert not missing


def test_a_chair_without_watchdogs_fails_the_suite() -> None:
    """The criteria can fail: the same kill with every drive-side monitor switched off."""
    case = dataclasses.replace(
        sc.CASES_BY_NAME["controller-sigkill"],
        controller={"drives": {"watchdog_timeout_ms": 0, "host_timeout_ms": 0}},
    )
    res = criteria.evaluate(case)
    assert not res.passed
    assert any("no stop happened" in f for f in res.failures)


def test_same_deceleration_on_both_wheels_would_fail_the_yaw_criterion() -> None:
    """Plain ODrive setpoints carry no stop reference: each drive ramps at Stop_Decel from
    its own speed, the wheels stop at different times and the chair yaws."""
    case = dataclasses.replace(
        sc.CASES_BY_NAME["controller-sigkill"], controller={"drives": {"require_auth": False}}
    )
    res = criteria.evaluate(case)
    assert res.dw_excess_radps is not None and res.dw_limit_radps is not None
    assert res.dw_excess_radps > 3 * res.dw_limit_radps
    assert any("curvature-keeping" in f for f in res.failures)


def test_the_safety_report_prints_the_cases_and_writes_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "safety.json"
    code = main(
        [
            "safety-report",
            "--case",
            "controller-sigkill",
            "--case",
            "duplication",
            "--json",
            str(out),
        ]
    )
    captured = capsys.readouterr()
    text = captured.out
    assert code == 0
    assert "controller-sigkill" in text and "duplication" in text and "2/2 cases" in text
    assert max(len(line) for line in text.splitlines()) <= 120
    # progress on stderr, a line per case (stderr is not a terminal here), none on stdout
    progress = [ln for ln in captured.err.splitlines() if ln.startswith("safety-report: ")]
    # each with the count, the time so far (and left, before the last) and the case's verdict
    assert [(ln.split(", ")[0], ln.rsplit("; ", 1)[1]) for ln in progress] == [
        ("safety-report: 1/2 cases (50 %)", "controller-sigkill: pass"),
        ("safety-report: 2/2 cases (100 %)", "duplication: pass"),
    ]
    assert " elapsed, about " in progress[0] and " left" not in progress[1]
    assert "safety-report: " not in text
    data = json.loads(out.read_text())
    kill = next(c for c in data["cases"] if c["name"] == "controller-sigkill")
    assert kill["passed"] and kill["detection_s"] <= kill["detection_limit_s"]
    assert kill["stop_distance_m"] <= kill["stop_distance_limit_m"]


def test_an_unknown_case_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["safety-report", "--case", "no-such-case"]) == 2
    assert "unknown safety case(s) no-such-case" in capsys.readouterr().err
