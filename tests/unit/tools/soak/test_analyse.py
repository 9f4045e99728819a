"""The soak's verdict on small synthetic inputs: an unexplained stop, an uncounted loss, a
wheel moving after a stop and memory growth each fail it; their explained, counted or
harmless counterparts do not."""

from __future__ import annotations

from typing import Any

from tools.soak import analyse
from tools.soak.analyse import LogView

S = 1_000_000_000  # ns per s
STEP = 10_000_000  # a 10 ms Bench_Step


def _steps(t0_s: float, t1_s: float, skip: tuple[float, float] | None = None) -> list[int]:
    out = list(range(int(t0_s * S), int(t1_s * S), STEP))
    if skip is not None:
        out = [t for t in out if not skip[0] * S <= t < skip[1] * S]
    return out


def _tracking_then(t_stop_s: float, state: str, reason: str) -> LogView:
    hb = [(k * S // 10, "TRACKING", "NONE") for k in range(10, int(t_stop_s * 10))]
    hb.append((int(t_stop_s * S), state, reason))
    hb += [(int(t_stop_s * S) + k * S // 10, "FAULT", reason) for k in range(1, 30)]
    return LogView("run.mcap", steps_ns=_steps(0, t_stop_s + 4), heartbeats=hb)


LEG = {"index": 1, "dir": "leg-01", "start_sim_s": 0.5, "end_sim_s": None}


def _fault(kind: str, at_s: float, duration_s: float) -> dict[str, Any]:
    return {
        "action": "fault",
        "kind": kind,
        "at_s": at_s,
        "done_sim_s": at_s,
        "duration_s": duration_s,
        "ok": True,
        "params": {},
    }


def test_a_stop_no_event_explains_fails_the_soak() -> None:
    view = _tracking_then(50.0, "SAFE_STOP", "OFF_PATH")
    stops = analyse.leg_stops([LEG], [view], [], auth=True)
    assert [(s.reason, s.explained) for s in stops] == [("OFF_PATH", False)]
    failures = analyse.judge(stops, [], [], [])
    assert failures and "unexplained stop" in failures[0]


def test_a_stop_during_a_fault_that_can_cause_it_is_explained() -> None:
    view = _tracking_then(50.0, "SAFE_STOP", "OFF_PATH")
    events = [_fault("localizer-bias", 44.0, 4.0)]  # ended 2 s before: within the grace
    stops = analyse.leg_stops([LEG], [view], events, auth=True)
    assert stops[0].explained, stops[0].evidence
    assert analyse.judge(stops, [], [], []) == []


def test_a_fault_that_cannot_cause_the_reason_explains_nothing() -> None:
    view = _tracking_then(50.0, "SAFE_STOP", "NON_FINITE")
    stops = analyse.leg_stops([LEG], [view], [_fault("dead-motor", 49.0, 5.0)], auth=True)
    assert not stops[0].explained


def test_an_attack_explains_nothing_with_authentication_on() -> None:
    view = _tracking_then(30.0, "SAFE_STOP", "DISOBEYED")
    attack = {"action": "attack", "kind": "forge-both", "at_s": 29.0, "duration_s": 3.5}
    assert not analyse.leg_stops([LEG], [view], [attack], auth=True)[0].explained
    assert analyse.leg_stops([LEG], [view], [attack], auth=False)[0].explained


def test_a_staleness_stop_is_explained_by_a_pause_of_the_feedback_in_the_log() -> None:
    view = _tracking_then(40.0, "SAFE_STOP", "ENCODER_STALE")
    assert not analyse.leg_stops([LEG], [view], [], auth=True)[0].explained
    view.gaps.append((int(39.9 * S), 45.0, "encoder feedback of LEFT"))
    stop = analyse.leg_stops([LEG], [view], [], auth=True)[0]
    assert stop.explained and "paused 45 ms" in stop.evidence[0]


def test_a_silent_host_after_its_sigterm_is_an_explained_stop() -> None:
    hb = [(k * S // 10, "TRACKING", "NONE") for k in range(10, 200)]
    view = LogView("run.mcap", steps_ns=_steps(0, 30), heartbeats=hb)
    term = {"action": "signal", "kind": "control-term", "at_s": 19.0, "done_sim_s": 19.0}
    stops = analyse.leg_stops([LEG], [view], [term], auth=True)
    assert [(s.reason, s.explained) for s in stops] == [("HOST_SILENT", True)]


def test_steps_missing_from_a_log_that_its_recorder_did_not_count_fail_the_soak() -> None:
    view = LogView("rec-01/run.mcap", steps_ns=_steps(0, 20, skip=(10.0, 10.05)))
    stats = {"rx_dropped": 0, "missed_steps": 0}
    rec: dict[str, Any] = {"name": "record-1", "stats": stats}
    _lost, uncounted = analyse.losses([rec], [view], {"rx_dropped": 0}, [])
    assert uncounted and "5 Bench_Step periods missing" in uncounted[0]
    assert analyse.judge([], uncounted, [], [])
    stats["missed_steps"] = 5
    assert analyse.losses([rec], [view], {"rx_dropped": 0}, [])[1] == []


def test_a_killed_recorders_gap_is_counted_as_its_downtime_not_lost_silently() -> None:
    first = LogView("rec-01/run.mcap", steps_ns=_steps(0, 10))
    second = LogView("rec-02/run.mcap", steps_ns=_steps(11, 20))
    recs: list[dict[str, Any]] = [
        {"name": "record-1", "stats": None, "signalled": "SIGKILL"},
        {"name": "record-2", "stats": {"rx_dropped": 0, "missed_steps": 0}},
    ]
    lost, uncounted = analyse.losses(recs, [first, second], {"rx_dropped": 0}, [])
    assert uncounted == []
    assert lost["record-2"]["steps_while_down_before"] == 100


def test_a_part_without_statistics_is_an_uncounted_loss() -> None:
    _lost, uncounted = analyse.losses([], [], None, [{"name": "control-3", "stats": None}])
    assert len(uncounted) == 2


def test_a_wheel_moving_after_a_stop_fails_the_soak() -> None:
    view = _tracking_then(10.0, "SAFE_STOP", "DISOBEYED")
    legs = [LEG, {"index": 2, "dir": "leg-02", "start_sim_s": 20.0}]
    stops = analyse.leg_stops(legs[:1], [view], [_fault("torque-loss", 9.0, 3.0)], auth=True)
    view.moving = [(int(11.0 * S), 0.5), (int(25.0 * S), 0.8)]  # ramping; next controller
    assert analyse.moving_after_stops(stops, legs, [view]) == []
    view.moving.append((int(14.0 * S), 0.2))
    moved = analyse.moving_after_stops(stops, legs, [view])
    assert moved and "0.200 m/s" in moved[0]
    assert analyse.judge(stops, [], moved, [])


def _rss(name: str, mib_per_min: float, seconds: int, base_mib: float = 100.0) -> list[Any]:
    return [
        (float(t), float(t), name, int((base_mib + mib_per_min * t / 60.0) * 1024))
        for t in range(seconds)
    ]


def test_memory_growing_fails_the_soak() -> None:
    _mem, failures = analyse.memory(_rss("sim", 5.0, 180))
    assert failures and "sim: memory grew" in failures[0]
    assert analyse.judge([], [], [], failures)


def test_growth_spread_over_restarted_processes_adds_up() -> None:
    # each recorder lives 80 s and grows 2 MiB/min: none alone grows 4 MiB after its warm-up,
    # the six together show the growth
    rss: list[Any] = []
    for k in range(6):
        rss += [(t + 100.0 * k, s, f"record-{k}", v) for t, s, _n, v in _rss("x", 2.0, 80)]
    one = analyse.memory([r for r in rss if r[2] == "record-0"])
    assert one[1] == []
    mem, failures = analyse.memory(rss)
    assert failures and "record: memory grew 2.00 MiB/min" in failures[0]
    assert mem["record"]["judged_processes"] == 6


def test_flat_memory_and_a_single_allocator_step_pass() -> None:
    mem, failures = analyse.memory(_rss("sim", 0.0, 180))
    assert failures == [] and mem["sim"]["growth_mib_per_min"] == 0.0
    step = [(t, s, n, k + (1024 if t > 90 else 0)) for t, s, n, k in _rss("record-1", 0.0, 180)]
    assert analyse.memory(step)[1] == []


def test_a_part_too_short_to_judge_is_reported_not_judged() -> None:
    mem, failures = analyse.memory(_rss("control-1", 20.0, 50))
    assert failures == []
    assert mem["control"]["growth_mib_per_min"] is None
    assert mem["control"]["rss_mib_per_minute"]


def test_a_controller_that_crashed_is_an_unexplained_stop_naming_its_error() -> None:
    leg = {**LEG, "end_sim_s": 3.0, "exit_code": 1, "stats": None, "said": "NameError: x"}
    view = LogView("run.mcap", steps_ns=_steps(0, 10))
    (stop,) = analyse.leg_stops([leg], [view], [], auth=True)
    assert (stop.reason, stop.explained) == ("EXIT_1", False)
    assert "NameError: x" in stop.source


def test_a_sigterm_explains_only_the_stop_of_the_controller_it_was_sent_to() -> None:
    view = _tracking_then(21.0, "SAFE_STOP", "ARMING_TIMEOUT")
    term = {"action": "signal", "kind": "control-term", "at_s": 19.0, "done_sim_s": 19.0}
    leg2 = {**LEG, "index": 2}
    assert not analyse.leg_stops([leg2], [view], [{**term, "target": "control-1"}], auth=True)[
        0
    ].explained
    assert analyse.leg_stops([leg2], [view], [{**term, "target": "control-2"}], auth=True)[
        0
    ].explained


def test_a_contract_mismatch_is_explained_by_a_corrupting_bus_only() -> None:
    # a drive's contract-hash answer with a bit flipped refuses the arming, as it must
    view = _tracking_then(50.0, "FAULT", "CONTRACT_MISMATCH")
    corrupt = analyse.leg_stops([LEG], [view], [_fault("bus-corrupt", 48.0, 4.0)], auth=True)
    assert corrupt[0].explained, corrupt[0].evidence
    drop = analyse.leg_stops([LEG], [view], [_fault("bus-drop", 48.0, 4.0)], auth=True)
    assert not drop[0].explained


def test_a_signal_whose_process_had_ended_is_moot_not_undone() -> None:
    ended = {"action": "signal", "kind": "control-term", "ok": False}
    assert analyse.is_moot({**ended, "detail": "control-76 had already ended"})
    assert analyse.is_moot({**ended, "detail": "no control running"})
    assert not analyse.is_moot({**ended, "detail": "the bench had ended"})
    assert not analyse.is_moot({"action": "fault", "ok": False, "detail": "no bench"})
