"""The command line's own behaviour: --version, a closed pipe, help text, metavars, names."""

from __future__ import annotations

import argparse
import fcntl
import os
import re
import subprocess
import sys

import pytest

from tools.cli import COMMANDS, build_parser, main, plain, version
from tools.cli.evaluate import add_arguments as evaluate_arguments
from tools.cli.options import controller_name


def _help(command: str) -> str:
    parser = build_parser([command])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[command].format_help()


def test_version_prints_the_installed_distributions_version(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.split() == ["wheelchair-hil", version()]
    assert re.fullmatch(r"\d+\.\d+\.\d+.*", version())


def test_output_into_a_closed_pipe_ends_quietly_with_the_sigpipe_status() -> None:
    # a one-page pipe and a reader that takes 100 bytes: `params` prints 45 kB, so whatever
    # the timing, most of it is still to write when the reader has gone (into a 64 KiB pipe
    # it could all be written before the close, and the command end with 0)
    r, w = os.pipe()
    fcntl.fcntl(w, fcntl.F_SETPIPE_SZ, 4096)
    proc = subprocess.Popen(
        [sys.executable, "-m", "tools.cli", "params"],
        stdout=w,
        stderr=subprocess.PIPE,
        text=True,
    )
    os.close(w)
    assert proc.stderr is not None
    assert os.read(r, 100)  # what `head -c 100` reads, then it goes away
    os.close(r)
    err = proc.stderr.read()
    assert proc.wait(timeout=60) == 141
    assert "Traceback" not in err and "BrokenPipe" not in err, err


def test_params_headers_name_the_file_and_its_table(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["params"]) == 0
    headers = [ln for ln in capsys.readouterr().out.splitlines() if ln and not ln.startswith(" ")]
    assert "<scenario>.toml [scenario]" in headers
    assert "controller/gains.toml [antifragile]" in headers
    assert "controller/controller.toml" in headers
    assert not [h for h in headers if h.startswith("[") or "[[" in h or "]]" in h], headers


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_help_shows_no_restructuredtext_markup(command: str) -> None:
    text = _help(command)
    assert "``" not in text and not re.search(r":[a-z]+:`", text), text


def test_plain_turns_literals_and_roles_into_text() -> None:
    assert plain("``replay --bus`` see :func:`tools.x.y` or :mod:`~a.b`") == (
        "replay --bus see tools.x.y or a.b"
    )


def test_inject_metavars_name_a_unit_or_the_parameter() -> None:
    text = _help("inject")
    assert not re.search(r"--[a-z-]+ 1\b", text), text
    assert "--gain GAIN" in text and "--to-radius M" in text and "--delay MS" in text
    assert "--fault-duration S" in text and "--wait S" in text


def test_controller_names_on_the_command_line_are_case_insensitive() -> None:
    assert controller_name("ANTIFRAGILE") == "antifragile"
    p = argparse.ArgumentParser()
    evaluate_arguments(p)
    args = p.parse_args(["--out", "x", "--controllers", "ANTIFRAGILE, Robust"])
    assert args.controllers == ("antifragile", "robust")
    run = build_parser(["run"]).parse_args(
        ["run", "--scenario", "short", "--out", "x", "--controller", "ANTIFRAGILE"]
    )
    assert run.controller == "antifragile"


def test_the_scenario_directory_option_is_taken_before_and_after_the_command() -> None:
    before = build_parser(["run"]).parse_args(
        ["--scenario-dir", "/a", "run", "--scenario", "s", "--out", "o"]
    )
    after = build_parser(["run"]).parse_args(
        ["run", "--scenario", "s", "--out", "o", "--scenario-dir", "/b"]
    )
    neither = build_parser(["run"]).parse_args(["run", "--scenario", "s", "--out", "o"])
    assert (before.scenario_dir, after.scenario_dir, neither.scenario_dir) == ("/a", "/b", None)


@pytest.mark.parametrize(
    "command", ["run", "sim", "control", "record", "doctor", "replay", "inject"]
)
def test_every_command_that_opens_a_bus_takes_python_cans_flags(command: str) -> None:
    """python-can's ``-i/--interface``, ``-c`` and ``-b`` (can.logger, can.player) beside the
    stack's own names, and any interface python-can has (pcan is not refused by argparse)."""
    extra = {"run": ["--scenario", "s", "--out", "o"], "sim": ["--scenario", "s"],
             "control": ["--scenario", "s"], "record": ["--out", "o"], "doctor": [],
             "replay": ["run.mcap"], "inject": ["flat-tire"]}  # fmt: skip
    p = build_parser([command])
    for flags in (["-i", "pcan", "-c", "PCAN_USBBUS1", "-b", "250000"],
                  ["--interface", "pcan", "--channel", "PCAN_USBBUS1", "--bitrate", "250000"],
                  ["--bus", "pcan", "--channel", "PCAN_USBBUS1", "--bitrate", "250000"]):  # fmt: skip
        try:
            args = p.parse_args([command, *flags, *extra[command]])
        except SystemExit as err:  # a command whose other arguments differ: say which
            raise AssertionError(f"{command} {' '.join(flags)}: refused ({err})") from None
        assert (args.bus, args.channel, args.bitrate) == ("pcan", "PCAN_USBBUS1", 250000)
