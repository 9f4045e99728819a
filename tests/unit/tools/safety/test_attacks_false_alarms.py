"""``attack --false-alarms N``: counting the plausibility stops of N fault-free runs.

The runs themselves are real-time and cross-process (tests/safety/test_attacks.py); here
``run_attack`` is replaced by one that lays out a run directory the way a repeated run does
(the figures live in ``try<k>/``), so the counting and the exit status are checked alone.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from tools.cli import attack as attack_command
from tools.safety.attacks import analysis, runs


def _args(n: int) -> argparse.Namespace:
    return argparse.Namespace(
        false_alarms=n,
        scenario="fault-free",
        controller="antifragile",
        at=8.0,
        duration=16.0,
        rt_priority=0,
    )


def _fake_runs(monkeypatch: pytest.MonkeyPatch, outcomes: list[tuple[str, float, bool]]) -> None:
    """Each call: a run whose host stopped with ``reason``, ``worst`` rev/s from the bound."""
    calls = iter(outcomes)

    def fake(out: Path, attack: str, **_kw: object) -> analysis.AttackResult:
        reason, worst, valid = next(calls)
        d = out / "try1"  # a second attempt: the first was invalid
        (d / "ctl").mkdir(parents=True)
        stats = {"final_state": "FAULT", "stop_reason": reason, "obey_worst_revps": worst}
        (d / "ctl" / "controller_stats.json").write_text(json.dumps(stats))
        res = analysis.AttackResult(attack, True, run_dir=str(d))
        res.stop_reason, res.obey_worst_revps, res.attempts = reason, worst, 2
        if not valid:
            res.failures.append("invalid run: the host was SAFE_STOP at the onset")
        if reason != "ROUTE_DONE":  # these stopped before the bench's end
            res.detected_s, res.detection = 1.25, "host SAFE_STOP (reason 3)"
        return res

    monkeypatch.setattr(runs, "run_attack", fake)


def test_fault_free_runs_without_a_plausibility_stop_pass(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _fake_runs(monkeypatch, [("ROUTE_DONE", 0.004, True), ("ENCODER_STALE", 0.006, True)])
    assert attack_command.false_alarms(_args(2), tmp_path, [True]) == 0
    out = capsys.readouterr().out
    assert "closest to the plausibility bound 0.0060 rev/s" in out
    assert "stopped 1.25 s after 8 s: host SAFE_STOP (reason 3)" in out
    assert "plausibility stops in 2 fault-free real-time runs: 0" in out
    assert "stopped for any reason before the bench ended: 1" in out


def test_a_disobeyed_stop_in_a_fault_free_run_fails(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _fake_runs(monkeypatch, [("ROUTE_DONE", 0.004, True), ("DISOBEYED", 0.09, True)])
    assert attack_command.false_alarms(_args(2), tmp_path, [True]) == 1
    assert "plausibility stops in 2 fault-free real-time runs: 1" in capsys.readouterr().out


def test_a_run_that_never_tracked_does_not_count_as_clean(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _fake_runs(monkeypatch, [("ENCODER_STALE", 0.0, False)])
    assert attack_command.false_alarms(_args(1), tmp_path, [True]) == 1
    assert "1 of them invalid" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("stats", "why"),
    [
        ({"missed_steps": 0, "rx_dropped": 0, "ended_by": "Bench_End"}, ""),
        ({"missed_steps": 230, "rx_dropped": 0, "ended_by": "Bench_End"}, "230 Bench_Step"),
        ({"missed_steps": 0, "rx_dropped": 5216, "ended_by": "Bench_End"}, "5216 frames dropped"),
        ({"ended_by": "bus silent for 5 s, no Bench_End"}, "no Bench_End"),
    ],
)
def test_a_run_whose_recorder_log_is_not_whole_is_named_so(
    tmp_path: Path, stats: dict[str, object], why: str
) -> None:
    """An attack is judged from the recorder's log; from a remnant it would be judged on
    the frames that happened to survive."""
    path = tmp_path / "recorder_stats.json"
    path.write_text(json.dumps(stats))
    got = analysis.log_incomplete(tmp_path)
    assert (why in got and got) if why else got == ""
    assert "is missing" in analysis.log_incomplete(tmp_path / "absent")


@pytest.mark.parametrize(
    ("part", "stats_file"),
    [("sim", "sim/bench_stats.json"), ("control", "ctl/controller_stats.json")],
)
def test_a_run_in_which_the_bench_or_the_host_lost_frames_is_not_whole(
    tmp_path: Path, part: str, stats_file: str
) -> None:
    """The drives or the host acting on a partial stream: the log is whole, the run is not."""
    (tmp_path / "recorder_stats.json").write_text(json.dumps({"ended_by": "Bench_End"}))
    assert analysis.log_incomplete(tmp_path) == ""  # no bench or host stats: nothing lost
    (tmp_path / stats_file).parent.mkdir(parents=True)
    (tmp_path / stats_file).write_text(json.dumps({"rx_dropped": 12}))
    assert analysis.log_incomplete(tmp_path) == f"{part} lost 12 frames"


@pytest.mark.parametrize("reason", ["ENCODER_STALE", "DRIVE_LOST"])
def test_a_host_starved_of_its_drives_feedback_makes_a_forge_run_invalid_not_failed(
    reason: str,
) -> None:
    res = analysis.AttackResult(
        attack="forge-left", auth=False, host_state_at_onset="TRACKING", stop_reason=reason
    )
    analysis.judge(res)
    assert res.failures and res.failures[0].startswith("invalid run"), res.failures
    assert reason in res.failures[0]


def test_a_forge_run_the_host_stopped_for_anything_else_but_disobeyed_fails() -> None:
    res = analysis.AttackResult(
        attack="forge-left", auth=False, host_state_at_onset="TRACKING", stop_reason="OFF_PATH"
    )
    analysis.judge(res)
    assert res.failures == ["the plausibility check did not stop the chair (OFF_PATH)"]
    ok = analysis.AttackResult(
        attack="forge-left", auth=False, host_state_at_onset="TRACKING", stop_reason="DISOBEYED"
    )
    analysis.judge(ok)
    assert ok.failures == []
    # a drive with another DBC may make its feedback unreadable: stale is no excuse there
    dbc = analysis.AttackResult(
        attack="wrong-dbc", auth=False, host_state_at_onset="TRACKING", stop_reason="ENCODER_STALE"
    )
    analysis.judge(dbc)
    assert dbc.failures and not dbc.failures[0].startswith("invalid run")
