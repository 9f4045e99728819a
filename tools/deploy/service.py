"""The systemd unit that runs the controller on a chair (``wheelchair-hil install-service``).

The unit runs the doctor first (``ExecStartPre=``: any failure keeps the controller from
starting), then the controller in real time under SCHED_FIFO with locked memory, its logs
in a new directory per start and its output in the journal.  It never restarts by itself:
the controller arms as soon as both drives are on the bus, so an automatic restart would
re-arm a latched stop that nobody has looked at (the unit's comment says it in full).

:func:`render` builds the text from :class:`UnitOptions`; :func:`unit_options` validates the
chair's config and route and makes them; ``install-service`` (tools/cli/install_service.py)
then prints the unit (``--print``) or writes it into ``--dest`` (``/etc/systemd/system`` by
default).  :func:`write_chair_template` writes the chair config template instead
(``--chair-template PATH``), to start the chair's config from.

The template and the unit for the paths docs/deploy.md uses (a test keeps it equal to what
:func:`render` writes) are package data, ``tools/deploy/templates/``, found through
:mod:`importlib.resources`: an installed wheel has them as the checkout does.
"""

from __future__ import annotations

import re
import shutil
import sys
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from controller.config import load_config
from dbc.runtime.errors import ConfigError
from tools.bus import transport
from tools.run import scenario as scenario_mod

#: Where docs/deploy.md installs things; the shipped unit uses them.
DOC_EXECUTABLE = "/opt/wheelchair-hil/.venv/bin/wheelchair-hil"
DOC_CONFIG = "/etc/wheelchair-hil/chair.toml"
DOC_SCENARIO = "/etc/wheelchair-hil/route.toml"
#: The package data of a deployment (the checkout's and an installed wheel's alike).
TEMPLATES = Path(str(resources.files("tools.deploy") / "templates"))
#: The chair config template: every parameter a chair needs, with its unit and how to measure it.
CHAIR_TEMPLATE = TEMPLATES / "chair.toml"
#: The unit install-service writes for docs/deploy.md's paths.
SHIPPED_UNIT = TEMPLATES / "wheelchair-hil.service"
_UNSAFE = re.compile(r"[\s\"'\\;$`]")


@dataclass(frozen=True)
class UnitOptions:
    """What the unit needs to know; the defaults are docs/deploy.md's."""

    config: str = DOC_CONFIG
    scenario: str = DOC_SCENARIO
    executable: str = DOC_EXECUTABLE
    bus: str = "socketcan"
    channel: str = "can0"
    bitrate: int = 500_000
    controller: str = ""
    rt_priority: int = 80
    user: str = "wheelchair"
    log_dir: str = "/var/log/wheelchair-hil"
    name: str = "wheelchair-hil"


def _word(s: str) -> str:
    """One command-line word for a unit file (``%`` escaped; no quoting needed or allowed)."""
    if not s or _UNSAFE.search(s):
        raise ConfigError(
            f"install-service: {s!r} is empty or has blanks, quotes or shell characters; "
            "use a path without them"
        )
    return s.replace("%", "%%")


def bus_args(o: UnitOptions) -> list[str]:
    return ["--bus", o.bus, "--channel", o.channel, "--bitrate", str(o.bitrate)]


def doctor_argv(o: UnitOptions) -> list[str]:
    """The pre-flight command (ExecStartPre=)."""
    return [
        o.executable,
        "doctor",
        *bus_args(o),
        "--config",
        o.config,
        "--rt-priority",
        str(o.rt_priority),
    ]


def control_argv(o: UnitOptions) -> list[str]:
    """The controller's command (ExecStart=), as docs/deploy.md documents it."""
    argv = [
        o.executable,
        "control",
        *bus_args(o),
        "--realtime",
        "--rt-priority",
        str(o.rt_priority),
    ]
    argv += ["--config", o.config, "--scenario", o.scenario]
    if o.controller:
        argv += ["--controller", o.controller]
    return [*argv, "--log-root", o.log_dir]


def render(o: UnitOptions) -> str:
    """The unit file's text."""
    if not 1 <= o.rt_priority <= 99:
        raise ConfigError(f"install-service: --rt-priority {o.rt_priority} is outside [1, 99]")
    pre = " ".join(_word(w) for w in doctor_argv(o))
    start = " ".join(_word(w) for w in control_argv(o))
    unit: list[str] = [
        f"# {o.name}.service: this chair's controller, started only after its pre-flight check.",
        "# Written by `wheelchair-hil install-service`; docs/deploy.md explains it.",
        "",
        "[Unit]",
        f"Description=wheelchair-hil controller ({o.bus} {o.channel}, {o.config})",
        "Documentation=man:systemd.service(5) man:systemd.exec(5)",
    ]
    if transport.profile(o.bus).network_device:
        device = f"sys-subsystem-net-devices-{o.channel}.device"
        unit += [
            "# The CAN interface must exist; the service stops if it disappears.",
            f"BindsTo={device}",
            f"After={device} network.target",
        ]
    logs = Path(o.log_dir)
    under_var_log = (
        logs.is_absolute() and logs.parts[:3] == ("/", "var", "log") and len(logs.parts) > 3
    )
    unit += [
        "",
        "[Service]",
        "Type=simple",
        f"User={_word(o.user)}",
        f"Group={_word(o.user)}",
        "# The pre-flight check moves no wheel. Any failure (a drive missing or at a wrong node",
        "# ID, a latched drive error, another host on the bus, a key others can read, the",
        "# interface down, real-time priority refused ...) keeps the controller from starting:",
        f"# `journalctl -u {o.name}` shows its lines, each with its fix.",
        f"ExecStartPre={pre}",
        f"ExecStart={start}",
        "# Never restarted by itself. The controller arms on start: once both drives send",
        "# heartbeats it sends them Clear_Errors and Set_Axis_State(CLOSED_LOOP_CONTROL)",
        "# (controller/node.py, _arm). An automatic restart would therefore clear a latched",
        "# stop (a drive watchdog expiry, an Estop, a safe stop that ended in FAULT, a crash)",
        "# and drive on without anyone deciding to. Only a person re-arms, by starting the",
        f"# service again (`systemctl start {o.name}`), which runs the doctor again first.",
        "Restart=no",
        "# Real time: SCHED_FIFO for the process, the loop asks for it again (--rt-priority)",
        "# and locks its memory; forked log writers go back to normal scheduling.",
        "CPUSchedulingPolicy=fifo",
        f"CPUSchedulingPriority={o.rt_priority}",
        "CPUSchedulingResetOnFork=yes",
        f"LimitRTPRIO={o.rt_priority}",
        "LimitMEMLOCK=infinity",
        f"# Logs: every start writes a new {o.log_dir}/<UTC start time>/ (controller.mcap,",
        "# controller_stats.json); stdout and stderr go to the journal.",
    ]
    if under_var_log:
        unit.append(f"LogsDirectory={'/'.join(logs.parts[3:])}")
    else:
        unit.append(f"ReadWritePaths={_word(o.log_dir)}")
    unit += [
        "StandardOutput=journal",
        "StandardError=journal",
        f"SyslogIdentifier={o.name}",
        "# SIGTERM ends the loop; the drives' watchdogs then stop both wheels on their ramp.",
        "KillSignal=SIGTERM",
        "TimeoutStopSec=10",
        "NoNewPrivileges=yes",
        "ProtectSystem=full",
        "PrivateTmp=yes",
        "",
        "[Install]",
        "WantedBy=multi-user.target",
        "",
    ]
    return "\n".join(unit)


def default_executable() -> str:
    """The ``wheelchair-hil`` this process runs as (its venv's), absolute."""
    here = Path(sys.argv[0])
    if here.name == "wheelchair-hil" and here.exists():
        return str(here.resolve())
    found = shutil.which("wheelchair-hil")
    if found:
        return str(Path(found).resolve())
    return str(Path(sys.executable).with_name("wheelchair-hil"))


def unit_options(
    config: str | Path,
    scenario: str,
    *,
    bus: str | None = None,
    channel: str | None = None,
    bitrate: int | None = None,
    controller: str | None = None,
    rt_priority: int = 80,
    user: str = "wheelchair",
    log_dir: str = "/var/log/wheelchair-hil",
    name: str = "wheelchair-hil",
    executable: str | None = None,
) -> UnitOptions:
    """The unit's options for the chair's ``config`` and route ``scenario`` (both validated);
    the bus is the config's where the caller names none (``bus``, ``channel``, ``bitrate``),
    the executable this one's (:func:`default_executable`) where none is given."""
    config = Path(config).resolve()
    cfg = load_config(config)  # ConfigError naming the file and the key
    scen = scenario_mod.find(scenario)
    scenario_mod.load(str(scen))  # the route must load, too
    interface = bus or cfg.bus.interface or "socketcan"
    same = interface == cfg.bus.interface
    spec = transport.resolve(  # validates the interface; its default channel (can0 ...)
        interface,
        channel or (cfg.bus.channel if same else "") or None,
        bitrate=bitrate or (cfg.bus.bitrate if same else None) or transport.DEFAULT_BITRATE,
    )
    return UnitOptions(
        config=str(config),
        scenario=str(scen.resolve()),
        executable=executable or default_executable(),
        bus=spec.interface,
        channel=spec.channel,
        bitrate=spec.bitrate,
        controller=controller or "",
        rt_priority=rt_priority,
        user=user,
        log_dir=log_dir,
        name=name,
    )


#: The chair-template presets (``install-service --chair-template PATH --preset NAME``):
#: name -> (key lines replaced, header said first).  ``secured``: the template as it is.
PRESETS: dict[str, tuple[dict[str, str], str]] = {
    "secured": ({}, ""),
    "odrive-stock": (
        {
            "require_auth = true": "require_auth = false  # preset odrive-stock: no MAC",
            "check_contract = true": "check_contract = false  # preset odrive-stock",
        },
        "# Preset odrive-stock: drives running ODrive's own firmware, which knows neither the\n"
        "# authenticated setpoint nor the wire-contract hash. What that gives up (the doctor\n"
        "# warns on both): any node on the bus can command the wheels with a plain\n"
        "# Set_Input_Vel, so the plausibility check (DISOBEYED, docs/safety.md \u00a7 1b) is the only\n"
        "# defence; and nothing checks that the drives speak this DBC before arming.\n#\n",
    ),
}


def write_chair_template(path: Path, preset: str = "secured") -> Path:
    """Write :data:`CHAIR_TEMPLATE` to ``path`` with ``preset``'s keys (never over an existing
    file)."""
    if preset not in PRESETS:
        raise ConfigError(f"--preset {preset!r}: choose one of {', '.join(PRESETS)}")
    if path.exists():
        raise ConfigError(f"install-service: {path} exists; the template is not written over it")
    keys, header = PRESETS[preset]
    text = CHAIR_TEMPLATE.read_text()
    for old, new in keys.items():
        if text.count(f"\n{old}\n") != 1:  # the template changed: say so, write nothing wrong
            raise ConfigError(f"preset {preset}: {CHAIR_TEMPLATE} has no single line {old!r}")
        text = text.replace(f"\n{old}\n", f"\n{new}\n")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(header + text)
    return path
