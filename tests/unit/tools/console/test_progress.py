"""Progress on stderr: a bar on a terminal, plain lines elsewhere, nothing when disabled."""

from __future__ import annotations

import io

import pytest

from tools.console.progress import UNKNOWN_TOTAL_EVERY, Progress, duration


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


class _Clock:
    """Synthetic seconds: each reading after the first is ``step`` later."""

    def __init__(self, step: float) -> None:
        self.t, self.step = 0.0, step

    def __call__(self) -> float:
        now = self.t
        self.t += self.step
        return now


def test_off_a_terminal_each_step_is_one_plain_line_with_elapsed_time_and_time_left() -> None:
    out = io.StringIO()
    clock = _Clock(20.0)  # every case takes 20 s
    with Progress(3, "safety-report", "case", lines="each", stream=out, clock=clock) as p:
        for name in ("a", "b", "c"):
            p.update(note=f"{name}: pass")
    assert out.getvalue().splitlines() == [
        "safety-report: 1/3 cases (33 %), 20 s elapsed, about 40 s left; a: pass",
        "safety-report: 2/3 cases (66 %), 40 s elapsed, about 20 s left; b: pass",
        "safety-report: 3/3 cases (100 %), 1 min 00 s elapsed; c: pass",
    ]


def test_off_a_terminal_a_long_job_prints_one_line_per_tenth() -> None:
    out = io.StringIO()
    with Progress(1234, "replay", "frame", stream=out, clock=_Clock(0.0)) as p:
        for _ in range(1234):
            p.update()
    lines = out.getvalue().splitlines()
    assert [ln.split("(")[1].split(")")[0] for ln in lines] == [f"{10 * k} %" for k in range(1, 11)]
    assert lines[-1] == "replay: 1234/1234 frames (100 %), 0 s elapsed"
    assert "\r" not in out.getvalue()


def test_updates_of_several_units_at_once_print_one_line() -> None:
    out = io.StringIO()
    p = Progress(10, "x", "step", stream=out, clock=_Clock(3.0))
    p.update(10)
    assert out.getvalue().splitlines() == ["x: 10/10 steps (100 %), 3 s elapsed"]


def test_an_unknown_total_prints_a_line_every_so_many_units() -> None:
    out = io.StringIO()
    p = Progress(None, "replay", "frame", stream=out, clock=_Clock(90.0))
    for _ in range(2 * UNKNOWN_TOTAL_EVERY + 5):
        p.update()
    assert out.getvalue().splitlines() == [
        f"replay: {UNKNOWN_TOTAL_EVERY} frames, 1 min 30 s elapsed",  # no estimate without a total
        f"replay: {2 * UNKNOWN_TOTAL_EVERY} frames, 3 min 00 s elapsed",
    ]


def test_a_message_off_a_terminal_is_a_plain_line_between_the_progress_lines() -> None:
    out = io.StringIO()
    with Progress(2, "evaluate", "run", lines="each", stream=out, clock=_Clock(0.0)) as p:
        p.write("run a failed: boom")
        p.update()
    assert out.getvalue().splitlines() == [
        "run a failed: boom",
        "evaluate: 1/2 runs (50 %), 0 s elapsed, about 0 s left",
    ]


def test_on_a_terminal_a_message_goes_above_the_bar() -> None:
    out = _Terminal()
    with Progress(2, "evaluate", "run", stream=out) as p:
        p.update()
        p.write("run a failed: boom")
        p.update()
    assert "run a failed: boom\n" in out.getvalue()
    assert "evaluate: 1/2" not in out.getvalue()


@pytest.mark.parametrize(
    ("seconds", "text"),
    [(0.4, "0 s"), (59.4, "59 s"), (65, "1 min 05 s"), (3599, "59 min 59 s"), (3725, "1 h 02 min")],
)
def test_durations_read_as_a_person_would_say_them(seconds: float, text: str) -> None:
    assert duration(seconds) == text


def test_on_a_terminal_it_is_one_bar_redrawn_in_place() -> None:
    out = _Terminal()
    with Progress(5, "safety-report", "case", lines="each", stream=out) as p:
        for _ in range(5):
            p.update(note="ok")
    text = out.getvalue()
    assert "\r" in text and "5/5" in text and "safety-report" in text
    assert "safety-report: 1/5" not in text  # no plain lines on a terminal


@pytest.mark.parametrize("stream", [io.StringIO(), _Terminal()])
def test_disabled_it_writes_nothing(stream: io.StringIO) -> None:
    with Progress(5, "x", "step", enabled=False, stream=stream) as p:
        p.update(5)
    assert stream.getvalue() == ""
