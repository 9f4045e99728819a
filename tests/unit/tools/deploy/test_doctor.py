"""The doctor against the bench on the virtual bus (healthy, a drive missing, a drive at a
wrong node ID, a key others can read), and each check's judgement on recorded input."""

from __future__ import annotations

import itertools
import os
from pathlib import Path
from typing import Any

import can
import pytest

from controller.config import load_config
from dbc.codec import DRIVES, AxisError, AxisState, Codec, Heartbeat, RxSdo
from dbc.runtime import params
from tools.bus.transport import BusSpec, open_bus, resolve
from tools.cli import doctor as doctor_command
from tools.cli import main as cli_main
from tools.deploy import bus_checks, doctor, host_checks, interface_checks
from tools.deploy.capture import Capture
from tools.deploy.check import Check, Status

from .benchkit import bench_running, chair_config, silent_drive_scenario, wrong_node_scenario

_channels = itertools.count()


def _spec() -> BusSpec:
    return resolve("virtual", f"doctor-{os.getpid()}-{next(_channels)}")


def _by_name(checks: list[Check]) -> dict[str, Check]:
    return {c.name: c for c in checks}


def _fails(checks: list[Check]) -> set[str]:
    return {c.name for c in checks if c.status is Status.FAIL}


def test_the_doctor_passes_a_healthy_bench_and_sends_no_command(tmp_path: Path) -> None:
    spec = _spec()
    cfg = chair_config(tmp_path)
    codec = Codec.default()
    with bench_running(spec):
        tap = open_bus(spec)
        try:
            checks = doctor.run_checks(cfg, spec, window_s=1.0)
            heard = []
            while (m := tap.recv(0.0)) is not None:
                heard.append(m)
        finally:
            tap.shutdown()
    assert _fails(checks) == set(), [c.line() for c in checks]
    assert doctor_command.report(checks, out=lambda _s: None) == 0
    by = _by_name(checks)
    for side in ("left", "right"):
        assert by[f"drive {side}"].status is Status.OK
        assert "IDLE" in by[f"drive {side}"].detail
    assert by["contract"].status is Status.OK
    assert f"{codec.contract_hash:08x}" in by["contract"].detail
    assert by["interface"].status is Status.NA
    # the emulated drives answer Get_Version as ODrive 0.6.10 does
    assert by["version"].status is Status.OK
    assert "Fw_Version_Minor=6 Fw_Version_Revision=10" in by["version"].detail
    assert by["key"].status is Status.WARN  # the bench's key is the public test key
    # what the doctor sent: RxSdo reads and RTR requests only, nothing that moves a wheel
    own = {codec.frame_id(cls, n) for cls, n, _ in codec.all_messages() if n in DRIVES}
    sent = [m for m in heard if not m.is_extended_id and m.arbitration_id in own]
    host_sent = [m for m in sent if codec.sender(*_cls_node(codec, m)) == "Host"]
    assert host_sent, "the doctor asked the drives nothing"
    for m in host_sent:
        if m.is_remote_frame:
            continue
        payload = codec.decode(m).payload
        assert isinstance(payload, RxSdo) and payload.opcode == 0, payload


def _cls_node(codec: Codec, msg: can.Message) -> tuple[type, Any]:
    for cls, node, _name in codec.all_messages():
        if node is not None and codec.frame_id(cls, node) == msg.arbitration_id:
            return cls, node
    raise AssertionError(hex(msg.arbitration_id))


def test_a_missing_drive_fails_naming_its_node_id(tmp_path: Path) -> None:
    spec = _spec()
    with bench_running(spec, str(silent_drive_scenario(tmp_path, "right"))):
        checks = doctor.run_checks(chair_config(tmp_path), spec, window_s=1.0)
    by = _by_name(checks)
    assert by["drive right"].status is Status.FAIL
    assert "no heartbeat from node 2 (0x041)" in by["drive right"].detail
    assert "not on the bus" in by["drive right"].detail
    assert by["drive left"].status is Status.OK
    assert doctor_command.report(checks, out=lambda _s: None) == 1


def test_a_drive_at_a_wrong_node_id_is_named_with_the_fix(tmp_path: Path) -> None:
    spec = _spec()
    with bench_running(spec, str(wrong_node_scenario(tmp_path, 5))):
        checks = doctor.run_checks(chair_config(tmp_path), spec, window_s=1.0)
    by = _by_name(checks)
    assert by["drive right"].status is Status.FAIL
    assert "as node 5 (0x0A1)" in by["drive right"].detail
    assert "node_id = 2" in by["drive right"].fix
    assert "drives.right_node_id = 5" in by["drive right"].fix  # or tell the chair file
    assert by["nodes"].status is Status.FAIL and "node 5" in by["nodes"].detail
    assert by["drive left"].status is Status.OK


def test_a_drive_at_the_node_id_the_chair_file_names_passes(tmp_path: Path) -> None:
    spec = _spec()
    cfg = chair_config(tmp_path, extra="[drives]\nright_node_id = 5\n")
    with bench_running(spec, str(wrong_node_scenario(tmp_path, 5))):
        checks = doctor.run_checks(cfg, spec, window_s=1.0)
    by = _by_name(checks)
    assert by["drive right"].status is Status.OK, by["drive right"]
    assert by["drive right"].detail.startswith("node 5: IDLE")
    assert by["nodes"].status is Status.OK, by["nodes"]
    assert by["contract"].status is Status.OK, by["contract"]  # the SDO read answered as 5


def test_a_key_others_can_read_fails_with_chmod(tmp_path: Path) -> None:
    cfg = load_config(chair_config(tmp_path, key_mode=0o644, chairs_own=True))
    c = host_checks.check_key(cfg)
    assert c.status is Status.FAIL
    assert "mode 0644" in c.detail and c.fix == f"chmod 600 {cfg.auth.key_file}"
    os.chmod(cfg.auth.key_file, 0o640)
    assert host_checks.check_key(cfg).status is Status.FAIL  # group-readable is refused too
    os.chmod(cfg.auth.key_file, 0o600)
    assert host_checks.check_key(cfg).status is Status.OK


def test_the_public_test_key_is_a_warning_whatever_its_mode(tmp_path: Path) -> None:
    # a clone has the repository's key with git's mode 0644: the bench's doctor must pass
    for mode in (0o644, 0o600):
        cfg = load_config(chair_config(tmp_path, key_mode=mode))
        c = host_checks.check_key(cfg)
        assert c.status is Status.WARN and "public TEST key" in c.detail, (oct(mode), c)


def test_the_benchs_default_config_names_the_repositorys_key_and_it_only_warns() -> None:
    """What the bench's doctor reads without --config, with the key file as this checkout
    has it (a clone: git's 0644)."""
    cfg = load_config(None)
    assert Path(cfg.auth.key_file).name == "TEST-ONLY-secoc.key"
    assert host_checks.check_key(cfg).status is Status.WARN


def test_the_verdict_line_counts_warnings_in_the_singular_and_the_plural() -> None:
    out: list[str] = []
    warn = Check("key", Status.WARN, "test key")
    assert doctor_command.report([warn], out.append) == 0
    assert doctor_command.report([warn, warn, Check("bus", Status.FAIL, "down")], out.append) == 1
    assert out[1] == "doctor: no failure (1 warning)"
    assert out[-1] == "doctor: 1 failed, 2 warnings: the controller must not arm"


def test_a_missing_key_and_a_malformed_one_fail_naming_the_file(tmp_path: Path) -> None:
    cfg = load_config(None, {"auth": {"key_file": str(tmp_path / "none.key")}})
    c = host_checks.check_key(cfg)
    assert c.status is Status.FAIL and "none.key" in c.detail
    bad = tmp_path / "bad.key"
    bad.write_text("abcd\n")
    bad.chmod(0o600)
    c = host_checks.check_key(load_config(None, {"auth": {"key_file": str(bad)}}))
    assert c.status is Status.FAIL and "bad.key" in c.detail and "16 bits" in c.detail


def test_the_doctor_command_exits_1_when_no_drive_answers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = chair_config(tmp_path)
    argv = ["doctor", "--bus", "virtual", "--channel", f"empty-{os.getpid()}", "--config", str(cfg)]
    assert cli_main([*argv, "--window", "0.2"]) == 1
    out = capsys.readouterr().out.splitlines()
    # a bench-made chair file names few keys: the rest take the bench's values, said
    assert out[0].startswith("warning config") and "take the bench's values" in out[0]
    assert any(line.startswith("FAIL    drive left") for line in out)
    assert out[-1].startswith("doctor: ") and "must not arm" in out[-1]


def test_a_config_error_is_one_failing_line_naming_the_key(tmp_path: Path) -> None:
    cfg = tmp_path / "chair.toml"
    cfg.write_text("[limits]\nv_max_mps = 9.0\n")
    checks = doctor.run_checks(cfg, None, spec_error="no bus given")
    by = _by_name(checks)
    assert by["config"].status is Status.FAIL and "limits.v_max_mps" in by["config"].detail
    assert by["bus"].status is Status.FAIL


def _cfg(**sections: dict[str, Any]) -> Any:
    return params.replace(load_config(), sections, source="test")


def test_limits_that_disagree_with_what_the_drives_get_fail_naming_both_keys() -> None:
    codec = Codec.default()
    assert [c.status for c in host_checks.check_limits(load_config(), codec)] == [Status.OK]
    c = host_checks.check_limits(_cfg(drives={"velocity_limit_revps": 0.8}), codec)
    assert [x.status for x in c] == [Status.FAIL]
    assert "limits.wheel_max_radps" in c[0].detail and "drives.velocity_limit_revps" in c[0].detail
    c = host_checks.check_limits(_cfg(drives={"watchdog_timeout_ms": 0}), codec)
    assert c[0].status is Status.FAIL and "watchdog" in c[0].detail
    c = host_checks.check_limits(_cfg(drives={"host_timeout_ms": 150}), codec)
    assert c[0].status is Status.FAIL and "host_timeout_ms" in c[0].detail
    c = host_checks.check_limits(_cfg(drives={"stop_decel_revps2": 1.5}), codec)
    assert c[0].status is Status.WARN and "stop ramp" in c[0].detail


def test_realtime_refused_is_a_failure_only_when_the_controller_will_ask_for_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def refuse(*_a: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_getscheduler", lambda _pid: os.SCHED_OTHER)
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    c = host_checks.check_realtime(80)
    assert c.status is Status.FAIL
    assert " - rtprio 80'" in c.fix and " - memlock unlimited'" in c.fix
    assert "/etc/security/limits.d/" in c.fix
    assert host_checks.check_realtime(0).status is Status.WARN


def _link(**over: Any) -> dict[str, Any]:
    """A can0 record as ``ip -details -statistics -json link show can0`` prints it."""
    data: dict[str, Any] = {
        "state": "ERROR-ACTIVE",
        "berr_counter": {"tx": 0, "rx": 0},
        "restart_ms": 100,
        "bittiming": {"bitrate": 500000, "sample_point": "0.875"},
    }
    data.update(over.pop("info_data", {}))
    link = {
        "ifname": "can0",
        "flags": ["NOARP", "UP", "LOWER_UP", "ECHO"],
        "operstate": "UP",
        "txqlen": 1000,
        "linkinfo": {"info_kind": "can", "info_data": data},
        "stats64": {"rx": {"errors": 0}},
    }
    link.update(over)
    return link


def test_socketcan_interface_judged_from_ip_json() -> None:
    ok = interface_checks.judge_socketcan(_link(), "can0", 500000)
    assert ok.status is Status.OK and "500000 bit/s, ERROR-ACTIVE" in ok.detail
    down = interface_checks.judge_socketcan(_link(flags=["NOARP", "ECHO"]), "can0", 500000)
    assert down.status is Status.FAIL and "is down" in down.detail
    assert "bitrate 500000 restart-ms 100" in down.fix
    slow = interface_checks.judge_socketcan(
        _link(info_data={"bittiming": {"bitrate": 250000}}), "can0", 500000
    )
    assert slow.status is Status.FAIL and "bitrate 250000" in slow.detail
    off = interface_checks.judge_socketcan(_link(info_data={"state": "BUS-OFF"}), "can0", 500000)
    assert off.status is Status.FAIL and "BUS-OFF" in off.detail and "120 ohm" in off.fix
    warn = interface_checks.judge_socketcan(
        _link(info_data={"state": "ERROR-WARNING"}), "can0", 500000
    )
    assert warn.status is Status.WARN
    short = interface_checks.judge_socketcan(_link(txqlen=10), "can0", 500000)
    assert short.status is Status.WARN and "txqueuelen 1000" in short.fix
    vcan = {
        "ifname": "vcan0",
        "flags": ["NOARP", "UP", "LOWER_UP"],
        "txqlen": 1000,
        "linkinfo": {"info_kind": "vcan"},
    }
    assert interface_checks.judge_socketcan(vcan, "vcan0", 500000).status is Status.OK
    vcan["flags"] = ["NOARP"]
    assert (
        interface_checks.judge_socketcan(vcan, "vcan0", 500000).fix == "sudo ip link set vcan0 up"
    )


def _capture(*beats: Heartbeat, node: int = 1) -> Capture:
    cap = Capture(seconds=1.0)
    cap.heartbeats[node] = list(beats)
    cap.encoder[node] = 100
    return cap


def test_a_drive_fault_fails_a_latched_stop_warns_and_an_armed_drive_fails() -> None:
    codec = Codec.default()
    left = DRIVES[0]
    fault = _capture(Heartbeat(int(AxisError.DRV_FAULT), AxisState.IDLE))
    c = bus_checks.check_drive(fault, left, codec)
    assert c.status is Status.FAIL and "DRV_FAULT" in c.detail
    latched = _capture(Heartbeat(int(AxisError.WATCHDOG_TIMER_EXPIRED), AxisState.IDLE))
    c = bus_checks.check_drive(latched, left, codec)
    assert c.status is Status.WARN and "latched stop WATCHDOG_TIMER_EXPIRED" in c.detail
    armed = _capture(Heartbeat(0, AxisState.CLOSED_LOOP_CONTROL))
    c = bus_checks.check_drive(armed, left, codec)
    assert c.status is Status.FAIL and "another host" in c.detail
    blind = _capture(Heartbeat(0, AxisState.IDLE))
    blind.encoder.clear()
    c = bus_checks.check_drive(blind, left, codec)
    assert c.status is Status.FAIL and "encoder_msg_rate_ms = 10" in c.fix


def test_a_busy_bus_fails_and_another_host_fails() -> None:
    spec = BusSpec("socketcan", "can0")
    cap = Capture(seconds=1.0, frames=5000, bits=450_000)
    c = bus_checks.check_busload(cap, spec)
    assert c.status is Status.FAIL and "90.0 % of 500 kbit/s" in c.detail
    cap.host_heartbeats = 3
    assert bus_checks.check_nodes(cap, Codec.default()).status is Status.FAIL


def test_get_version_answers_are_reported_and_a_silent_drive_warns(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # a DBC with Get_Version (ODrive cmd 0x00): the version frame's ID for each drive
    monkeypatch.setattr(bus_checks, "version_id", lambda _codec, node: int(node) << 5)
    codec = Codec.default()
    cap = _capture(Heartbeat(0, AxisState.IDLE), node=1)
    cap.heartbeats[2] = [Heartbeat(0, AxisState.IDLE)]
    cap.versions[1] = {"Fw_Version_Major": 0, "Fw_Version_Minor": 6, "Fw_Version_Revision": 10}
    c = bus_checks.check_version(cap, codec)
    assert c.status is Status.WARN and "did not answer Get_Version (right)" in c.detail
    assert "left: Fw_Version_Major=0 Fw_Version_Minor=6 Fw_Version_Revision=10" in c.detail
    cap.versions[2] = dict(cap.versions[1])
    assert bus_checks.check_version(cap, codec).status is Status.OK


def test_a_chair_file_that_leaves_a_key_to_the_bench_is_warned_naming_the_key(
    tmp_path: Path,
) -> None:
    """Deleting wheel_radius_m from a chair file gave "valid" and the bench's radius."""
    from tools.deploy.service import CHAIR_TEMPLATE

    whole = tmp_path / "chair.toml"
    whole.write_text(CHAIR_TEMPLATE.read_text())
    by = _by_name(doctor.run_checks(whole, None, spec_error="no bus given"))
    assert by["config"].status is Status.OK, by["config"]
    lines = [
        ln for ln in CHAIR_TEMPLATE.read_text().splitlines() if not ln.startswith("wheel_radius_m")
    ]
    assert len(lines) == len(CHAIR_TEMPLATE.read_text().splitlines()) - 1
    partial = tmp_path / "partial.toml"
    partial.write_text("\n".join(lines) + "\n")
    by = _by_name(doctor.run_checks(partial, None, spec_error="no bus given"))
    assert by["config"].status is Status.WARN
    assert "1 keys of the chair template" in by["config"].detail
    assert "geometry.wheel_radius_m" in by["config"].detail


def test_one_mistake_in_the_config_is_one_failure(tmp_path: Path) -> None:
    """A config that does not load: its own line fails; what depends on it is not checked (and
    says so), and the bus its [bus] names is not failed again as 'no bus given'."""
    cfg = tmp_path / "chair.toml"
    cfg.write_text("[limits]\nv_max_mps = 9.0\n[bus]\ninterface = 'socketcan'\n")
    err = "not checked: the config did not load (its [bus] names the bus)"
    by = _by_name(doctor.run_checks(cfg, None, spec_error=err))
    assert [n for n, c in by.items() if c.status is Status.FAIL] == ["config"]
    assert by["bus"].status is Status.NA and by["limits"].status is Status.NA


def test_socketcan_without_af_can_gets_the_kernels_fix_not_an_ip_link_line(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from tools.bus.transport import BusSpec
    from tools.deploy import interface_checks

    spec = BusSpec("socketcan", "can1", 500_000, False, ())
    monkeypatch.setattr(
        interface_checks, "socketcan_available", lambda: (False, "AF_CAN: errno 97")
    )
    fix = interface_checks.bus_fix(spec)
    assert "modprobe can can_raw" in fix and "sandbox --socketcan" in fix and "ip link" not in fix
    monkeypatch.setattr(interface_checks, "socketcan_available", lambda: (True, ""))
    assert interface_checks.bus_fix(spec).startswith("sudo ip link set can1 down")


def test_the_doctor_says_whether_the_controllers_kernels_run_compiled(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    here = host_checks.check_compiled().status  # make install compiles them
    assert here is (Status.OK if host_checks.compiled(host_checks.kernels) else Status.WARN)
    monkeypatch.setattr(host_checks, "compiled", lambda module: False)
    monkeypatch.setattr(host_checks.controller, "SOURCES_BECAUSE", None)
    c = host_checks.check_compiled()
    assert c.status is Status.WARN
    assert "no C compiler" in c.detail and "python3.11-dev" in c.fix
