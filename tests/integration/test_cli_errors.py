"""Bad input fails with one line naming the file, key or limit, a non-zero exit, and nothing left running.

The commands run in this process (:func:`tools.cli.main`, the program's own path after
its signal set-up): a program would spend its first 3 s importing the stack for an error
found in milliseconds.  The parts' refusal of ``udp_multicast`` runs the program itself.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.cli import run_cli as _run


def _program(*args: str) -> subprocess.CompletedProcess[str]:
    """``wheelchair-hil ARGS`` as a program."""
    return subprocess.run(
        [sys.executable, "-m", "tools.cli", *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def _one_error_line(res: subprocess.CompletedProcess[str]) -> str:
    assert res.returncode == 2, (res.returncode, res.stderr)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("wheelchair-hil: error:")]
    assert len(errors) == 1, res.stderr
    assert "Traceback" not in res.stderr
    return errors[0]


def _scenario(tmp_path: Path, body: str) -> Path:
    p = tmp_path / "bad.toml"
    p.write_text(body)
    return p


def test_unknown_scenario_key_is_named(tmp_path: Path) -> None:
    p = _scenario(tmp_path, '[scenario]\nroute = "short"\nspeeed = 3\n')
    line = _one_error_line(
        _run("run", "--scenario", str(p), "--bus", "virtual", "--out", str(tmp_path / "o"))
    )
    assert f"{p}: unknown key 'scenario.speeed'" in line


def test_out_of_range_scenario_value_names_key_and_bound(tmp_path: Path) -> None:
    p = _scenario(tmp_path, '[scenario]\nroute = "short"\ntail_s = -4.0\n')
    line = _one_error_line(
        _run("run", "--scenario", str(p), "--bus", "virtual", "--out", str(tmp_path / "o"))
    )
    assert "scenario.tail_s = -4.0 is below its minimum 0.0 (s)" in line


def test_unknown_table_is_named(tmp_path: Path) -> None:
    p = _scenario(tmp_path, '[scenario]\nroute = "short"\n[plant]\nmass_kg = 100\n')
    line = _one_error_line(
        _run("run", "--scenario", str(p), "--bus", "virtual", "--out", str(tmp_path / "o"))
    )
    assert "unknown table [plant]" in line


def test_out_of_range_bench_override_is_named(tmp_path: Path) -> None:
    p = _scenario(tmp_path, '[scenario]\nroute = "short"\n[bench.chair]\nmass_kg = 900.0\n')
    line = _one_error_line(
        _run("run", "--scenario", str(p), "--bus", "virtual", "--out", str(tmp_path / "o"))
    )
    assert "mass_kg = 900.0 is above its maximum" in line


def test_missing_dbc_is_named(tmp_path: Path) -> None:
    line = _one_error_line(
        _run(
            "run",
            "--scenario",
            "short",
            "--bus",
            "virtual",
            "--dbc",
            str(tmp_path / "none.dbc"),
            "--out",
            str(tmp_path / "o"),
        )
    )
    assert "none.dbc: DBC file not found" in line


def test_unknown_controller_lists_the_known_ones(tmp_path: Path) -> None:
    line = _one_error_line(
        _run(
            "run",
            "--scenario",
            "short",
            "--bus",
            "virtual",
            "--controller",
            "pid",
            "--out",
            str(tmp_path / "o"),
        )
    )
    assert (
        "unknown controller 'pid'; choose one of baseline, antifragile, robust, adaptive, resilient"
        in line
    )


def test_unknown_scenario_lists_the_known_ones(tmp_path: Path) -> None:
    line = _one_error_line(
        _run("run", "--scenario", "nowhere", "--bus", "virtual", "--out", str(tmp_path / "o"))
    )
    assert "unknown scenario 'nowhere'" in line and "fault-free" in line


def test_unreachable_bus_is_named(tmp_path: Path) -> None:
    line = _one_error_line(
        _run(
            "run",
            "--scenario",
            "short",
            "--bus",
            "socketcan",
            "--channel",
            "nosuchcan0",
            "--out",
            str(tmp_path / "o"),
        )
    )
    assert "nosuchcan0" in line


@pytest.mark.parametrize("part", ["sim", "control"])
def test_parts_refuse_udp_multicast_outside_a_private_namespace(tmp_path: Path, part: str) -> None:
    from tools.bus import transport

    if transport.in_private_namespace():
        pytest.skip("this test process already runs in a private namespace")
    line = _one_error_line(
        _program(part, "--scenario", "short", "--bus", "udp_multicast", "--duration", "1")
    )
    assert "refusing udp_multicast" in line and "--allow-network-multicast" in line


@pytest.mark.parametrize(
    ("override", "words"),
    [
        ('"chair.wheel_radius_m" = 0.0', "wheel_radius_m = 0.0 is below its minimum"),
        ('"chair.mass_kg" = -130.0', "mass_kg = -130.0 is below its minimum"),
        ('"chair.mass_kg" = nan', "mass_kg = nan is not finite"),
        ('"chair.mass_kg" = "heavy"', "mass_kg must be a number"),
    ],
)
def test_an_implausible_bench_override_is_refused_before_anything_starts(
    tmp_path: Path, override: str, words: str
) -> None:
    p = _scenario(tmp_path, f'[scenario]\nroute = "short"\n[bench]\n{override}\n')
    out = tmp_path / "o"
    res = _run("run", "--scenario", str(p), "--bus", "virtual", "--out", str(out))
    assert words in _one_error_line(res)
    assert not out.exists()  # no process was started, no file written


def test_out_naming_a_file_is_one_line_with_the_path_and_the_os_reason(tmp_path: Path) -> None:
    f = tmp_path / "a-file"
    f.write_text("x")
    res = _run("run", "--scenario", "short", "--bus", "virtual", "--out", str(f))
    assert res.returncode == 1
    assert "Traceback" not in res.stderr
    assert f"{f}: EEXIST" in res.stderr


@pytest.mark.parametrize("command", ["run", "evaluate"])
def test_a_seed_outside_the_scenarios_bounds_is_refused_on_the_command_line(
    tmp_path: Path, command: str
) -> None:
    extra = ["--scenario", "short", "--bus", "virtual"] if command == "run" else []
    line = _one_error_line(
        _run(command, *extra, "--seed", "99999999999", "--out", str(tmp_path / "o"))
    )
    assert "--seed 99999999999 is outside [0, 2147483647]" in line
    assert not list((tmp_path / "o").rglob("*.mcap"))  # refused before any run


def test_a_scenario_directory_that_is_not_one_is_named(tmp_path: Path) -> None:
    line = _one_error_line(
        _run("--scenario-dir", str(tmp_path / "nope"), "run", "--scenario", "short", "--out", "o")
    )
    assert f"--scenario-dir {tmp_path / 'nope'}: not a directory" in line


def test_an_unknown_name_says_it_looked_in_the_scenario_directory_first(tmp_path: Path) -> None:
    line = _one_error_line(
        _run(
            "run",
            "--scenario",
            "mine",
            "--scenario-dir",
            str(tmp_path),
            "--bus",
            "virtual",
            "--out",
            "o",
        )
    )
    assert f"looked in {tmp_path.resolve()}, " in line and "fault-free" in line


def test_a_run_that_would_enter_a_private_namespace_refuses_bad_input_in_one_line(
    tmp_path: Path,
) -> None:
    # the program re-executes itself in the namespace before it validates: the error is the
    # inner run's, one line, and nothing is written
    out = tmp_path / "o"
    res = _program("run", "--scenario", "no-such-scenario", "--out", str(out))
    assert "unknown scenario 'no-such-scenario'" in _one_error_line(res)
    assert not out.exists()
