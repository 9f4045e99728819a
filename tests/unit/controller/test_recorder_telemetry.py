"""The controller's side of the log: tick records become Foxglove and internals channels."""

from __future__ import annotations

import json
import logging
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from mcap.reader import make_reader

from controller.clock import ClockStats
from controller.telemetry import TICK_TOPIC, McapTelemetry
from dbc import logschema as ls
from tools.live.appschema import foxglove_refusal
from tools.logs.mcap_io import iter_messages

MS = 1_000_000


def _tick_record(k: int) -> dict[str, Any]:
    """The shape of controller/node.py's per-tick record."""
    return {
        "route_time_s": 0.01 * k,
        "ref": {"x": 1.0 + k, "y": 2.0, "heading": 0.5, "v": 0.4, "omega": 0.0},
        "est": {"x": 1.1 + k, "y": 2.1, "heading": 0.4, "v": 0.39, "omega": 0.01},
        "err": {"x_e": 0.1, "y_e": -0.05, "phi_e": math.nan},
        "cmd_raw": {"v": 0.5, "omega": 0.1},
        "cmd": {"v": 0.45, "omega": 0.1, "wheel_left_radps": 1.4, "wheel_right_radps": 1.6},
        "step_us": 12.5,
        "internals": {"s1": 0.3, "qp.status": 1.0, "qp.iterations": 25.0, "bank.p_nominal": 0.9},
    }


class _FakeClock:
    """Ticks at 0, 10, 20 ms (lock-step) or at a real-time schedule with lateness."""

    def __init__(self, lockstep: bool) -> None:
        self.lockstep = lockstep
        self.period_ns = 10 * MS
        self.stats = ClockStats()
        self.ended_by = "test"
        self._t = [0, 10 * MS, 20 * MS]

    def start(self) -> None:
        pass

    def wait_tick(self, on_frame: Any) -> int | None:
        if not self._t:
            return None
        if not self.lockstep:
            self.stats.lateness_ns.append(40_000)
        return self._t.pop(0)

    def tick_done(self, t_ns: int) -> None:
        pass


def _run(path: Path, lockstep: bool = True, pose_every: int = 1) -> None:
    tel = McapTelemetry(path, pose_every=pose_every)
    _ticks(tel, lockstep)
    tel.metadata("controller_stats", {"ticks": "3"})
    tel.close()


def _ticks(tel: Any, lockstep: bool) -> None:
    """Three ticks of the fake clock through ``tel``, with a log line in the second."""
    clock = tel.wrap_clock(_FakeClock(lockstep))
    clock.start()
    log = logging.getLogger("controller.node")
    while (t := clock.wait_tick(lambda m: None)) is not None:
        if t == 10 * MS:
            log.warning("safe stop: %s", "ENCODER_STALE")
        clock.tick_done(t)
        tel.log(TICK_TOPIC, t, _tick_record(t // (10 * MS)))
    assert clock.ended_by == "test"  # the wrapped clock's attributes are still there


def _topics(path: Path) -> dict[str, list[Any]]:
    out: dict[str, list[Any]] = defaultdict(list)
    for ch, m in iter_messages(path):
        out[ch.topic].append(m)
    return out


def test_tick_records_are_split_into_the_layouts_channels(tmp_path: Path) -> None:
    _run(tmp_path / "c.mcap")
    t = _topics(tmp_path / "c.mcap")
    assert [m.log_time for m in t["/controller/errors"]] == [0, 10 * MS, 20 * MS]
    err = json.loads(t["/controller/errors"][0].data)
    assert err == {"x_e": 0.1, "y_e": -0.05, "phi_e": None}  # NaN is not JSON: null
    est = json.loads(t["/controller/estimate"][1].data)
    assert est["x"] == pytest.approx(2.1)
    pose = json.loads(t["/controller/estimate/pose"][1].data)
    assert pose["frame_id"] == ls.WORLD_FRAME
    assert pose["pose"]["position"]["x"] == pytest.approx(2.1)
    tf = json.loads(t["/controller/reference/tf"][2].data)
    assert tf["child_frame_id"] == ls.REFERENCE_FRAME
    assert tf["translation"]["x"] == pytest.approx(3.0)
    cmd = json.loads(t["/controller/command"][0].data)
    assert cmd["wheel_right_radps"] == 1.6 and cmd["raw"] == {"v": 0.5, "omega": 0.1}
    assert json.loads(t["/controller/internals"][0].data) == {"s1": 0.3}
    assert json.loads(t["/controller/internals/qp"][0].data) == {
        "status": 1.0,
        "iterations": 25.0,
    }
    assert json.loads(t["/controller/internals/bank"][0].data) == {"p_nominal": 0.9}
    assert json.loads(t[TICK_TOPIC][0].data) == {"route_time_s": 0.0, "step_us": 12.5}


def test_every_tick_is_timed_and_controller_log_lines_become_foxglove_logs(
    tmp_path: Path,
) -> None:
    _run(tmp_path / "c.mcap")
    t = _topics(tmp_path / "c.mcap")
    loop = [json.loads(m.data) for m in t["/controller/loop"]]
    assert len(loop) == 3 and all(r["tick_us"] >= 0 for r in loop)
    assert "lateness_us" not in loop[0]  # lock-step has no schedule to be late against
    logs = t["/controller/log"]
    assert len(logs) == 1 and logs[0].log_time == 10 * MS
    rec = json.loads(logs[0].data)
    assert rec["level"] == ls.LogLevel.WARNING
    assert rec["message"] == "safe stop: ENCODER_STALE"
    assert rec["name"] == "controller.node" and rec["line"] > 0


def test_real_time_ticks_carry_lateness_and_wall_clock_log_times(tmp_path: Path) -> None:
    _run(tmp_path / "c.mcap", lockstep=False)
    t = _topics(tmp_path / "c.mcap")
    loop = [(m.log_time, json.loads(m.data)) for m in t["/controller/loop"]]
    assert all(r["lateness_us"] == 40.0 for _t, r in loop)
    assert loop[0][0] > 1_000_000_000 * 1_000_000_000  # epoch ns, like the recorder's
    assert loop[1][0] - loop[0][0] == 10 * MS


def test_foxglove_poses_are_decimated_while_the_json_channels_keep_every_tick(
    tmp_path: Path,
) -> None:
    _run(tmp_path / "c.mcap", pose_every=2)
    t = _topics(tmp_path / "c.mcap")
    assert [m.log_time for m in t["/controller/estimate"]] == [0, 10 * MS, 20 * MS]
    assert [m.log_time for m in t["/controller/estimate/pose"]] == [0, 20 * MS]
    assert [m.log_time for m in t["/controller/reference/tf"]] == [0, 20 * MS]


def test_the_handler_is_removed_when_the_log_closes(tmp_path: Path) -> None:
    before = list(logging.getLogger("controller").handlers)
    _run(tmp_path / "c.mcap")
    assert logging.getLogger("controller").handlers == before


def _without_nulls(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _without_nulls(x) for k, x in v.items() if x is not None}
    if isinstance(v, list):
        return [_without_nulls(x) for x in v]
    return v


def test_controller_channels_validate_against_foxglove_schemas(tmp_path: Path) -> None:
    _run(tmp_path / "c.mcap")
    n = 0
    with open(tmp_path / "c.mcap", "rb") as fh:
        reader = make_reader(fh)
        for schema, _ch, m in reader.iter_messages():
            assert schema is not None
            data = json.loads(m.data)  # every message is valid JSON (no NaN)
            # a non-finite number is null (docs/logs.md); the schemas say number, so that
            # Foxglove takes the channel (tools/live/appschema.py)
            jsonschema.validate(_without_nulls(data), json.loads(schema.data))
            assert foxglove_refusal("json", schema.encoding, schema.data) is None, _ch.topic
            n += schema.name.startswith("foxglove.")
        md = {r.name: r.metadata for r in reader.iter_metadata()}
    assert n == 13  # 4 poses/transforms per tick, one log line
    assert md["controller_stats"] == {"ticks": "3"}
