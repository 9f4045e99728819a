"""The live view with the Foxglove app's own client: ``tests/repro/foxglove_client``.

``check.mjs`` connects with npm ``@foxglove/ws-protocol``'s ``FoxgloveClient``, offering
the app's subprotocols, subscribes to every channel when it is advertised, reads each
channel's schema by the app's rules, decodes every message, validates it against the
advertised schema and, for ``foxglove.*`` schemas, against Foxglove's published one
(npm ``@foxglove/schemas``), and watches the server's clock as the app uses it.  Here it
watches a real-time run (``run --live`` over udp_multicast: separate processes in a private
network namespace, the view outside it, where Foxglove on the machine reaches it) and then
a replay of that run's log (``replay --live``, which waits for the client, so it must get
every message of the log).

It needs node, npm and the repro's packages (``npm ci`` in ``tests/repro/foxglove_client``);
without them it skips and says which is missing, and in CI that skip fails (tests/conftest.py):
``.ci/run`` installs them.  The Python side of each rule is tested in ``tests/unit/tools/live``.
"""

from __future__ import annotations

import json
import re
import shutil
import socket
import subprocess
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from tests.rt import rt
from tools.bus import transport
from tools.logs import mcap_io

# one client check for the module's tests (a module fixture: make test gives a `paired` file's
# tests to one worker).  Paired: the controller on SCHED_FIFO, the bench above it; the client
# must get every message whatever runs beside it (it did beside two spinning processes)
pytestmark = [pytest.mark.hil, pytest.mark.alone, pytest.mark.paired]

REPRO = Path(__file__).resolve().parents[1] / "repro" / "foxglove_client"
_PACKAGES = ("@foxglove/ws-protocol", "@foxglove/schemas", "ajv", "ws")


def _node_missing() -> str | None:
    missing = [tool for tool in ("node", "npm") if shutil.which(tool) is None]
    if missing:
        return f"{' and '.join(missing)} not on PATH (the repro runs on node)"
    absent = [p for p in _PACKAGES if not (REPRO / "node_modules" / p / "package.json").exists()]
    if absent:
        return (
            f"the repro's node_modules lack {', '.join(absent)}: run `npm ci` in {REPRO} "
            "(npm registry access needed once)"
        )
    return None


NODE_WHY = _node_missing()
SANDBOX_OK, SANDBOX_WHY = transport.sandbox_supported()
needs_node = pytest.mark.skipif(NODE_WHY is not None, reason=f"Foxglove client check: {NODE_WHY}")
needs_sandbox = pytest.mark.skipif(
    not SANDBOX_OK, reason=f"no private network namespace: {SANDBOX_WHY}"
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _client(port: int, out: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [
            "node",
            str(REPRO / "check.mjs"),
            f"ws://127.0.0.1:{port}",
            "--connect-s",
            "120",
            "--seconds",
            "600",
            "--json",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _serve_and_check(server_cmd: list[str], port: int, out: Path) -> dict[str, Any]:
    """Start the client (it retries until the view listens), then the server; the report."""
    client = _client(port, out)
    try:
        server = subprocess.run(
            server_cmd, capture_output=True, text=True, timeout=600, check=False
        )
        _, client_err = client.communicate(timeout=60)  # it ends when the server closes
    finally:
        if client.poll() is None:
            client.kill()
            client.wait()
    assert server.returncode == 0, server.stderr[-3000:]
    report: dict[str, Any] = json.loads(out.read_text())
    assert report["connected"], (report.get("connectError"), client_err)
    sdk = _sdk_unknown_channel(report)
    if client.returncode != 0 and sdk and len(sdk) == len(report["failures"]):
        # every failure is foxglove-sdk's: see _sdk_unknown_channel
        pytest.xfail(
            f"foxglove-sdk refused the subscription to advertised channels {sdk} "
            "('Unknown channel ID', twice); docs/logs.md § live, known issue"
        )
    assert client.returncode == 0, "\n".join(report["failures"])
    return report


def _sdk_unknown_channel(report: dict[str, Any]) -> list[str]:
    """The failures that are foxglove-sdk 0.30.3's, not the view's: a channel the server
    advertised to this client and never unadvertised, whose subscription it refuses as an
    'Unknown channel ID', again when the client retries (check.mjs).  In about 1 run in 7
    beside a busy process; the channel the view created stays registered (its messages are
    served to the other clients and logged).  Any other failure, or this one with a retry
    that succeeded, is judged as such."""
    raced = {r["channel"] for r in report.get("subscribeRaces", [])}
    out = []
    for f in report["failures"]:
        m = re.fullmatch(r"server status \(level 2\): Unknown channel ID: (\d+)", f)
        if m and int(m.group(1)) in raced:
            out.append(f)
    return out


def _logged(path: Path) -> Counter[str]:
    return Counter(ch.topic for ch, _ in mcap_io.iter_messages(path))


def _assert_app_reads_everything(report: dict[str, Any], logged: Counter[str]) -> None:
    assert report["subprotocol"] == "foxglove.sdk.v1"
    assert report["serverInfo"]["capabilities"] == ["time"]  # nothing advertised unanswered
    assert set(report["channels"]) == set(logged)  # the log's channels, all advertised
    totals = report["totals"]
    for key in ("schemaRefused", "decodeFailures", "schemaViolations", "wellKnownViolations"):
        assert totals[key] == 0, (key, report["failures"])
    wk = {t: c["wellKnown"] for t, c in report["channels"].items() if c["wellKnown"]}
    assert wk and set(wk.values()) == {"matched"}  # foxglove.* names Foxglove knows
    assert report["time"]["messages"] > 0 and report["time"]["backwards"] == 0
    # foxglove-sdk's advertise/subscribe race (check.mjs, the "status" handler) is retried
    # there and reported; any other status from the server is a failure
    others = [s for s in report["statusMessages"] if not s.get("subscribeRaceRetried")]
    assert report["unknownSubscription"] == 0 and not others, others
    if report["subscribeRaces"]:
        print(f"foxglove-sdk subscribe race, retried: {report['subscribeRaces']}")


@pytest.fixture(scope="module")
def live_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    if NODE_WHY is not None:
        pytest.skip(f"Foxglove client check: {NODE_WHY}")
    if not SANDBOX_OK:
        pytest.skip(f"no private network namespace: {SANDBOX_WHY}")
    out = tmp_path_factory.mktemp("foxglove-live")
    port = _free_port()
    cmd = [
        sys.executable,
        "-m",
        "tools.cli",
        "run",
        "--realtime",
        *rt("control").split(),  # the controller on SCHED_FIFO, the bench above it
        "--controller",
        "baseline",
        "--scenario",
        "short",
        "--duration",
        "4",
        "--bus",
        "udp_multicast",
        "--live",
        f"127.0.0.1:{port}",
        "--out",
        str(out / "run"),
    ]
    return out, _serve_and_check(cmd, port, out / "live.json")


@needs_sandbox
@needs_node
def test_the_apps_client_reads_every_channel_of_a_real_time_run(
    live_run: tuple[Path, dict[str, Any]],
) -> None:
    out, report = live_run
    log = out / "run" / "run.mcap"
    logged = _logged(log)
    _assert_app_reads_everything(report, logged)
    got = {t: c["messages"] for t, c in report["channels"].items()}
    # it connected before the parts started (it retries until the view listens), so it got
    # every message the view served: the start-up frames too, whose channels are created
    # with their first message (the view holds a new channel's messages for the subscriptions)
    connected_ns = int(report["connectedAtMs"]) * 1_000_000
    assert connected_ns < min(m.log_time for _, m in mcap_io.iter_messages(log))
    served = json.loads((out / "run" / "live_stats.json").read_text())["by_topic"]
    assert {t: n for t, n in got.items() if n} == served
    assert [t for t, n in got.items() if n == 0] == []


@needs_sandbox
@needs_node
def test_the_apps_client_gets_every_message_of_a_replay(
    live_run: tuple[Path, dict[str, Any]],
) -> None:
    out, _ = live_run
    log = out / "run" / "run.mcap"
    port = _free_port()
    cmd = [sys.executable, "-m", "tools.cli", "replay", str(log), "--live", f"127.0.0.1:{port}"]
    report = _serve_and_check([*cmd, "--speed", "4"], port, out / "replay.json")
    logged = _logged(log)
    _assert_app_reads_everything(report, logged)
    assert {t: c["messages"] for t, c in report["channels"].items()} == dict(logged)
