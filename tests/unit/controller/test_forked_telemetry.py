"""The controller's log written by a forked process is the log written in the loop."""

from __future__ import annotations

import logging
import os
import signal
from pathlib import Path
from typing import Any

import pytest

from controller import telemetry as telemetry_mod
from controller.telemetry import ForkedTelemetry, McapTelemetry, open_telemetry
from dbc.runtime.forked import ForkedWriterError
from tests.unit.controller.test_recorder_telemetry import MS, _ticks
from tools.logs.mcap_io import iter_messages


def _write(tel: Any, lockstep: bool) -> None:
    _ticks(tel, lockstep)
    tel.log("/controller/extra", 25 * MS, {"a": 1.5})
    tel.metadata("controller_stats", {"ticks": "3"})
    tel.attach("gains.toml", b"k = 1\n")
    tel.close()


def _content(path: Path) -> list[tuple[str, int, int, bytes]]:
    """Every message but the loop channel's tick durations (perf counter), in log order."""
    return [
        (ch.topic, m.log_time, m.publish_time, b"" if ch.topic == "/controller/loop" else m.data)
        for ch, m in iter_messages(path)
    ]


@pytest.mark.parametrize("lockstep", [True, False])
def test_the_forked_writer_writes_what_the_loop_would(
    tmp_path: Path, lockstep: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    wall = iter(range(10**18, 2 * 10**18, 1_000_003))  # the same wall clock for both logs
    monkeypatch.setattr(telemetry_mod.time, "time_ns", lambda: next(wall))
    _write(McapTelemetry(tmp_path / "loop.mcap", pose_every=2), lockstep)
    wall = iter(range(10**18, 2 * 10**18, 1_000_003))
    forked = ForkedTelemetry(tmp_path / "forked.mcap", pose_every=2, batch=3)
    _write(forked, lockstep)
    here, there = _content(tmp_path / "loop.mcap"), _content(tmp_path / "forked.mcap")
    assert len(here) > 25
    assert there == here  # real time too: offsets and publish times are the loop's
    assert forked.writer.lost == 0
    from mcap.reader import make_reader

    with (tmp_path / "forked.mcap").open("rb") as fh:
        reader = make_reader(fh)
        assert [a.name for a in reader.iter_attachments()] == ["gains.toml"]
        assert [m.name for m in reader.iter_metadata()] == ["controller_stats"]


def test_a_record_changed_after_it_was_logged_is_logged_as_it_was(tmp_path: Path) -> None:
    tel = ForkedTelemetry(tmp_path / "c.mcap", batch=100)
    rec = {"a": 1.0}
    tel.log("/controller/x", 0, rec)
    rec["a"] = 2.0  # the batch has not been shipped yet
    tel.close()
    import json

    data = [json.loads(m.data) for ch, m in iter_messages(tmp_path / "c.mcap")]
    assert data == [{"a": 1.0}]


def test_a_writer_that_dies_costs_records_not_an_exception_in_the_loop(tmp_path: Path) -> None:
    tel = ForkedTelemetry(tmp_path / "c.mcap", batch=1)
    tel.log("/controller/x", 0, {"a": 1.0})
    pid = tel.writer.pid
    assert pid is not None
    os.kill(pid, signal.SIGKILL)
    os.waitpid(pid, 0)
    for k in range(20):
        tel.log("/controller/x", k * MS, {"a": float(k)})  # must not raise
    assert tel.writer.lost >= 1
    with pytest.raises(ForkedWriterError, match=r"telemetry .*c\.mcap failed.*not written"):
        tel.close()


def test_where_no_writer_can_be_forked_the_log_is_written_in_the_loop(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def refuse(self: Any) -> None:
        raise ForkedWriterError("cannot fork a writer here: test")

    monkeypatch.setattr(telemetry_mod.ForkedWriter, "start", refuse)
    with caplog.at_level(logging.WARNING):
        tel = open_telemetry(tmp_path / "c.mcap")
    assert isinstance(tel, McapTelemetry)
    assert "cannot fork a writer here" in caplog.text
    tel.close()


def test_a_log_that_cannot_be_opened_fails_at_start_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(ForkedWriterError, match="missing-dir"):
        ForkedTelemetry(tmp_path / "missing-dir" / "c.mcap")


def test_a_controller_run_that_fails_still_closes_its_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from controller.node import ControllerNode
    from tools.bus.transport import resolve
    from tools.run import parts
    from tools.run import scenario as scenario_mod
    from tools.run.plan import make_plan

    started: list[ForkedTelemetry] = []
    original = parts.open_telemetry

    def watched(path: Path) -> Any:
        tel = original(path)
        started.append(tel)
        return tel

    def broken(self: ControllerNode) -> None:
        self.telemetry.log("/controller/x", 0, {"a": 1.0})
        raise RuntimeError("loop broke")

    monkeypatch.setattr(parts, "open_telemetry", watched)
    monkeypatch.setattr(ControllerNode, "run", broken)
    plan = make_plan(scenario_mod.load("short"), "baseline", realtime=False)
    with pytest.raises(RuntimeError, match="loop broke"):
        parts.run_controller(resolve("virtual", "forked-tel-fail"), plan, out_dir=tmp_path)
    (tel,) = started
    assert isinstance(tel, ForkedTelemetry)
    pid = tel.writer.pid
    assert pid is not None
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # already reaped: the writer has finished
    topics = [ch.topic for ch, _m in iter_messages(tmp_path / "controller.mcap")]
    assert topics == ["/controller/x"]  # closed with what the loop had logged
