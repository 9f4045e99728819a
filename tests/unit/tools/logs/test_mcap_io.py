"""MCAP as a python-can log format (entry points), and merging logs."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import can
import pytest
from mcap.reader import make_reader

from dbc.codec import (
    BenchStep,
    BenchStepAck,
    Codec,
    EncoderEstimates,
    Node,
    SetInputVel,
    TruthPose,
)
from dbc.runtime.mcapwriter import LogWriter
from tools.logs import mcap_io
from tools.logs.mcap_io import (
    LogContents,
    MCAPReader,
    MCAPWriter,
    iter_frames,
    iter_messages,
    merge_into,
    read_contents,
    scan,
)
from tools.logs.recorder import FrameLog

CODEC = Codec.default()
MS = 1_000_000


def _frames() -> list[can.Message]:
    out = []
    for k in range(50):
        t = k * 10 * MS
        out.append(CODEC.encode(EncoderEstimates(0.01 * k, 1.0), Node.LEFT))
        out.append(CODEC.encode(BenchStep(t)))
        out.append(CODEC.encode(SetInputVel(0.5), Node.RIGHT))
        out.append(CODEC.encode(BenchStepAck(t)))
        out.append(CODEC.encode(TruthPose(0.1 * k, 0.0, 0.0)))
    out.append(can.Message(arbitration_id=0x123, is_remote_frame=True, dlc=0, is_extended_id=False))
    out.append(can.Message(is_error_frame=True, arbitration_id=0, dlc=0))
    for i, m in enumerate(out):
        m.timestamp = 1_700_000_000.0 + i * 1e-3
    return out


def _write(path: Path, frames: list[can.Message], lockstep: bool = True) -> None:
    log = FrameLog(LogWriter(path), lockstep=lockstep)
    for m in frames:
        log.record(m)
    log.close()


def _key(m: can.Message) -> tuple[object, ...]:
    return (
        m.arbitration_id,
        m.is_extended_id,
        m.is_remote_frame,
        m.is_error_frame,
        m.dlc,
        bytes(m.data),
    )


def test_can_logreader_yields_the_recorded_frames_in_bus_order(tmp_path: Path) -> None:
    frames = _frames()
    _write(tmp_path / "x.mcap", frames)
    with can.LogReader(tmp_path / "x.mcap") as reader:
        assert isinstance(reader, MCAPReader)
        back = list(reader)
    assert [_key(m) for m in back] == [_key(m) for m in frames]
    # lock-step recordings replay on simulation time (the 5th frame is step 0's truth), dated
    # by the first frame's receive time: the chair's timing, on the day it ran
    first = frames[0].timestamp
    assert first > 1.6e9  # a real date
    assert [round(m.timestamp - first, 6) for m in back[:6]] == [0.0, 0.0, 0.0, 0.0, 0.0, 0.01]
    log = list(MCAPReader(tmp_path / "x.mcap", timestamps="log"))
    assert [m.timestamp for m in log[:6]] == [0.0, 0.0, 0.0, 0.0, 0.0, 0.01]
    received = list(MCAPReader(tmp_path / "x.mcap", timestamps="receive"))
    assert [m.timestamp for m in received] == [m.timestamp for m in frames]


def test_can_logger_writes_the_recorders_layout(tmp_path: Path) -> None:
    frames = _frames()
    with can.Logger(tmp_path / "y.mcap") as logger:
        assert isinstance(logger, MCAPWriter)
        for m in frames:
            logger(m)
    topics = {ch.topic for ch, _m in iter_messages(tmp_path / "y.mcap")}
    assert {"/can/raw", "/can/Left_Get_Encoder_Estimates", "/truth/pose"} <= topics
    assert [_key(m) for _t, m in iter_frames(tmp_path / "y.mcap")] == [_key(m) for m in frames]
    contents = read_contents(tmp_path / "y.mcap")
    assert contents.complete and "wheelchair.dbc" in contents.attachments
    # not lock-step by default: log time is the receive time
    assert next(iter_frames(tmp_path / "y.mcap"))[0] == int(frames[0].timestamp * 1e9)


def test_mcap_logs_cannot_be_appended_to(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="appended"):
        can.Logger(tmp_path / "z.mcap", append=True)


def _tool(name: str) -> list[str]:
    exe = shutil.which(name, path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip(f"{name} not installed")
    return [exe]


def test_can_logconvert_to_asc_and_back_keeps_every_frame(tmp_path: Path) -> None:
    frames = _frames()
    _write(tmp_path / "x.mcap", frames)
    res = subprocess.run(
        [*_tool("can_logconvert"), str(tmp_path / "x.mcap"), str(tmp_path / "x.asc")],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert res.returncode == 0, res.stderr
    asc = list(can.LogReader(tmp_path / "x.asc"))
    mcap = list(can.LogReader(tmp_path / "x.mcap"))
    assert len(asc) == len(mcap) == len(frames)
    assert [_key(m) for m in asc] == [_key(m) for m in mcap]
    res = subprocess.run(
        [*_tool("can_logconvert"), str(tmp_path / "x.asc"), str(tmp_path / "back.mcap")],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert res.returncode == 0, res.stderr
    assert [_key(m) for m in can.LogReader(tmp_path / "back.mcap")] == [_key(m) for m in frames]


def _json_log(path: Path, topic: str, times: list[int], md: dict[str, dict[str, str]]) -> None:
    w = LogWriter(path)
    s = w.register_schema(topic, "jsonschema", b"{}")
    c = w.register_channel(topic, "json", s)
    for t in times:
        w.add_message(c, t, t, json.dumps({"t": t}).encode())
    for name, rec in md.items():
        w.add_metadata(name, rec)
    w.add_attachment(f"{topic.strip('/')}.txt", b"x")
    w.close()


def test_merge_interleaves_by_log_time_and_keeps_the_main_logs_order(tmp_path: Path) -> None:
    main, extra = tmp_path / "run.mcap", tmp_path / "ctl.mcap"
    _json_log(main, "/bus", [0, 20, 10, 30], {"run": {"a": "1", "b": "1"}})
    _json_log(extra, "/ctl", [5, 10, 25, 40], {"controller_stats": {"ticks": "4"}})
    seen: list[tuple[str, int, bytes]] = []
    merged = LogContents()
    n = merge_into(
        main,
        [extra],
        metadata={"run": {"b": "2"}},
        on_message=lambda ch, m: seen.append((ch.topic, m.log_time, bytes(m.data))),
        contents=merged,
    )
    assert n == 8
    # the callback saw the merged log exactly as a reader of the new file does
    assert seen == [(ch.topic, m.log_time, bytes(m.data)) for ch, m in iter_messages(main)]
    assert merged.metadata["run"] == {"a": "1", "b": "2"} and merged.message_count == 8
    assert set(merged.attachments) == {"bus.txt", "ctl.txt"}
    order = [(ch.topic, m.log_time) for ch, m in iter_messages(main)]
    assert [x for x in order if x[0] == "/bus"] == [("/bus", t) for t in (0, 20, 10, 30)]
    assert order == [
        ("/bus", 0),
        ("/ctl", 5),
        ("/ctl", 10),
        ("/bus", 20),
        ("/bus", 10),
        ("/ctl", 25),
        ("/bus", 30),
        ("/ctl", 40),
    ]
    contents = scan(main)
    assert contents.complete
    assert contents.metadata["run"] == {"a": "1", "b": "2"}
    assert contents.metadata["controller_stats"] == {"ticks": "4"}
    assert set(contents.attachments) == {"bus.txt", "ctl.txt"}
    with open(main, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    assert sorted(c.topic for c in summary.channels.values()) == ["/bus", "/ctl"]
    assert not (tmp_path / "run.mcap.tmp").exists()


def test_a_failed_merge_leaves_the_main_log_untouched(tmp_path: Path) -> None:
    main = tmp_path / "run.mcap"
    _json_log(main, "/bus", [0, 1], {})
    before = main.read_bytes()
    (tmp_path / "ctl.mcap").write_bytes(b"not an mcap file")
    with pytest.raises(Exception, match="not an MCAP"):
        merge_into(main, [tmp_path / "ctl.mcap"])
    assert main.read_bytes() == before
    assert not (tmp_path / "run.mcap.tmp").exists()


def test_a_summary_refuses_a_collector_that_would_leave_out_bus_channels(tmp_path: Path) -> None:
    from tools.metrics.tracking import BusCollector
    from tools.run.summary import build_summary

    with pytest.raises(ValueError, match="every /can/ channel"):
        build_summary(tmp_path, None, None, 0.0, BusCollector(["Bench_Truth_Pose"]))  # type: ignore[arg-type]


def test_a_log_cut_anywhere_is_reported_cut_off_not_damaged(tmp_path: Path) -> None:
    """Wherever a killed writer stopped (inside a record's header, its body or between two
    records), the log reads as far as it is whole and says it is cut off."""
    whole = tmp_path / "whole.mcap"
    _write(whole, _frames())
    data = whole.read_bytes()
    with warnings.catch_warnings():
        warnings.simplefilter("error", mcap_io.TruncatedLogWarning)
        n_whole = sum(1 for _ in mcap_io.iter_records(whole))  # a whole log: no warning
    cut = tmp_path / "cut.mcap"
    for at in range(9, len(data) - 1, max(1, len(data) // 150)):
        cut.write_bytes(data[:at])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            n_cut = sum(1 for _ in mcap_io.iter_records(cut))
        text = " ".join(str(w.message) for w in caught)
        assert "cut off" in text and "damaged" not in text, (at, text)
        assert n_cut < n_whole


def test_a_long_log_keeps_its_chunk_indexes_compact_and_readable(tmp_path: Path) -> None:
    # a real-time recorder closes a chunk every 50 ms: its summary's chunk indexes stay in
    # memory until it closes; serialized, they cost ~100 bytes each (objects: ~600)
    import tracemalloc

    from mcap.reader import make_reader

    from dbc.runtime.mcapwriter import LogWriter

    path = tmp_path / "many-chunks.mcap"
    w = LogWriter(path, flush_interval_s=0, chunk_size=200)
    sid = w.register_schema("s", "jsonschema", b"{}")
    cid = w.register_channel("/a", "json", sid)
    data = b'{"x": 1}' * 8
    for i in range(200):
        w.add_message(cid, i, i, data)
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for i in range(200, 20200):
        w.add_message(cid, i, i, data)
    grown = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    w.close()
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    chunks = summary.statistics.chunk_count
    assert chunks == len(summary.chunk_indexes) > 5000
    assert grown / chunks < 200  # bytes per chunk kept until close
    with path.open("rb") as f:
        assert sum(1 for _ in make_reader(f).iter_messages()) == 20200
