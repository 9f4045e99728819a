"""The live view's cost: what its mirror costs a log writer (``live_feed_us``) and the controller's
tick in real-time runs with and without the view and its clients (``live_tick_us``,
``bench --case live``)."""

from __future__ import annotations

import contextlib
import json
import socket
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from controller.telemetry import TICK_TOPIC, McapTelemetry
from tools.live.address import LiveAddress
from tools.live.server import LiveServer
from tools.perf.common import PAPER, cli_run, per_call_us


def _tick_record() -> dict[str, Any]:
    return {
        "route_time_s": 12.34,
        "ref": {k: 0.1 * i for i, k in enumerate(("x", "y", "heading", "v", "omega", "a"))},
        "est": {k: 0.2 * i for i, k in enumerate(("x", "y", "heading", "v", "omega"))},
        "err": {"x_e": 0.01, "y_e": -0.02, "phi_e": 0.003},
        "cmd": {"v": 0.45, "omega": 0.1, "wheel_left_radps": 1.4, "wheel_right_radps": 1.6},
        "internals": {"s1": 0.3, "bank.p_nominal": 0.9},
    }


def feed_costs(calls: int) -> dict[str, Any]:
    """What the live view's mirror costs a log writer (``live_feed_us``, wall time).

    ``message``: one :meth:`LiveFeed.message` (the append to the bounded queue);
    ``tick_record``: a tick record written by :class:`McapTelemetry` in this thread,
    without a mirror and with a feed to a real view process (its sender thread running:
    wall time, so that the interpreter lock it takes is counted).  In a run the
    telemetry writes from a forked process, not in the loop; this is the worst case,
    where it could not fork.
    """
    out: dict[str, float] = {}
    with (
        tempfile.TemporaryDirectory(prefix="whil-bench-feed-") as tmp,
        LiveServer(LiveAddress("127.0.0.1", 0)) as view,
    ):
        feed = view.feed()
        feed.schema(1, "T", "jsonschema", b"{}")
        feed.channel(1, "/t", "json", 1)
        payload = b'{"x":1.0}' * 20
        out["message"] = per_call_us(lambda: feed.message(1, 0, payload), calls)
        feed.close()
        record = _tick_record()
        for label, mirror in (("tick_record", None), ("tick_record_with_feed", view.feed())):
            tel = McapTelemetry(Path(tmp) / f"{label}.mcap", mirror=mirror)
            k = iter(range(10**9))
            out[label] = per_call_us(
                lambda t=tel, k=k: t.log(TICK_TOPIC, next(k) * 10_000_000, record), calls // 4
            )
            tel.close()
    return {"live_feed_us": out}


#: The live view's cases: (name, serve the view, run a client, the client's delay per message).
LIVE_CASES = (
    ("no view", False, False, 0.0),
    ("view, no client", True, False, 0.0),
    ("view, client on every channel", True, True, 0.0),
    ("view, slow client (2 ms per message)", True, True, 0.002),
)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def live_cost(work: Path, seconds: float, rounds: int = 2) -> dict[str, Any]:
    """The controller's tick with and without the live view (``live_tick_us``).

    One real-time run of ``seconds`` on the virtual bus per case of :data:`LIVE_CASES`
    (``run --realtime --bus virtual [--live 127.0.0.1:PORT]``), ``rounds`` times, the
    order reversed every other round (so that a machine getting busier does not favour
    one case); the client is :mod:`tools.live.client` in a process of its own, connected
    before the run starts, subscribed to every channel as it is advertised.  The tick
    figures are the controller's own (``tick_us_*``: a tick's work from its clock's
    wake-up to its ack; ``lateness_us_p99``: against its absolute schedule), the mean over
    the rounds; ``rounds`` keeps each run's figures.
    """
    per_case: dict[str, list[dict[str, Any]]] = {name: [] for name, *_ in LIVE_CASES}
    k = 0
    for r in range(rounds):
        order = LIVE_CASES if r % 2 == 0 else tuple(reversed(LIVE_CASES))
        for name, view, with_client, delay in order:
            k += 1
            per_case[name].append(_live_run(work / f"live-{k}", seconds, view, with_client, delay))
    out: dict[str, Any] = {}
    for name, runs in per_case.items():
        errors = [r for r in runs if "error" in r]
        if errors:
            out[name] = errors[0]
            continue
        mean = {
            key: statistics.fmean(float(r[key]) for r in runs)
            for key in ("tick_us_p50", "tick_us_p99", "lateness_us_p99")
            if all(r.get(key) is not None for r in runs)
        }
        out[name] = {
            **runs[-1],
            **mean,
            "missed_ticks": sum(r.get("missed_ticks") or 0 for r in runs),
        }
        out[name]["rounds"] = runs
    return {"live_tick_us": out, "live_seconds": seconds, "live_rounds": rounds}


def _live_run(
    run_dir: Path, seconds: float, view: bool, with_client: bool, delay: float
) -> dict[str, Any]:
    """One real-time run of :func:`live_cost`."""
    port = _free_port()
    extra = ["--live", f"127.0.0.1:{port}"] if view else []
    client = None
    counts = run_dir / "client.json"
    run_dir.mkdir(parents=True, exist_ok=True)
    if with_client:
        client = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tools.live.client",
                f"ws://127.0.0.1:{port}",
                "--delay-s",
                repr(delay),
                "--json",
                str(counts),
            ]
        )
    err = cli_run(
        [
            "run",
            "--realtime",
            "--bus",
            "virtual",
            "--controller",
            "baseline",
            "--scenario",
            PAPER,
            "--duration",
            str(seconds),
            *extra,
            "--out",
            str(run_dir),
        ],
        timeout=seconds * 3 + 120,
    )
    got: dict[str, Any] = {}
    if client is not None:
        try:
            client.wait(30)
        except subprocess.TimeoutExpired:
            client.kill()
            client.wait()
        with contextlib.suppress(OSError, ValueError):
            got = json.loads(counts.read_text())
    if err:
        return err
    s = json.loads((run_dir / "summary.json").read_text())
    served: dict[str, Any] = {}
    with contextlib.suppress(OSError, ValueError):
        served = json.loads((run_dir / "live_stats.json").read_text())
    return {
        "tick_us_p50": s.get("tick_us_p50"),
        "tick_us_p99": s.get("tick_us_p99"),
        "lateness_us_p99": s.get("lateness_us_p99"),
        "missed_ticks": s.get("missed_ticks"),
        "view_messages": served.get("messages"),
        "feed_dropped": served.get("feed_dropped"),
        "client_messages": got.get("messages"),
        "client_channels": got.get("channels"),
        "client_by_topic": got.get("by_topic"),
    }


def format_live(r: dict[str, Any]) -> str:
    """The live view's cases as a table."""

    def f(v: Any, fmt: str = ".1f") -> str:
        return "n/a" if v is None or (isinstance(v, float) and v != v) else format(v, fmt)

    lines = [
        f"| live view, {f(r.get('live_seconds'), 'g')} s real-time runs (mean of "
        f"{r.get('live_rounds', 1)}) | tick p50 / p99 | "
        "lateness p99 | missed ticks | served / dropped by the feeds | client got (channels) |",
        "|---|---|---|---|---|---|",
    ]
    fc = r.get("live_feed_us") or {}
    if fc:
        lines.append(
            f"| a log writer's mirror: one message / a tick record without / with it "
            f"(in one thread) | {f(fc.get('message'), '.2f')} us / {f(fc.get('tick_record'))} "
            f"/ {f(fc.get('tick_record_with_feed'))} us | | | | |"
        )
    for name, c in (r.get("live_tick_us") or {}).items():
        if "error" in c:
            lines.append(f"| {name} | {c['error']} | | | | |")
            continue
        got = (
            f"{c['client_messages']} ({c['client_channels']})"
            if c.get("client_messages") is not None
            else "-"
        )
        served = (
            f"{c['view_messages']} / {c['feed_dropped']}"
            if c.get("view_messages") is not None
            else "-"
        )
        lines.append(
            f"| {name} | {f(c['tick_us_p50'])} / {f(c['tick_us_p99'])} us | "
            f"{f(c['lateness_us_p99'])} us | {c.get('missed_ticks')} | {served} | {got} |"
        )
    return "\n".join(lines)
