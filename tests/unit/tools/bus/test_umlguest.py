"""The user-mode Linux guest's PID 1 script, and the one-line error where no vcan0 can be had."""

from __future__ import annotations

from pathlib import Path

import pytest

from dbc.runtime.errors import BusError
from tests.hil.socketcan.conftest import PART_RT_PRIORITY
from tools.bus import umlguest
from tools.run.processes import RT_OFFSETS


def test_the_init_script_loads_the_can_modules_in_order_and_reports_the_status(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setattr(umlguest, "module_dir", lambda: Path("/usr/lib/uml/modules/6.1/kernel"))
    script = umlguest.init_script(
        ["wheelchair-hil", "run", "--out", "a b"],
        tmp_path / "status",
        cwd="/work/x",
        env={"PATH": "/usr/bin", "TERM": "xterm", "CI": "1"},
    )
    order = [script.index(f"/{m}") for m in umlguest.CAN_MODULES]
    assert order == sorted(order)  # vcan after can-dev
    assert script.index("ip link set up vcan0") < script.index("wheelchair-hil run --out 'a b'")
    assert f"echo $? > {tmp_path / 'status'}" in script
    assert script.rstrip().endswith("poweroff -f")
    assert "export CI=1" in script and "TERM" not in script
    assert f"export {umlguest.GUEST_ENV}=1" in script


def test_the_guests_softirq_thread_runs_above_every_parts_priority_before_the_command(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # the kernel's frame delivery must not wait for the parts it delivers to
    monkeypatch.setattr(umlguest, "module_dir", lambda: Path("/usr/lib/uml/modules/6.1/kernel"))
    script = umlguest.init_script(["true"], tmp_path / "status", cwd="/", env={})
    chrt = f"chrt -f -p {umlguest.SOFTIRQ_RT_PRIORITY}"
    assert "ksoftirqd/*)" in script and chrt in script
    assert script.index(chrt) < script.index("\ntrue ")
    highest_part = PART_RT_PRIORITY + max(RT_OFFSETS.values())
    assert highest_part < umlguest.SOFTIRQ_RT_PRIORITY


def test_without_kernel_can_or_a_guest_the_sandbox_names_what_to_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(umlguest, "host_can_ready", lambda channel="vcan0": (False, "no AF_CAN"))
    monkeypatch.setattr(umlguest, "_try_host_vcan", lambda channel="vcan0": False)
    monkeypatch.setattr(umlguest, "uml_kernel", lambda: None)
    with pytest.raises(BusError, match="user-mode-linux") as err:
        umlguest.run_with_vcan(["true"])
    assert "\n" not in str(err.value)
    assert "linux.uml" in str(err.value)
