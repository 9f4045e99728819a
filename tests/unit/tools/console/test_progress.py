"""Progress on stderr: a bar on a terminal, plain lines elsewhere, nothing when disabled."""

from __future__ import annotations

import io

import pytest

from tools.console.progress import UNKNOWN_TOTAL_EVERY, Progress


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_off_a_terminal_each_step_is_one_plain_line() -> None:
    out = io.StringIO()
    with Progress(3, "safety-report", "case", lines="each", stream=out) as p:
        for name in ("a", "b", "c"):
            p.update(note=f"{name}: pass")
    assert out.getvalue().splitlines() == [
        "safety-report: 1/3 cases (33 %) a: pass",
        "safety-report: 2/3 cases (66 %) b: pass",
        "safety-report: 3/3 cases (100 %) c: pass",
    ]


def test_off_a_terminal_a_long_job_prints_one_line_per_tenth() -> None:
    out = io.StringIO()
    with Progress(1234, "replay", "frame", stream=out) as p:
        for _ in range(1234):
            p.update()
    lines = out.getvalue().splitlines()
    assert [ln.rsplit("(", 1)[1] for ln in lines] == [f"{10 * k} %)" for k in range(1, 11)]
    assert lines[-1] == "replay: 1234/1234 frames (100 %)"
    assert "\r" not in out.getvalue()


def test_updates_of_several_units_at_once_print_one_line() -> None:
    out = io.StringIO()
    p = Progress(10, "x", "step", stream=out)
    p.update(10)
    assert out.getvalue().splitlines() == ["x: 10/10 steps (100 %)"]


def test_an_unknown_total_prints_a_line_every_so_many_units() -> None:
    out = io.StringIO()
    p = Progress(None, "replay", "frame", stream=out)
    for _ in range(2 * UNKNOWN_TOTAL_EVERY + 5):
        p.update()
    assert out.getvalue().splitlines() == [
        f"replay: {UNKNOWN_TOTAL_EVERY} frames",
        f"replay: {2 * UNKNOWN_TOTAL_EVERY} frames",
    ]


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
