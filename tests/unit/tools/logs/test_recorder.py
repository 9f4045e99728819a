"""The bus recorder: every channel round-trips, lock-step stamping, Foxglove schemas, crash safety."""

from __future__ import annotations

import json
import math
import threading
import uuid
import warnings
from collections import defaultdict
from pathlib import Path
from typing import Any

import can
import jsonschema
import pytest
from mcap.reader import make_reader

from dbc import logschema as ls
from dbc.codec import (
    AxisState,
    BenchEnd,
    BenchStep,
    BenchStepAck,
    Codec,
    EncoderEstimates,
    GetError,
    Heartbeat,
    HostHeartbeat,
    HostState,
    Iq,
    Node,
    PoseFix,
    RecordAck,
    SetAxisState,
    SetInputVel,
    SetInputVelAuth,
    Torques,
    TruthPose,
    TruthTwist,
    TruthWheels,
    Version,
)
from dbc.errors import DecodeError
from dbc.runtime.mcapwriter import LogWriter
from tools.live.appschema import foxglove_refusal
from tools.logs.mcap_io import TruncatedLogWarning, iter_frames, iter_messages
from tools.logs.recorder import BusRecorder, FrameLog

CODEC = Codec.default()
MS = 1_000_000
L, R = Node.LEFT, Node.RIGHT


def _bus_traffic() -> list[tuple[str, can.Message]]:
    """Two lock-step ticks as they appear on the bus, each frame tagged with its expected tick."""
    out: list[tuple[str, can.Message]] = []

    def add(tag: str, payload: Any, node: Node | None = None) -> None:
        out.append((tag, CODEC.encode(payload, node)))

    for t, (state, hs) in enumerate(
        [(AxisState.IDLE, HostState.ARMING), (AxisState.CLOSED_LOOP_CONTROL, HostState.TRACKING)]
    ):
        tick = f"t{t}"
        add(tick, Heartbeat(0, state), L)
        add(tick, Heartbeat(0, state), R)
        add(tick, EncoderEstimates(0.25 * t, 0.5), L)
        add(tick, EncoderEstimates(0.5 * t, -0.5), R)
        add(tick, PoseFix(1.0, 2.0, 0.1), Node.LOCALIZER)
        add(tick, BenchStep(t * 10 * MS))
        if t == 0:
            add(tick, SetAxisState(AxisState.CLOSED_LOOP_CONTROL), L)
            add(tick, SetInputVel(0.0), L)
            add(tick, SetInputVel(0.0), R)
            out.append((tick, CODEC.request(Iq, L)))  # an RTR poll
        else:
            add(tick, SetInputVelAuth(0.75, 0.75, 3, 0x1234), L)
            # ODrive answers the recorder decodes too: versions, torques, several error bits
            add(tick, Version(2, 4, 4, 58, 0, 6, 10, 0), L)
            add(tick, Torques(0.5, 0.25), R)
            add(tick, GetError(0x1000040 | 0x80000000, 0x1000000), L)
            bad = bytearray(CODEC.encode(SetInputVelAuth(0.75, 0.75, 4, 0), R).data)
            bad[0:2] = b"\x00\x80"  # Input_Vel raw -32768: outside its range, raw only
            out.append(
                (
                    tick,
                    can.Message(
                        arbitration_id=CODEC.frame_id(SetInputVelAuth, R),
                        data=bad,
                        is_extended_id=False,
                    ),
                )
            )
        add(tick, HostHeartbeat(hs, t + 1, 0.01 * t, 0), Node.HOST)
        add(tick, BenchStepAck(t * 10 * MS))
        # after the ack: the ground truth describes t, everything else is the next step
        add(tick, TruthPose(1.0 + t, -2.0, 0.5 * math.pi))
        add(tick, TruthTwist(0.5, 0.1))
        add(tick, TruthWheels(0.3, 0.3, 1.0, 1.0))
        out.append(
            (f"t{t + 1}", can.Message(arbitration_id=0x7F0, data=b"\x01", is_extended_id=False))
        )
    add("t2", BenchEnd(20 * MS))
    for i, (_tag, m) in enumerate(out):
        m.timestamp = 1_700_000_000.0 + i * 1e-4
        m.channel = "vbus"
    return out


def _record(path: Path, traffic: list[tuple[str, can.Message]], **kw: Any) -> FrameLog:
    log = FrameLog(LogWriter(path, **kw), lockstep=True)
    for _tag, m in traffic:
        log.record(m)
    log.close()
    return log


def _by_topic(path: Path) -> dict[str, list[Any]]:
    out: dict[str, list[Any]] = defaultdict(list)
    for ch, m in iter_messages(path):
        out[ch.topic].append(m)
    return out


def test_every_raw_frame_round_trips_in_bus_order(tmp_path: Path) -> None:
    traffic = _bus_traffic()
    _record(tmp_path / "x.mcap", traffic)
    back = [m for _t, m in iter_frames(tmp_path / "x.mcap", timestamps="receive")]
    assert len(back) == len(traffic)
    for (_tag, a), b in zip(traffic, back, strict=True):
        assert (b.arbitration_id, b.is_extended_id, b.is_remote_frame, b.dlc, bytes(b.data)) == (
            a.arbitration_id,
            a.is_extended_id,
            a.is_remote_frame,
            a.dlc,
            bytes(a.data),
        )
        assert b.timestamp == a.timestamp
        assert b.channel == "vbus"


def test_lockstep_log_times_follow_the_tick_each_frame_belongs_to(tmp_path: Path) -> None:
    traffic = _bus_traffic()
    _record(tmp_path / "x.mcap", traffic)
    times = [t for t, _m in iter_frames(tmp_path / "x.mcap")]
    expected = [int(tag[1:]) * 10 * MS for tag, _m in traffic]
    assert times == expected


def test_every_decoded_channel_round_trips_with_units_and_labels(tmp_path: Path) -> None:
    traffic = _bus_traffic()
    _record(tmp_path / "x.mcap", traffic)
    topics = _by_topic(tmp_path / "x.mcap")
    expected: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for _tag, m in traffic:
        try:
            name, values = CODEC.decode_signals(m)
        except DecodeError:
            continue
        if m.is_remote_frame:
            continue
        rec: dict[str, Any] = dict(values)
        for s in CODEC.describe_signals(name):
            if s["choices"] and s["flags"]:
                rec[s["name"] + "_label"] = ls.flags_label(values[s["name"]], s["choices"])
            elif s["choices"]:
                rec[s["name"] + "_label"] = s["choices"][int(values[s["name"]])]
        expected[name].append(rec)
    assert expected  # the traffic has decodable frames of many kinds
    for name, recs in expected.items():
        got = [json.loads(m.data) for m in topics[f"/can/{name}"]]
        assert got == recs, name
    with open(tmp_path / "x.mcap", "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    schemas = {ch.topic: summary.schemas[ch.schema_id] for ch in summary.channels.values()}
    vel = json.loads(schemas["/can/Left_Get_Encoder_Estimates"].data)
    assert "[rev/s]" in vel["properties"]["Vel_Estimate"]["description"]
    hb = json.loads(schemas["/can/Host_Heartbeat"].data)
    assert "TRACKING" in hb["properties"]["Host_State_label"]["enum"]
    (err,) = (json.loads(m.data) for m in topics["/can/Left_Get_Error"])
    assert err["Active_Errors_label"] == "MISSING_INPUT|WATCHDOG_TIMER_EXPIRED|0x80000000"
    assert err["Disarm_Reason_label"] == "WATCHDOG_TIMER_EXPIRED"
    assert (
        "enum"
        not in json.loads(schemas["/can/Left_Get_Error"].data)["properties"]["Active_Errors_label"]
    )
    assert [json.loads(m.data)["Fw_Version_Revision"] for m in topics["/can/Left_Get_Version"]] == [
        10
    ]
    # the rejected frame is on /can/raw only; the RTR poll too
    assert len(topics["/can/Right_Set_Input_Vel_Auth"]) == 0
    assert "/can/Left_Get_Iq" not in topics


def test_truth_poses_joint_states_and_events_are_derived(tmp_path: Path) -> None:
    _record(tmp_path / "x.mcap", _bus_traffic())
    topics = _by_topic(tmp_path / "x.mcap")
    poses = [json.loads(m.data) for m in topics["/truth/pose"]]
    assert [p["pose"]["position"]["x"] for p in poses] == pytest.approx([1.0, 2.0], abs=1e-3)
    q = poses[0]["pose"]["orientation"]
    assert 2.0 * math.atan2(q["z"], q["w"]) == pytest.approx(0.5 * math.pi, abs=1e-3)
    assert [m.log_time for m in topics["/truth/pose"]] == [0, 10 * MS]
    tf = json.loads(topics["/truth/tf"][1].data)
    assert (tf["parent_frame_id"], tf["child_frame_id"]) == (ls.WORLD_FRAME, ls.TRUTH_FRAME)
    assert tf["translation"]["x"] == pytest.approx(2.0, abs=1e-3)
    js = [json.loads(m.data) for m in topics["/wheels/joint_states"]]
    assert len(js) == 2
    joints = {j["name"]: j for j in js[1]["joints"]}
    assert joints["left_wheel"]["position"] == pytest.approx(0.25 * 2 * math.pi, rel=1e-6)
    assert joints["right_wheel"]["velocity"] == pytest.approx(-0.5 * 2 * math.pi, rel=1e-6)
    events = [json.loads(m.data) for m in topics["/events"]]
    texts = [e["message"] for e in events]
    assert "host state - -> ARMING" in texts
    assert "host state ARMING -> TRACKING" in texts
    assert "drive LEFT state IDLE -> CLOSED_LOOP_CONTROL" in texts
    assert any(t.startswith("rejected frame") and "outside" in t for t in texts)
    assert any(t.startswith("rejected frame") and "unknown frame ID" in t for t in texts)
    assert texts[-1].startswith("bench ended the run")


def test_foxglove_channels_validate_against_the_published_schemas(tmp_path: Path) -> None:
    _record(tmp_path / "x.mcap", _bus_traffic())
    checked = 0
    with open(tmp_path / "x.mcap", "rb") as fh:
        for schema, _ch, m in make_reader(fh).iter_messages():
            if schema is None or not schema.name.startswith("foxglove."):
                continue
            assert schema.data == ls.foxglove_schema(schema.name)
            jsonschema.validate(json.loads(m.data), json.loads(schema.data))
            checked += 1
    assert checked >= 9


def test_every_channel_of_the_log_has_a_schema_foxglove_takes(tmp_path: Path) -> None:
    # Foxglove refuses a channel whose JSON schema gives a field a list of types; /can/raw
    # had "channel": ["string", "null"] and was not shown at all (tools/live/appschema.py)
    traffic = _bus_traffic()
    traffic[0][1].channel = None  # python-can's Message without a channel
    _record(tmp_path / "x.mcap", traffic)
    topics = 0
    with open(tmp_path / "x.mcap", "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    for ch in summary.channels.values():
        schema = summary.schemas[ch.schema_id]
        assert foxglove_refusal(ch.message_encoding, schema.encoding, schema.data) is None, ch.topic
        topics += 1
    assert topics > 10
    raw = _by_topic(tmp_path / "x.mcap")["/can/raw"]
    first, second = json.loads(raw[0].data), json.loads(raw[1].data)
    assert "channel" not in first and second["channel"] == "vbus"
    for rec in (first, second):
        jsonschema.validate(rec, ls.RAW_SCHEMA)
    back = [m for _t, m in iter_frames(tmp_path / "x.mcap", timestamps="receive")]
    assert (back[0].channel, back[1].channel) == (None, "vbus")


def test_a_foxglove_schema_rejects_json_that_foxglove_would_not_read() -> None:
    schema = json.loads(ls.foxglove_schema("foxglove.Log"))
    good = json.loads(ls.log_message(5, ls.LogLevel.WARNING, 'say "hi"', "x"))
    jsonschema.validate(good, schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**good, "level": 9}, schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({k: v for k, v in good.items() if k != "name"}, schema)


def test_signals_the_recorder_derives_from_exist_in_the_dbc() -> None:
    pose = {s["name"] for s in CODEC.describe_signals(CODEC.message_name(TruthPose))}
    assert set(ls.TRUTH_POSE_SIGNALS) <= pose
    for n in (L, R):
        enc = {s["name"] for s in CODEC.describe_signals(CODEC.message_name(EncoderEstimates, n))}
        assert set(ls.ENCODER_SIGNALS) <= enc


def test_log_carries_versions_attachments_and_recorder_statistics(tmp_path: Path) -> None:
    channel = f"rec-{uuid.uuid4()}"
    traffic = _bus_traffic()
    with (
        can.Bus(interface="virtual", channel=channel) as rx,
        can.Bus(interface="virtual", channel=channel) as tx,
    ):
        rec = BusRecorder(
            rx,
            tmp_path / "run.mcap",
            lockstep=True,
            attachments={"wheelchair.dbc": b"VERSION x"},
            metadata={"run": {"controller": "baseline"}},
            ack_every_steps=0,  # flow control has its own test
        )
        th = threading.Thread(target=rec.run, kwargs={"drain_s": 0.0})
        th.start()
        for _tag, m in traffic:
            tx.send(m)
        th.join(10)
    assert not th.is_alive()
    with open(tmp_path / "run.mcap", "rb") as fh:
        reader = make_reader(fh)
        md = {m.name: m.metadata for m in reader.iter_metadata()}
        atts = {a.name: a.data for a in reader.iter_attachments()}
    assert atts == {"wheelchair.dbc": b"VERSION x"}
    assert md["run"] == {"controller": "baseline"}
    assert md["versions"]["python-can"] and md["versions"]["mcap"]
    assert json.loads(md["recorder"]["frames"]) == len(traffic)
    assert json.loads(md["recorder"]["rejected"]) == {"range": 1, "unknown_id": 2}
    assert rec.stats.ended_by == "Bench_End"


# --------------------------------------------------------------------- crash safety


def _many_frames(n: int) -> list[can.Message]:
    out = []
    for i in range(n):
        m = CODEC.encode(EncoderEstimates(i * 1e-3, 0.5), L if i % 2 else R)
        m.timestamp = 1_700_000_000.0 + i * 1e-3
        out.append(m)
    return out


def test_an_unclosed_log_is_readable_up_to_its_last_chunk(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    w = LogWriter(path, chunk_size=4096, flush_interval_s=0.0)
    log = FrameLog(w, lockstep=False)
    frames = _many_frames(2100)
    for i, m in enumerate(frames):
        log.record(m)
        if i >= 2000 and w.message_count > w._messages:  # a chunk is in progress
            frames = frames[: i + 1]
            break
    # no close(): what a process killed here leaves on disk
    in_flight = w.message_count - w._messages
    with pytest.warns(TruncatedLogWarning, match="killed"):
        back = [m for _t, m in iter_frames(path)]
    assert 0 < len(frames) - len(back) <= in_flight
    assert [bytes(b.data) for b in back] == [bytes(m.data) for m in frames[: len(back)]]
    w.close()


def test_a_truncated_log_is_read_as_far_as_it_is_intact(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    w = LogWriter(path, chunk_size=2048, flush_interval_s=0.0)
    log = FrameLog(w, lockstep=False)
    frames = _many_frames(1000)
    for m in frames:
        log.record(m)
    log.close()
    data = path.read_bytes()
    counts = []
    for cut in (len(data) // 3, len(data) // 2, len(data) - 100):
        (tmp_path / "cut.mcap").write_bytes(data[:cut])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            back = [m for _t, m in iter_frames(tmp_path / "cut.mcap")]
        assert any(issubclass(c.category, TruncatedLogWarning) for c in caught), cut
        assert [bytes(b.data) for b in back] == [bytes(m.data) for m in frames[: len(back)]]
        counts.append(len(back))
    assert counts == sorted(counts) and counts[0] > 0
    assert counts[-1] >= len(frames) - 60  # only the tail: the summary and maybe the last chunk


def test_a_damaged_chunk_stops_reading_with_a_warning_naming_the_crc(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    w = LogWriter(path, chunk_size=2048, flush_interval_s=0.0, compression="")
    log = FrameLog(w, lockstep=False)
    for m in _many_frames(500):
        log.record(m)
    log.close()
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x55
    path.write_bytes(bytes(data))
    with pytest.warns(TruncatedLogWarning, match="damaged.*crc"):
        back = list(iter_frames(path))
    assert 0 < len(back) < 500


def test_chunks_close_after_the_flush_interval_even_when_the_bus_is_quiet(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    w = LogWriter(path, chunk_size=1 << 20, flush_interval_s=1e-9)
    s = w.register_schema("s", "jsonschema", b"{}")
    c = w.register_channel("/a", "json", s)
    w.add_message(c, 1, 1, b"{}")  # already older than the interval: written at once
    with pytest.warns(TruncatedLogWarning):
        assert len(list(iter_messages(path))) == 1
    w.close()


def test_logwriter_output_reads_back_through_mcap_indexes(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    _record(path, _bus_traffic(), chunk_size=512)
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.chunk_count > 3
        by_index = sum(1 for _ in reader.iter_messages(topics=["/can/raw"]))
        total = sum(1 for _ in reader.iter_messages())
    assert by_index == len(_bus_traffic())
    assert total == summary.statistics.message_count == len(list(iter_messages(path)))


def test_missing_bench_steps_are_counted_and_reported(tmp_path: Path) -> None:
    log = FrameLog(LogWriter(tmp_path / "x.mcap"), lockstep=True)
    for t in (0, 10, 40, 50):
        log.record(CODEC.encode(BenchStep(t * MS)))
    log.close()
    assert log.stats.missed_steps == 2
    events = [json.loads(m.data)["message"] for m in _by_topic(tmp_path / "x.mcap")["/events"]]
    assert any("missed 2 Bench_Step" in e for e in events)


def test_a_recorder_ends_when_the_bench_falls_silent_without_bench_end(tmp_path: Path) -> None:
    channel = f"rec-{uuid.uuid4()}"
    with (
        can.Bus(interface="virtual", channel=channel) as rx,
        can.Bus(interface="virtual", channel=channel) as tx,
    ):
        rec = BusRecorder(rx, tmp_path / "run.mcap", lockstep=True, ack_every_steps=0)
        for t in (0, 10):
            tx.send(CODEC.encode(BenchStep(t * MS)))
        stats = rec.run(bench_silent_s=0.2)  # the Bench_End never comes
    assert "silent" in stats.ended_by
    assert stats.frames == 2


def test_a_lockstep_recorder_acknowledges_every_tenth_step_and_logs_its_own_acks(
    tmp_path: Path,
) -> None:
    channel = f"rec-{uuid.uuid4()}"
    with (
        can.Bus(interface="virtual", channel=channel) as rx,
        can.Bus(interface="virtual", channel=channel) as tx,
    ):
        rec = BusRecorder(rx, tmp_path / "run.mcap", lockstep=True)
        for k in range(25):
            tx.send(CODEC.encode(BenchStep(k * 10 * MS)))
        tx.send(CODEC.encode(RecordAck(7)))  # another recorder's ack: flow control, not logged
        tx.send(CODEC.encode(BenchEnd(250 * MS)))
        stats = rec.run(drain_s=0.0)
        acks = []
        while (m := tx.recv(0.2)) is not None:
            acks.append(CODEC.decode(m).payload.sim_time_ns)
    assert acks == [0, 100 * MS, 200 * MS]
    assert stats.by_name["Bench_Record_Ack"] == 3  # its own, each logged when sent
    assert stats.frames == 25 + 1 + 3
