"""The systemd unit: what install-service writes, the unit shipped in tools/deploy/templates/, the
command docs/deploy.md documents and the project's own parser all agree; the unit is valid."""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from dbc.runtime.errors import ConfigError
from tools.cli import build_parser
from tools.cli import main as cli_main
from tools.deploy import service
from tools.deploy.service import SHIPPED_UNIT, UnitOptions

from .benchkit import ROOT, chair_config

DEPLOY_MD = ROOT / "docs" / "deploy.md"


def unit_keys(text: str) -> dict[str, list[str]]:
    """``Section.Key`` -> values, as systemd reads a unit (comments and blank lines skipped)."""
    out: dict[str, list[str]] = {}
    section = ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            assert line.endswith("]"), raw
            section = line[1:-1]
            continue
        key, sep, value = line.partition("=")
        assert sep, f"not a key=value line: {raw!r}"
        out.setdefault(f"{section}.{key.strip()}", []).append(value.strip())
    return out


def test_the_shipped_unit_is_what_install_service_writes_for_the_documented_paths() -> None:
    assert SHIPPED_UNIT.read_text() == service.render(UnitOptions())


def test_exec_start_is_the_command_docs_deploy_md_documents() -> None:
    keys = unit_keys(SHIPPED_UNIT.read_text())
    (start,) = keys["Service.ExecStart"]
    documented = re.findall(r"^ExecStart=(.+)$", DEPLOY_MD.read_text(), flags=re.M)
    assert documented, "docs/deploy.md documents no ExecStart= line"
    assert all(shlex.split(d) == shlex.split(start) for d in documented)
    readme = (ROOT / "README.md").read_text()
    assert "docs/deploy.md" in readme and "install-service" in readme


def _documented_commands() -> list[list[str]]:
    """Every ``wheelchair-hil`` command of docs/deploy.md's ``sh`` blocks, as argv after the
    executable (continuation lines joined, ``sudo``, comments and ``&`` left out)."""
    text = DEPLOY_MD.read_text()
    blocks = re.findall(r"^```sh\n(.*?)^```", text, flags=re.M | re.S)
    out = []
    for line in "\n".join(blocks).replace("\\\n", " ").splitlines():
        words = shlex.split(line, comments=True)
        # the command itself, run as it is or through sudo (not a path or a unit's name)
        at = [
            i
            for i, w in enumerate(words)
            if w == "wheelchair-hil" or w.endswith("/bin/wheelchair-hil")
        ]
        if at and all(w in ("sudo", "-u", "wheelchair") for w in words[: at[0]]):
            argv = words[at[0] + 1 :]
            out.append(argv[:-1] if argv[-1:] == ["&"] else argv)
    return out


def test_every_command_docs_deploy_md_gives_parses_with_the_projects_parser() -> None:
    commands = _documented_commands()
    assert ["install-service", "--chair-template", service.DOC_CONFIG] in commands
    assert {argv[0] for argv in commands} >= {"install-service", "doctor", "control", "sim"}
    for argv in commands:
        build_parser(argv).parse_args(argv)  # SystemExit (usage error) on a wrong option


def test_the_unit_commands_are_valid_command_lines_of_the_project() -> None:
    keys = unit_keys(SHIPPED_UNIT.read_text())
    for key, command in (("ExecStartPre", "doctor"), ("ExecStart", "control")):
        (line,) = keys[f"Service.{key}"]
        argv = shlex.split(line)
        assert Path(argv[0]).name == "wheelchair-hil" and argv[1] == command
        args = build_parser(argv[1:]).parse_args(argv[1:])
        assert (args.bus, args.channel, args.bitrate) == ("socketcan", "can0", 500000)
        assert args.config == service.DOC_CONFIG and args.rt_priority == 80
    start = build_parser(shlex.split(keys["Service.ExecStart"][0])[1:]).parse_args(
        shlex.split(keys["Service.ExecStart"][0])[1:]
    )
    assert start.realtime and start.log_root == "/var/log/wheelchair-hil"


def test_the_unit_never_restarts_runs_the_doctor_first_and_has_real_time_limits() -> None:
    text = SHIPPED_UNIT.read_text()
    k = unit_keys(text)
    assert k["Service.Restart"] == ["no"]
    assert "re-arm" in text and "Clear_Errors" in text  # the comment says why
    assert "doctor" in k["Service.ExecStartPre"][0]
    assert k["Service.CPUSchedulingPolicy"] == ["fifo"]
    assert k["Service.CPUSchedulingPriority"] == ["80"] and k["Service.LimitRTPRIO"] == ["80"]
    assert k["Service.LimitMEMLOCK"] == ["infinity"]
    assert k["Service.LogsDirectory"] == ["wheelchair-hil"]
    assert k["Service.StandardOutput"] == ["journal"] and k["Service.StandardError"] == ["journal"]
    assert k["Unit.BindsTo"] == ["sys-subsystem-net-devices-can0.device"]
    assert k["Install.WantedBy"] == ["multi-user.target"]


def test_install_service_validates_the_config_and_writes_the_unit_into_dest(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = chair_config(tmp_path)
    (tmp_path / "bench").mkdir()
    dest = tmp_path / "units"
    argv = ["install-service", "--config", str(cfg), "--scenario", "short", "--dest", str(dest)]
    assert cli_main([*argv, "--executable", "/opt/x/bin/wheelchair-hil"]) == 0
    k = unit_keys((dest / "wheelchair-hil.service").read_text())
    assert f"--config {cfg}" in k["Service.ExecStart"][0]
    assert "--scenario " + str(ROOT / "scenarios" / "short.toml") in k["Service.ExecStart"][0]
    assert "systemctl start wheelchair-hil" in capsys.readouterr().out
    assert (
        cli_main(["install-service", "--config", str(cfg), "--scenario", "short", "--print"]) == 0
    )
    printed = capsys.readouterr().out
    assert printed.startswith("# wheelchair-hil.service") and "ExecStartPre=" in printed
    bench = chair_config(tmp_path / "bench", extra='[bus]\ninterface = "udp_multicast"\n')
    assert (
        cli_main(["install-service", "--config", str(bench), "--scenario", "short", "--print"]) == 0
    )
    start = unit_keys(capsys.readouterr().out)["Service.ExecStart"][0]
    assert "--bus udp_multicast --channel 239.74.163.2 --bitrate 500000" in start
    assert "Unit.BindsTo" not in unit_keys(service.render(UnitOptions(bus="udp_multicast")))
    bad = tmp_path / "bad.toml"
    bad.write_text("[drives]\nwatchdog_timeout_ms = -1\n")
    assert (
        cli_main(["install-service", "--config", str(bad), "--scenario", "short", "--print"]) == 2
    )
    assert "drives.watchdog_timeout_ms" in capsys.readouterr().err


def test_install_service_writes_the_chair_template_to_start_a_config_from(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "etc" / "chair.toml"
    assert cli_main(["install-service", "--chair-template", str(path)]) == 0
    assert path.read_text() == service.CHAIR_TEMPLATE.read_text()
    assert f"doctor --config {path}" in capsys.readouterr().out
    # a chair's measured config is never written over
    path.write_text("# measured\n")
    assert cli_main(["install-service", "--chair-template", str(path)]) == 2
    assert "exists" in capsys.readouterr().err
    assert path.read_text() == "# measured\n"


def test_without_a_config_or_a_route_install_service_says_what_it_needs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli_main(["install-service", "--scenario", "short", "--dest", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "--config required" in err and "--chair-template PATH" in err
    assert cli_main(["install-service", "--dest", str(tmp_path)]) == 2
    assert "--config and --scenario required" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_the_template_and_the_unit_are_package_data_inside_the_package() -> None:
    package = Path(service.__file__).resolve().parent
    for f in (service.CHAIR_TEMPLATE, service.SHIPPED_UNIT):
        assert f.is_file() and f.resolve().is_relative_to(package), f
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert '"tools.deploy" = ["templates/chair.toml", "templates/wheelchair-hil.service"]' in (
        pyproject
    )


def test_a_path_a_unit_cannot_carry_is_refused_naming_it() -> None:
    with pytest.raises(ConfigError, match="has blanks"):
        service.render(UnitOptions(config="/etc/my chair.toml"))
    assert "--log-root /var/log/50%%" in service.render(UnitOptions(log_dir="/var/log/50%"))
    with pytest.raises(ConfigError, match=r"\[1, 99\]"):
        service.render(UnitOptions(rt_priority=0))


def _verify(unit: Path) -> tuple[int, list[str]]:
    res = subprocess.run(
        ["systemd-analyze", "verify", str(unit)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    return res.returncode, [ln for ln in (res.stdout + res.stderr).splitlines() if ln.strip()]


@pytest.mark.skipif(
    shutil.which("systemd-analyze") is None,
    reason="systemd-analyze not installed (package systemd); the keys are checked above",
)
def test_systemd_analyze_verifies_the_unit_and_would_reject_a_bad_key(tmp_path: Path) -> None:
    exe = Path(sys.executable).with_name("wheelchair-hil")  # verify checks it is executable
    opts = UnitOptions(
        config=str(chair_config(tmp_path)),
        scenario=str(ROOT / "scenarios" / "short.toml"),
        executable=str(exe),
    )
    unit = tmp_path / "wheelchair-hil.service"
    text = service.render(opts)
    unit.write_text(text)
    assert _verify(unit) == (0, [])
    # the same check sees a key systemd cannot parse (it only warns, and ignores the key)
    unit.write_text(text.replace("CPUSchedulingPolicy=fifo", "CPUSchedulingPolicy=fast"))
    _rc, lines = _verify(unit)
    assert any("Failed to parse CPU scheduling policy" in ln for ln in lines), lines


def test_the_stock_odrive_preset_turns_off_authentication_and_the_contract_check_saying_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from controller.config import load_config

    path = tmp_path / "chair.toml"
    argv = ["install-service", "--chair-template", str(path), "--preset", "odrive-stock"]
    assert cli_main(argv) == 0
    assert "preset odrive-stock" in capsys.readouterr().out
    text = path.read_text()
    assert text.startswith("# Preset odrive-stock:")
    assert "DISOBEYED" in text.split("\n\n")[0]  # the header names the defence that is left
    cfg = load_config(path)
    assert cfg.drives.require_auth is False and cfg.auth.check_contract is False
    # every other key is the template's
    secured = load_config(service.CHAIR_TEMPLATE)
    assert cfg.limits == secured.limits and cfg.geometry == secured.geometry
    assert secured.drives.require_auth is True and secured.auth.check_contract is True
