"""dbc.runtime.forked.ForkedWriter: items in order, failures named, and a log closed even when the
loop that wrote it dies."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from dbc.runtime.forked import ForkedWriter, ForkedWriterError


class _FileSink:
    """Appends every item to a JSON-lines file; ``close`` returns how many it wrote."""

    def __init__(self, path: Path, fail_on: object = None) -> None:
        self.fh = path.open("w")
        self.n = 0
        self.fail_on = fail_on

    def take(self, items: list[object]) -> None:
        for item in items:
            if item == self.fail_on:
                raise ValueError(f"cannot write {item!r}")
            self.fh.write(json.dumps(item) + "\n")
            self.n += 1

    def close(self) -> int:
        self.fh.close()
        return self.n


def _lines(path: Path) -> list[object]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_items_reach_the_sink_in_order_and_stop_returns_its_result(tmp_path: Path) -> None:
    w = ForkedWriter("test log", lambda: _FileSink(tmp_path / "log"), batch=7)
    w.start()
    for i in range(50):
        w.put(i)
    assert w.stop() == 50
    assert _lines(tmp_path / "log") == list(range(50))


def test_a_sink_that_fails_is_reported_by_stop_with_the_logs_name(tmp_path: Path) -> None:
    w = ForkedWriter("test log", lambda: _FileSink(tmp_path / "log", fail_on=3), batch=2)
    w.start()
    for i in range(10):
        w.put(i)  # never raises in the loop
    with pytest.raises(ForkedWriterError, match=r"test log failed: ValueError: cannot write 3"):
        w.stop()
    assert _lines(tmp_path / "log") == [0, 1, 2]  # what was written stays


def test_a_sink_that_cannot_open_fails_at_start(tmp_path: Path) -> None:
    w = ForkedWriter("test log", lambda: _FileSink(tmp_path / "no-such-dir" / "log"))
    with pytest.raises(ForkedWriterError, match=r"test log: FileNotFoundError.*no-such-dir"):
        w.start()


def test_when_the_loop_dies_the_writer_closes_the_log_with_what_it_got(tmp_path: Path) -> None:
    w = ForkedWriter("test log", lambda: _FileSink(tmp_path / "log"), batch=1)
    w.start()
    for i in range(5):
        w.put(i)
    pid = w.pid
    assert pid is not None
    assert w._conn is not None
    w._conn.close()  # what the writer sees when the loop's process is killed
    deadline = time.monotonic() + 30
    while os.waitpid(pid, os.WNOHANG) == (0, 0):
        assert time.monotonic() < deadline, "the writer did not end"
        time.sleep(0.01)
    assert _lines(tmp_path / "log") == [0, 1, 2, 3, 4]


class _GatedSink(_FileSink):
    """A writer that is behind: it takes nothing until the file ``gate`` exists."""

    def __init__(self, path: Path, gate: Path) -> None:
        super().__init__(path)
        self.gate = gate

    def take(self, items: list[object]) -> None:
        while not self.gate.exists():
            time.sleep(0.01)
        super().take(items)


def test_in_real_time_a_writer_that_is_behind_never_blocks_the_loop_and_drops_are_counted(
    tmp_path: Path,
) -> None:
    """Shipping from a thread: with the child stalled, a loop that writes far more than the
    pipe and the queue hold goes on (it would block on the pipe otherwise); the newest
    batches beyond the queue are dropped and counted (``stop`` says so), and what was queued
    reaches the sink in order once the child catches up."""
    from dbc.runtime.forked import QUEUED_BATCHES_MAX

    gate = tmp_path / "gate"
    w = ForkedWriter("test log", lambda: _GatedSink(tmp_path / "log", gate), batch=4)
    w.start()
    w.ship_from_thread()
    total = 4 * (QUEUED_BATCHES_MAX + 2000)
    for i in range(total):
        w.put(i)  # returns: the loop is not held by the stalled child
    assert w.dropped > 0
    gate.touch()
    with pytest.raises(ForkedWriterError, match=rf"{w.dropped} item\(s\) dropped"):
        w.stop()  # the log is partial: said, not a quiet success
    got = _lines(tmp_path / "log")
    assert len(got) + w.dropped == total and w.lost == 0
    assert got == sorted(got) and got[: 4 * QUEUED_BATCHES_MAX] == list(
        range(4 * QUEUED_BATCHES_MAX)
    )


def test_in_real_time_a_writer_that_takes_nothing_is_ended_at_stop_and_named(
    tmp_path: Path,
) -> None:
    """A child that never reads holds the shipping thread in a full pipe: ``stop`` waits
    ``close_timeout_s`` for it, then kills the child and raises, instead of hanging."""
    w = ForkedWriter(
        "test log",
        lambda: _GatedSink(tmp_path / "log", tmp_path / "never"),
        batch=4,
        close_timeout_s=1.0,
    )
    w.start()
    w.ship_from_thread()
    for _ in range(4 * 200):  # 800 kB: far more than the pipe holds
        w.put("x" * 1000)
    with pytest.raises(ForkedWriterError, match="took nothing for 1 s"):
        w.stop()
