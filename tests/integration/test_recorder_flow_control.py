"""Lock-step flow control: a slow recorder slows the run instead of losing frames.

The recorder thread (``recorder="thread"``) holds the bench back with Bench_Record_Ack;
the forked writer of ``tools.logs.bustap`` (the default) with the pipe it reads from."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from firmware_sim import bench as bench_mod
from tests.integration.conftest import run_stack
from tools.logs import recorder as recorder_mod
from tools.run.parts import RECORDER_WINDOW_STEPS

STEP_NS = 10_000_000


def test_a_slow_recorder_holds_the_bench_within_its_window(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    leads: list[int] = []
    original_await = bench_mod.Bench._await_recorder
    original_record = recorder_mod.FrameLog.record

    def slow_record(self: recorder_mod.FrameLog, msg: object) -> None:
        time.sleep(0.0003)  # a recorder ~15x slower than the stack
        original_record(self, msg)  # type: ignore[arg-type]

    def watched_await(self: bench_mod.Bench, t_ns: int) -> None:
        original_await(self, t_ns)
        leads.append(self.sim.now_ns - self._record_ack_ns)

    monkeypatch.setattr(recorder_mod.FrameLog, "record", slow_record)
    monkeypatch.setattr(bench_mod.Bench, "_await_recorder", watched_await)
    s = run_stack(tmp_path, "short", "baseline", duration_s=6.0, recorder="thread")
    assert s["recorder_missed_steps"] == 0
    # never more than the window (plus the recorder's ack spacing) ahead of the log
    assert max(leads) <= (RECORDER_WINDOW_STEPS + 10) * STEP_NS
    assert max(leads) > 50 * STEP_NS  # the recorder really was behind: the bench had to wait


def test_a_bench_waiting_for_a_recorder_that_never_answers_gives_up_and_finishes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(recorder_mod.BusRecorder, "_acknowledge", lambda self: None)
    from firmware_sim.config import BenchParams

    monkeypatch.setattr(
        BenchParams, "__init__", _with_default(BenchParams.__init__, recorder_timeout_s=0.2)
    )
    s = run_stack(tmp_path, "short", "baseline", duration_s=3.0, recorder="thread")
    bench = (tmp_path / "bench_stats.json").read_text()
    assert '"recorder_lost": true' in bench
    assert s["sim_duration_s"] == pytest.approx(3.0)


def _with_default(init: object, **defaults: object) -> object:
    def patched(self: object, *args: object, **kwargs: object) -> None:
        for k, v in defaults.items():
            kwargs.setdefault(k, v)
        init(self, *args, **kwargs)  # type: ignore[operator]

    return patched


def _messages(run_mcap: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) of every decoded frame and truth message (no wall-clock fields)."""
    from tools.logs.mcap_io import iter_messages

    return [
        (channel.topic, m.log_time, m.data)
        for channel, m in iter_messages(run_mcap)
        if channel.topic != "/can/raw"  # raw frames carry the wall-clock timestamp
        and channel.topic.startswith(("/can/", "/truth/"))
        and "Record_Ack" not in channel.topic
    ]


def test_the_forked_writer_logs_what_the_recorder_thread_logs(tmp_path: Path) -> None:
    a = run_stack(tmp_path / "thread", "short", "baseline", duration_s=4.0, recorder="thread")
    b = run_stack(tmp_path / "process", "short", "baseline", duration_s=4.0)
    thread_msgs = _messages(tmp_path / "thread" / "run.mcap")
    process_msgs = _messages(tmp_path / "process" / "run.mcap")
    assert len(process_msgs) > 1000
    assert process_msgs == thread_msgs  # same frames, same order, same stamps and values
    assert a["rmse_pos_m"] == b["rmse_pos_m"]
    rec = (tmp_path / "process" / "recorder_stats.json").read_text()
    assert '"ended_by": "Bench_End"' in rec


def test_a_slow_forked_writer_slows_the_run_and_loses_no_frame(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    original_record = recorder_mod.FrameLog.record

    def slow_record(self: recorder_mod.FrameLog, msg: object) -> None:
        time.sleep(0.0003)  # the writer is forked after this patch, so it has it too
        original_record(self, msg)  # type: ignore[arg-type]

    monkeypatch.setattr(recorder_mod.FrameLog, "record", slow_record)
    s = run_stack(tmp_path, "short", "baseline", duration_s=3.0)
    import json

    bench = json.loads((tmp_path / "bench_stats.json").read_text())
    ctl = json.loads((tmp_path / "controller_stats.json").read_text())
    rec = json.loads((tmp_path / "recorder_stats.json").read_text())
    acks = rec["by_name"]["Bench_Step_Ack"]  # the controller's clock sends these, not its link
    assert acks == rec["by_name"]["Bench_Step"] > 250  # every step on the log, and its ack
    assert rec["frames"] == bench["frames_sent"] + ctl["link_sent"] + acks
    assert s["frames_total"] == rec["frames"]
    assert s["recorder_missed_steps"] == 0
