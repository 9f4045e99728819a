"""The chair config template (tools/deploy/templates/chair.toml) loads with the controller's own loader,
names every parameter a chair needs, and says each one's unit and how to choose or measure it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from controller.config import ControllerConfig, load_config
from dbc.runtime.errors import ConfigError
from dbc.runtime.params import describe, load_toml
from tools.cli import from_args
from tools.deploy.service import CHAIR_TEMPLATE
from tools.run.parts import new_run_dir

TEMPLATE = CHAIR_TEMPLATE
#: Only a lock-step run against the bench uses these; a chair never does.
#: Parameters a chair never sets: lock-step timeouts, and the sensor faults the evaluation
#: injects into the estimate (the paper's fault setting).
BENCH_ONLY = {
    "loop.lockstep_idle_timeout_s",
    "loop.lockstep_start_timeout_s",
    "estimation.perceived_flats",
}


def test_the_template_loads_with_the_controllers_loader() -> None:
    cfg = load_config(TEMPLATE)
    assert cfg.bus.interface == "socketcan" and cfg.bus.channel == "can0"
    assert cfg.bus.bitrate == 500_000
    assert (cfg.drives.left_node_id, cfg.drives.right_node_id) == (1, 2)
    assert cfg.auth.key_file == "/etc/wheelchair-hil/secoc.key"  # absolute: kept as written
    assert cfg.drives.require_auth and cfg.auth.check_contract


def test_the_template_names_every_parameter_but_the_lock_step_ones() -> None:
    table = load_toml(TEMPLATE)
    in_file = {f"{sec}.{k}" for sec, sub in table.items() for k in sub}
    declared = {row["key"] for row in describe(ControllerConfig)}
    assert in_file == declared - BENCH_ONLY


def test_every_key_of_the_template_has_a_comment_with_its_unit() -> None:
    lines = TEMPLATE.read_text().splitlines()
    units = {row["key"].split(".", 1)[1]: row["unit"] for row in describe(ControllerConfig)}
    for i, line in enumerate(lines):
        m = re.match(r"^(\w+) = ", line)
        if not m:
            continue
        j = i
        while j > 0 and lines[j - 1].startswith("#"):
            j -= 1
        comment = " ".join(lines[j:i])
        assert comment, f"{m.group(1)} has no comment"
        unit = units[m.group(1)] or "(no unit)"
        assert comment.startswith(f"# {unit}"), f"{m.group(1)}: comment does not start with {unit}"


def test_a_node_id_another_node_has_is_refused_naming_the_key(tmp_path: Path) -> None:
    p = tmp_path / "chair.toml"
    p.write_text("[drives]\nright_node_id = 5\nleft_node_id = 0\n")
    cfg = load_config(p)  # a drive may take any free node ID: translated at the bus
    assert (cfg.drives.left_node_id, cfg.drives.right_node_id) == (0, 5)
    p.write_text("[drives]\nright_node_id = 3\n")
    with pytest.raises(
        ConfigError, match=r"drives\.right_node_id and bus\.localizer_node_id are both 3"
    ):
        load_config(p)
    p.write_text("[drives]\nleft_node_id = 8\n")
    with pytest.raises(ConfigError, match=r"drives\.left_node_id = 8 is the host's node ID"):
        load_config(p)
    p.write_text("[drives]\nleft_node_id = 3\nright_node_id = 4\n[bus]\nlocalizer_node_id = 5\n")
    cfg = load_config(p)  # drives on 3 and 4: the localizer moves
    assert (cfg.drives.left_node_id, cfg.bus.localizer_node_id) == (3, 5)
    p.write_text("[drives]\nleft_node_id = 2\n")
    with pytest.raises(ConfigError, match=r"left_node_id and drives\.right_node_id are both 2"):
        load_config(p)
    p.write_text("[drives]\nleft_node_id = 63\n")
    with pytest.raises(ConfigError, match=r"drives\.left_node_id"):
        load_config(p)


class _Args:
    def __init__(self, bus: str | None = None, channel: str | None = None) -> None:
        self.bus, self.channel, self.bitrate = bus, channel, None
        self.allow_network_multicast, self.bus_option = False, []


def test_the_configs_bus_is_used_where_the_command_line_names_none() -> None:
    cfg = load_config(TEMPLATE)
    spec = from_args.bus_spec(_Args(), cfg.bus)  # type: ignore[arg-type]
    assert (spec.interface, spec.channel, spec.bitrate) == ("socketcan", "can0", 500_000)
    spec = from_args.bus_spec(_Args("virtual", "x"), cfg.bus)  # type: ignore[arg-type]
    assert (spec.interface, spec.channel) == ("virtual", "x")


def test_each_start_gets_a_log_directory_of_its_own(tmp_path: Path) -> None:
    a, b = new_run_dir(tmp_path), new_run_dir(tmp_path)
    assert a != b and a.is_dir() and b.is_dir() and a.parent == b.parent == tmp_path
    assert re.fullmatch(r"\d{8}T\d{6}Z(-\d+)?", a.name)
