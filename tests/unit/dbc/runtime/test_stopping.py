"""The stop signals' handling in one process (dbc.runtime.stopping); across processes and at
every moment of a part's life: tests/hil/test_stop_signals.py."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading

import pytest

from dbc.runtime import stopping
from tools import cli


def _sentinel(signum: int, frame: object) -> None:  # pragma: no cover - never called
    raise AssertionError("the test's own handler was called")


def test_a_command_run_in_process_gives_the_process_its_handlers_back() -> None:
    old = {s: signal.signal(s, _sentinel) for s in stopping.SIGNALS}
    try:
        assert cli.main(["params"]) == 0
        assert all(signal.getsignal(s) is _sentinel for s in stopping.SIGNALS)
        assert not stopping.STOP.is_set()
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def test_a_child_started_after_an_in_process_command_still_dies_of_sigterm() -> None:
    # the program's own seal (ignored signals) must not leak into a longer-lived process:
    # an ignored disposition is inherited across exec, and run's parts could not be stopped
    assert cli.main(["params"]) == 0
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        child.send_signal(signal.SIGTERM)
        assert child.wait(30) == -signal.SIGTERM
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()


def test_a_stop_signal_only_sets_the_stop_event_however_many_come() -> None:
    with stopping.handled() as stop:
        for _ in range(200):
            os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.is_set()
        assert stopping.received() == ["SIGTERM", "SIGINT"]  # the first and the latest
    assert not stopping.STOP.is_set()


def test_a_command_without_a_loop_is_interrupted_once() -> None:
    with stopping.handled():
        stopping.raise_on_stop()
        with pytest.raises(stopping.StopRequested) as caught:
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):  # the handler runs between bytecodes
                pass
        assert caught.value.signum == signal.SIGTERM
        os.kill(os.getpid(), signal.SIGTERM)  # a second one no longer raises
        for _ in range(1000):
            pass


def test_a_signal_held_back_by_blocked_is_handled_when_the_block_ends() -> None:
    # blocked() holds the signals back in this thread (what a child started meanwhile
    # inherits); a signal for this thread waits until the block ends
    with stopping.handled() as stop:
        with stopping.blocked():
            signal.pthread_kill(threading.get_ident(), signal.SIGTERM)
            assert not stop.is_set()
        for _ in range(1000):  # the handler runs between bytecodes
            pass
        assert stop.is_set()


def test_signal_at_names_the_moment_and_the_signal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(stopping.SIGNAL_AT_ENV, "ready, flush:INT")
    assert stopping._planned() == {"ready": signal.SIGTERM, "flush": signal.SIGINT}
