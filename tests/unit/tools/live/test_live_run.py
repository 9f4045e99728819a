"""A real WebSocket client on a run's live view and on a replay: the log's channels and bytes.

The client (:mod:`tools.live.client`, the ``websockets`` package) connects before the run
starts, reads the server's ``serverInfo`` and ``advertise`` messages and subscribes to
every channel as it is advertised.  What it receives is checked against the MCAP of the
same run: the same channels with the same schemas, and every message it got is one the log
has, byte for byte and at the same log time.
"""

from __future__ import annotations

import itertools
import json
import threading
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from dbc.codec import Codec
from tools.bus.transport import resolve
from tools.cli import main as cli_main
from tools.live.address import LiveAddress
from tools.live.client import LiveClient, Received
from tools.live.playback import serve_log
from tools.live.server import LiveServer
from tools.live.view import LiveView
from tools.logs import mcap_io
from tools.run import scenario as scenario_mod
from tools.run.in_process import run_threads
from tools.run.plan import make_plan
from tools.run.summary import build_summary

_channel = itertools.count()

#: Channels a person watching the chair needs, one of each kind the log has.
WATCHED = (
    "/can/raw",
    "/can/Left_Get_Encoder_Estimates",
    "/truth/pose",
    "/truth/tf",
    "/wheels/joint_states",
    "/events",
    "/controller/estimate/pose",
    "/controller/estimate/tf",
    "/controller/reference/pose",
    "/controller/internals",
    "/controller/errors",
    "/controller/command",
    "/controller/loop",
)
#: What flows on every tick of a real-time run whatever the controller does: under load a
#: real-time run can end in a safe stop before the controller tracks (an encoder late by
#: 190 ms beside two busy workers), and its estimate and reference channels then stay empty.
EVERY_TICK = (
    "/can/raw",
    "/can/Left_Get_Encoder_Estimates",
    "/truth/pose",
    "/truth/tf",
    "/wheels/joint_states",
    "/controller/loop",
)


def _run_live(out: Path, *, realtime: bool, duration_s: float) -> tuple[Received, dict[str, Any]]:
    """One run on the virtual bus with a live view and a client; its log is finalized."""
    plan = make_plan(
        scenario_mod.load("short"), "baseline", realtime=realtime, duration_s=duration_s
    )
    spec = resolve("virtual", f"live{next(_channel)}")
    out.mkdir(parents=True, exist_ok=True)
    with LiveServer(LiveAddress("127.0.0.1", 0)) as live:
        client = LiveClient(live.url).start()
        try:
            run_threads(spec, plan, out, Codec.default(), live=live)
        finally:
            # the feeds are closed with their logs; what they sent is served before the view ends
            live.stop()
            received = client.join(10.0)
    assert client.error is None
    build_summary(out, plan, spec, 0.0)
    return received, live.stats


def _logged(path: Path) -> tuple[mcap_io.LogContents, Counter[tuple[str, int, bytes]]]:
    messages: Counter[tuple[str, int, bytes]] = Counter()

    def take(ch: Any, msg: Any) -> None:
        messages[(ch.topic, msg.log_time, bytes(msg.data))] += 1

    return mcap_io.scan(path, take), messages


def _check_against_log(
    received: Received, run_dir: Path, watched: tuple[str, ...] = WATCHED
) -> Counter[tuple[str, int, bytes]]:
    contents, logged = _logged(run_dir / "run.mcap")
    assert received.server_info.get("op") == "serverInfo"
    # the same channels, with the log's encodings and schemas
    by_topic = {c.topic: c for c in contents.channels.values()}
    advertised = {c["topic"]: c for c in received.channels.values()}
    assert set(advertised) == set(by_topic)
    for topic, ad in advertised.items():
        ch = by_topic[topic]
        schema = contents.schemas[ch.schema_id]
        assert ad["encoding"] == ch.message_encoding, topic
        assert ad["schemaName"] == schema.name, topic
        assert ad["schemaEncoding"] == schema.encoding, topic
        assert json.loads(ad["schema"]) == json.loads(schema.data), topic
    # every message received is in the log: same channel, log time and bytes
    got = Counter(received.messages)
    extra = got - logged
    assert not extra, f"{sum(extra.values())} messages not in the log, e.g. {next(iter(extra))}"
    counts = received.counts()
    missing = [t for t in watched if counts[t] == 0]
    assert not missing, f"no message received on {missing}"
    assert received.unknown == 0
    return logged


@pytest.fixture(scope="module")
def lockstep_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Received, dict[str, Any]]:
    out = tmp_path_factory.mktemp("live-lockstep")
    received, stats = _run_live(out, realtime=False, duration_s=4.0)
    return out, received, stats


def test_client_of_a_lockstep_run_gets_the_logs_channels_and_bytes(
    lockstep_run: tuple[Path, Received, dict[str, Any]],
) -> None:
    out, received, _ = lockstep_run
    _check_against_log(received, out)


def test_view_serves_every_logged_message_or_counts_it_dropped(
    lockstep_run: tuple[Path, Received, dict[str, Any]],
) -> None:
    out, _, stats = lockstep_run
    _, logged = _logged(out / "run.mcap")
    assert stats["unknown_channel"] == 0 and stats["bad_datagrams"] == 0
    assert stats["feeds"] == 2  # the recorder's and the controller's
    assert stats["messages"] + stats["feed_dropped"] == sum(logged.values())
    per_topic = Counter(topic for topic, _, _ in logged.elements())
    for topic, n in stats["by_topic"].items():
        assert n <= per_topic[topic], topic


def test_client_of_a_realtime_run_gets_the_logs_channels_and_bytes(tmp_path: Path) -> None:
    received, stats = _run_live(tmp_path, realtime=True, duration_s=2.0)
    _check_against_log(received, tmp_path, EVERY_TICK)
    assert stats["feed_dropped"] == 0  # 100 Hz fits the feeds' queues many times over


def test_replay_serves_the_whole_log_at_its_pace(
    lockstep_run: tuple[Path, Received, dict[str, Any]],
) -> None:
    out, _, _ = lockstep_run
    views: list[LiveView] = []
    ready = threading.Event()
    result: dict[str, Any] = {}

    def serve() -> None:
        def on_ready(view: LiveView) -> None:
            views.append(view)
            ready.set()

        try:
            result["counts"] = serve_log(
                out / "run.mcap", LiveAddress("127.0.0.1", 0), speed=4.0, on_ready=on_ready
            )
        finally:
            ready.set()

    server = threading.Thread(target=serve, daemon=True)
    server.start()
    assert ready.wait(20.0) and views
    # playback waits for the client's subscriptions: it gets the log from its first message
    received = LiveClient(views[0].url).start().join(60.0)
    server.join(30.0)
    logged = _check_against_log(received, out)
    assert received.counts() == Counter(topic for topic, _, _ in logged.elements())
    assert result["counts"] == received.counts()


def test_live_option_errors_name_the_text(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli_main(["replay", "run.mcap", "--live", "host:port"])
    assert "--live 'host:port': PORT must be an integer" in capsys.readouterr().err


def test_replay_live_does_not_go_with_verify(
    lockstep_run: tuple[Path, Received, dict[str, Any]], capsys: pytest.CaptureFixture[str]
) -> None:
    out, _, _ = lockstep_run
    assert cli_main(["replay", str(out / "run.mcap"), "--live", "0", "--verify"]) == 2
    assert "does not go with --verify" in capsys.readouterr().err


def test_run_live_prints_the_address_and_writes_what_it_served(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["run", "--bus", "virtual", "--scenario", "short", "--duration", "2"]
    assert cli_main([*argv, "--live", "127.0.0.1:0", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert "live: ws://127.0.0.1:" in err
    stats = json.loads((tmp_path / "live_stats.json").read_text())
    assert f"live: served {stats['messages']} messages on {len(stats['by_topic'])} channels" in err
    assert stats["feeds"] == 2
    assert "/controller/estimate/pose" in stats["by_topic"] and "/can/raw" in stats["by_topic"]


def test_replay_live_with_a_bus_serves_and_retransmits_together(
    lockstep_run: tuple[Path, Received, dict[str, Any]], capsys: pytest.CaptureFixture[str]
) -> None:
    out, _, _ = lockstep_run
    log = out / "run.mcap"
    argv = ["replay", str(log), "--bus", "virtual", "--live", "127.0.0.1:0", "--no-wait"]
    assert cli_main([*argv, "--speed", "20"]) == 0
    captured = capsys.readouterr()
    assert "live: ws://127.0.0.1:" in captured.err
    contents, logged = _logged(log)
    frames = sum(1 for topic, _, _ in logged.elements() if topic == "/can/raw")
    assert (
        f"served {sum(logged.values())} messages on {len(contents.channels)} channels"
        in captured.out
    )
    assert f"replayed {frames} frames on virtual" in captured.out
