"""One log per run, summaries from the log alone, replay --verify, what-if and re-transmission."""

from __future__ import annotations

import json
import shutil
import threading
import uuid
import warnings
from pathlib import Path
from typing import Any

import can
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter

from controller.tracking import registry
from dbc.runtime.errors import ConfigError
from dbc.runtime.mcapwriter import LogWriter
from tests.cli import run_cli as _cli
from tests.integration.conftest import run_stack
from tools.logs import mcap_io, runlog
from tools.replay.retransmit import retransmit
from tools.replay.verify import replay_offline

# make test starts the heaviest files first (tests/conftest.py)
pytestmark = pytest.mark.heavy(seconds=43)

DURATION_S = 6.0  # long enough to arm and track for a few seconds


def _available(name: str) -> bool:
    try:
        registry.controller_class(name)
    except ConfigError:
        return False
    return True


@pytest.fixture(scope="module")
def baseline_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("baseline")
    summary = run_stack(out, "short", "baseline", duration_s=DURATION_S)
    return out, summary


def test_a_run_leaves_one_log_with_bus_controller_and_foxglove_channels(
    baseline_run: tuple[Path, dict[str, Any]],
) -> None:
    out, _summary = baseline_run
    assert not (out / "controller.mcap").exists()  # merged into run.mcap
    contents = mcap_io.read_contents(out / "run.mcap")
    assert contents.complete
    topics = contents.topics()
    for t in (
        "/can/raw",
        "/can/Left_Set_Input_Vel_Auth",
        "/truth/pose",
        "/truth/tf",
        "/wheels/joint_states",
        "/events",
        "/controller/estimate/pose",
        "/controller/reference/tf",
        "/controller/errors",
        "/controller/command",
        "/controller/internals",
        "/controller/loop",
    ):
        assert t in topics, t
    for name in ("run", "versions", "recorder", "bench_stats", "controller_stats"):
        assert name in contents.metadata, name
    assert contents.metadata["controller_config"]["controller"] == "baseline"
    assert {"wheelchair.dbc", "scenario/short.toml", "route/short.toml"} <= set(
        contents.attachments
    )


def test_summarize_recomputes_the_summary_from_the_log_alone(
    baseline_run: tuple[Path, dict[str, Any]],
) -> None:
    out, summary = baseline_run
    assert summary["tracking_started"]
    again = runlog.summarize(out / "run.mcap")  # re-plans the route from the attachment
    assert json.dumps(again, sort_keys=True, default=str) == json.dumps(
        summary, sort_keys=True, default=str
    )
    res = _cli("summarize", str(out / "run.mcap"), "--json")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["rmse_pos_m"] == summary["rmse_pos_m"]


@pytest.mark.parametrize("name", registry.names())
def test_replay_verify_passes_on_a_run_of_each_controller(
    name: str, tmp_path: Path, baseline_run: tuple[Path, dict[str, Any]]
) -> None:
    if not _available(name):
        pytest.skip(f"controller {name} is not available yet")
    if name == "baseline":
        out = baseline_run[0]
    else:
        out = tmp_path
        run_stack(out, "short", name, duration_s=DURATION_S)
    res = replay_offline(out / "run.mcap")
    assert res.controller == name
    assert res.first_mismatch is None
    assert res.ok
    assert res.setpoints_compared > 2 * 100  # both wheels, through arming and tracking
    cli = _cli("replay", str(out / "run.mcap"), "--verify")
    assert cli.returncode == 0, cli.stderr
    assert "verify: OK" in cli.stdout


def test_verify_fails_and_names_the_first_differing_frame(
    tmp_path: Path, baseline_run: tuple[Path, dict[str, Any]]
) -> None:
    log = tmp_path / "tampered.mcap"
    shutil.copy(baseline_run[0] / "run.mcap", log)
    gains = json.loads(mcap_io.read_contents(log).metadata["controller_config"]["gains"])
    gains["k_y"] *= 1.01  # a fresh controller with other gains must be caught
    mcap_io.merge_into(log, [], metadata={"controller_config": {"gains": json.dumps(gains)}})
    res = _cli("replay", str(log), "--verify")
    assert res.returncode == 1
    assert "first difference" in res.stderr
    assert "Set_Input_Vel" in res.stderr and "tick" in res.stderr


def test_verify_refuses_a_real_time_recording(tmp_path: Path) -> None:
    log = tmp_path / "rt.mcap"
    w = LogWriter(log)
    w.add_metadata("run", {"mode": "realtime"})
    w.close()
    res = _cli("replay", str(log), "--verify")
    assert res.returncode == 2
    assert "lock-step recording" in res.stderr


def test_replay_retransmits_the_recorded_frames_in_bus_order(
    baseline_run: tuple[Path, dict[str, Any]],
) -> None:
    log = baseline_run[0] / "run.mcap"
    recorded = [m for _t, m in mcap_io.iter_frames(log)]
    channel = f"replay-{uuid.uuid4()}"
    got: list[can.Message] = []
    with (
        can.Bus(interface="virtual", channel=channel) as tx,
        can.Bus(interface="virtual", channel=channel) as rx,
    ):
        done = threading.Event()

        def listen() -> None:
            while True:
                m = rx.recv(0.2)
                if m is None:
                    if done.is_set():
                        return
                    continue
                got.append(m)

        th = threading.Thread(target=listen)
        th.start()
        n = retransmit(log, tx, speed=200.0)
        done.set()
        th.join(10)
    assert n == len(recorded)
    key = [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in recorded]
    assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in got] == key


def test_what_if_another_controller_open_and_closed_loop(
    tmp_path: Path, baseline_run: tuple[Path, dict[str, Any]]
) -> None:
    other = next((n for n in registry.names() if n != "baseline" and _available(n)), "baseline")
    res = _cli(
        "replay",
        str(baseline_run[0] / "run.mcap"),
        "--controller",
        other,
        "--out",
        str(tmp_path),
    )
    assert res.returncode == 0, res.stderr
    assert "open loop" in res.stdout and "setpoint difference" in res.stdout
    frames = [m for _t, m in mcap_io.iter_frames(tmp_path / f"open-loop-{other}.mcap")]
    assert len(frames) > 1000
    topics = mcap_io.read_contents(tmp_path / f"open-loop-{other}.mcap").topics()
    assert "/controller/errors" in topics
    summary = json.loads((tmp_path / f"closed-loop-{other}" / "summary.json").read_text())
    assert summary["controller"] == other
    assert summary["scenario"] == "short"


def test_a_truncated_run_log_is_summarized_as_far_as_it_goes(
    tmp_path: Path, baseline_run: tuple[Path, dict[str, Any]]
) -> None:
    data = (baseline_run[0] / "run.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) * 2 // 3])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = sum(1 for _ in mcap_io.iter_frames(tmp_path / "cut.mcap"))
    assert any(issubclass(c.category, mcap_io.TruncatedLogWarning) for c in caught)
    assert frames > 1000


def test_verify_of_a_log_damaged_in_the_middle_fails_saying_how_many_ticks_it_checked(
    tmp_path: Path, baseline_run: tuple[Path, dict[str, Any]]
) -> None:
    data = bytearray((baseline_run[0] / "run.mcap").read_bytes())
    mid = len(data) // 2
    data[mid : mid + 1024] = bytes(range(256)) * 4  # 1 KiB of garbage
    (tmp_path / "damaged.mcap").write_bytes(bytes(data))
    res = _cli("replay", "--verify", str(tmp_path / "damaged.mcap"))
    assert res.returncode == 1, res.stdout
    assert "verify: OK" not in res.stdout
    assert "INCOMPLETE" in res.stderr and " ticks verified" in res.stderr
    assert "damaged at byte" in res.stderr


def _damage_json(src: Path, dst: Path, every: int) -> int:
    """Rewrite ``src`` with every ``every``-th ``/can/raw`` record's JSON broken, through
    the mcap writer: every chunk CRC is valid, only the payloads are damaged."""
    damaged = n = 0
    with src.open("rb") as fi, dst.open("wb") as fo:
        reader = make_reader(fi)
        summary = reader.get_summary()
        assert summary is not None
        writer = McapWriter(fo)
        writer.start(profile=reader.get_header().profile, library="test")
        schemas = {
            sid: writer.register_schema(s.name, s.encoding, s.data)
            for sid, s in summary.schemas.items()
        }
        channels = {
            cid: writer.register_channel(
                c.topic, c.message_encoding, schemas.get(c.schema_id, 0), dict(c.metadata)
            )
            for cid, c in summary.channels.items()
        }
        for _schema, channel, m in reader.iter_messages(log_time_order=False):
            data = m.data
            if channel.topic == "/can/raw":
                n += 1
                if n % every == 0:
                    data = data[:20] + b"\xff\x00 not json" + data[30:]
                    damaged += 1
            writer.add_message(channels[channel.id], m.log_time, data, m.publish_time, m.sequence)
        for a in reader.iter_attachments():
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        for md in reader.iter_metadata():
            writer.add_metadata(md.name, dict(md.metadata))
        writer.finish()
    return damaged


def test_a_log_with_damaged_json_but_valid_crcs_is_reported_damaged_by_summarize_and_verify(
    tmp_path: Path, baseline_run: tuple[Path, dict[str, Any]]
) -> None:
    bad = tmp_path / "bad-json.mcap"
    damaged = _damage_json(baseline_run[0] / "run.mcap", bad, every=200)
    assert damaged > 10
    res = _cli("summarize", str(bad))
    assert res.returncode == 1, res.stdout
    assert f"MISSING: {damaged} of" in res.stdout and "not readable" in res.stdout
    assert "Traceback" not in res.stderr
    res = _cli("replay", "--verify", str(bad))
    assert res.returncode == 1, res.stdout
    assert "verify: OK" not in res.stdout and "Traceback" not in res.stderr
    assert f"{damaged} /can/raw messages are damaged" in res.stderr, res.stderr


def test_summarize_of_a_cut_log_says_what_is_missing_and_fails_unless_partial(
    tmp_path: Path, baseline_run: tuple[Path, dict[str, Any]]
) -> None:
    data = (baseline_run[0] / "run.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    res = _cli("summarize", str(cut))  # the route attachment is at the end: lost
    assert res.returncode == 2 and "--scenario" in res.stderr
    res = _cli("summarize", str(cut), "--scenario", "short", "--json")
    assert res.returncode == 1
    s = json.loads(res.stdout)
    assert s["complete"] is False
    assert any("cut off" in m for m in s["missing"])
    assert any("no controller_stats metadata" in m for m in s["missing"])
    assert s["deadline_misses"] is None  # missing, not -1
    res = _cli("summarize", str(cut), "--scenario", "short", "--partial")
    assert res.returncode == 0
    assert "None" not in res.stdout and "-1 deadline" not in res.stdout
    assert "MISSING:" in res.stdout


def test_replay_on_a_bus_shows_its_progress_on_stderr_a_line_per_tenth(
    baseline_run: tuple[Path, dict[str, Any]],
) -> None:
    log = baseline_run[0] / "run.mcap"
    total = mcap_io.raw_frame_count(log)
    assert total == sum(1 for _ in mcap_io.iter_frames(log))
    res = _cli(
        "replay", str(log), "--bus", "virtual", "--channel", f"r-{uuid.uuid4()}", "--speed", "1000"
    )
    assert res.returncode == 0, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("replay: ")]
    assert len(lines) == 10, res.stderr
    assert lines[-1].startswith(f"replay: {total}/{total} frames (100 %), "), res.stderr
    assert all(" elapsed" in ln for ln in lines) and " left" in lines[0]
    assert "\r" not in res.stderr
    assert f"replayed {total} frames" in res.stdout and "replay: " not in res.stdout
    quiet = _cli("replay", str(log), "--bus", "virtual", "--speed", "1000", "--no-progress")
    assert "replay: " not in quiet.stderr
