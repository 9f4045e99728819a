"""Lock-step on the virtual bus with the bench and the controller in one thread (the default)
against the same run with each in a thread of its own."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from controller import clock as clock_mod
from tests.integration.conftest import run_stack
from tools.logs.mcap_io import iter_messages


def _log(run_mcap: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) of the decoded frames and the ground truth (no wall-clock field).

    The bench repeats its first ``Bench_Step(0)`` every ``handshake_resend_ms`` of wall time
    until the host answers: how often depends on how soon a host thread gets the CPU, so only
    the first is kept (the run itself is lock-step from the host's first ack)."""
    out = []
    handshake = ("/can/Bench_Step", 0)
    seen = False
    for channel, m in iter_messages(run_mcap):
        if not channel.topic.startswith(("/can/", "/truth/")) or channel.topic == "/can/raw":
            continue
        if (channel.topic, m.log_time) == handshake:
            if seen:
                continue
            seen = True
        out.append((channel.topic, m.log_time, m.data))
    return out


def _controller_log(run_dir: Path) -> list[tuple[str, int, bytes]]:
    """The controller's deterministic channels (the loop channel holds tick durations)."""
    return [
        (channel.topic, m.log_time, m.data)
        for channel, m in iter_messages(run_dir / "run.mcap")
        if channel.topic.startswith(("/controller/reference", "/controller/estimate"))
        or channel.topic in ("/controller/errors", "/controller/command")
    ]


@pytest.mark.parametrize("controller", ["baseline", "antifragile"])
def test_one_thread_runs_exactly_the_run_of_two_threads(tmp_path: Path, controller: str) -> None:
    apart = run_stack(tmp_path / "apart", "short", controller, duration_s=5.0, one_thread=False)
    together = run_stack(tmp_path / "together", "short", controller, duration_s=5.0)
    log = _log(tmp_path / "together" / "run.mcap")
    assert len(log) > 2000
    assert log == _log(tmp_path / "apart" / "run.mcap")  # every frame, time and value
    ctl = _controller_log(tmp_path / "together")
    assert len(ctl) > 1000
    assert ctl == _controller_log(tmp_path / "apart")
    for key in ("rmse_pos_m", "rmse_phie_rad", "frames_total", "deadline_misses"):
        assert together[key] == apart[key], key


def test_a_controller_that_fails_in_one_thread_ends_the_run_with_its_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    original = clock_mod.LockstepClock.tick_done

    def failing(self: clock_mod.LockstepClock, t_ns: int) -> None:
        if t_ns >= 1_000_000_000:
            raise RuntimeError("clock broke at 1 s")
        original(self, t_ns)

    monkeypatch.setattr(clock_mod.LockstepClock, "tick_done", failing)
    with pytest.raises(RuntimeError, match="clock broke at 1 s"):
        run_stack(tmp_path, "short", "baseline", duration_s=20.0)
    bench = json.loads((tmp_path / "bench_stats.json").read_text())
    assert bench["stopped_early"] is True
    assert bench["sim_time_s"] < 2.0  # it stopped at once, not after the bench's ack timeouts
    assert (tmp_path / "controller_stats.json").is_file()  # the controller's results are kept
