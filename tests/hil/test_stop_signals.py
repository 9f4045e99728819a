"""A stop signal at any moment of a part's life: the part exits with its real status.

systemd stops the chair's service with SIGTERM, ``run`` and the tests stop parts with it, a
terminal sends SIGINT.  Each part (``sim``, ``control``, ``record``, ``run``, ``replay`` and the
live view) must then end with the status that says what happened (0 whole, 1 failed, 3 partial
log; 2 for the bench whose controller never answered), never die of the signal (a negative
status), and leave a log that reads back whole.

The moments are exact, not guessed with a timer: ``WHEELCHAIR_HIL_SIGNAL_AT`` makes a part
send itself SIGTERM at ``start`` (handlers just installed, nothing else done), ``ready`` (it
said READY), ``bench-end`` (Bench_End sent or read), ``flush`` (its log being closed) or
``exit`` (status chosen, the interpreter about to finalize), and its stderr says it did.  Two
storms send SIGTERM every 10 ms: from a part's birth (started with the signals blocked,
as ``run`` starts its parts), and from the moment the bench has ended until the controller and
the recorder, ending on its Bench_End, have exited: the race of the CI run that lost the
recorder's status 3 to a SIGTERM at its exit.

Every case is one lock-step run of the short route (5 s simulated) in a private network
namespace of its own, so that three cases run side by side.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from tools.bus import transport
from tools.logs.mcap_io import TruncatedLogWarning, iter_frames

pytestmark = [pytest.mark.hil, pytest.mark.heavy(seconds=32)]
SANDBOX_OK, SANDBOX_WHY = transport.sandbox_supported()
ROOT = Path(__file__).resolve().parents[2]

UDP = ("--bus", "udp_multicast")
LOCKSTEP = (*UDP, "--scenario", "short", "--duration", "5")


def _rec(name: str, d: Path, **kw: Any) -> dict[str, Any]:
    return {"name": name, "argv": ["record", *UDP, "--out", str(d / name / "run.mcap")], **kw}


def _ctl(name: str, d: Path, **kw: Any) -> dict[str, Any]:
    argv = ["control", *LOCKSTEP, "--controller", "baseline", "--out", str(d / name)]
    return {"name": name, "argv": argv, **kw}


def _sim(d: Path, **kw: Any) -> dict[str, Any]:
    return {"name": "sim", "argv": ["sim", *LOCKSTEP, "--out", str(d / "sim")], **kw}


def _view(name: str, d: Path, **kw: Any) -> dict[str, Any]:
    argv = ["--socket", str(d / f"{name}.sock"), "--port", "0"]
    return {"name": name, "module": "tools.live.view", "argv": argv, **kw}


#: case -> (its parts in start order, each part's expected exit status)
def _cases(d: Path, log: Path) -> dict[str, tuple[list[dict[str, Any]], dict[str, int]]]:
    def at(case: str) -> Path:
        return d / case

    replay = ["replay", str(log), *UDP, "--no-progress", "--speed", "10"]
    run_virtual = ["run", "--bus", "virtual", "--scenario", "short", "--duration", "3"]
    return {
        # every (part, moment) once: the bench, the controller and the recorder in turn
        "A": (
            [
                _rec("rec", at("A"), at="flush"),
                _ctl("ctl", at("A"), at="bench-end"),
                _sim(at("A"), at="start"),
            ],
            # the bench stopped before its first step: nothing simulated, whole
            {"rec": 0, "ctl": 0, "sim": 0},
        ),
        "B": (
            [
                _rec("rec", at("B"), at="exit"),
                _ctl("ctl", at("B"), at="flush"),
                _sim(at("B"), at="ready"),
            ],
            {"rec": 0, "ctl": 0, "sim": 0},
        ),
        "C": (
            [
                _rec("rec", at("C"), at="start"),
                _ctl("ctl", at("C"), at="exit"),
                _sim(at("C"), at="bench-end"),
            ],
            {"rec": 0, "ctl": 0, "sim": 0},
        ),
        "D": (
            [
                _rec("rec", at("D"), at="ready"),
                _rec("rec2", at("D"), at="bench-end"),
                _ctl("ctl", at("D")),
                _sim(at("D"), at="exit"),
            ],
            {"rec": 0, "rec2": 0, "ctl": 0, "sim": 0},
        ),
        # a controller stopped before it drives: no bench is started against it
        "E": (
            [_ctl("ctl", at("E"), at="start"), _ctl("ctl2", at("E"), at="ready")],
            {"ctl": 0, "ctl2": 0},
        ),
        # the CI run's race: SIGTERM while the recorder and the controller end on Bench_End
        "storm-ending": (
            [
                _rec("rec", at("storm-ending"), storm="after:sim"),
                _ctl("ctl", at("storm-ending"), storm="after:sim"),
                _sim(at("storm-ending")),
            ],
            {"rec": 0, "ctl": 0, "sim": 0},
        ),
        # SIGTERM from the first instant (started with the signals blocked, as run does)
        "storm-birth": (
            [
                _rec("rec", at("storm-birth"), storm="birth"),
                _ctl("ctl", at("storm-birth"), storm="birth"),
                _view("view", at("storm-birth"), storm="birth", keep_stdin=True),
                {"name": "replay", "argv": replay, "storm": "birth", "ready": False},
                {"name": "run", "argv": run_virtual, "storm": "birth", "ready": False},
            ],
            {"rec": 0, "ctl": 0, "view": 0, "replay": 0, "run": 0},
        ),
        # run, on the virtual bus (its parts are threads of its own) and across processes
        "run": (
            [
                {"name": "run-start", "argv": run_virtual, "at": "start", "ready": False},
                {"name": "run-end", "argv": run_virtual, "at": "bench-end", "ready": False},
                {"name": "run-flush", "argv": run_virtual, "at": "flush", "ready": False},
                {"name": "run-exit", "argv": run_virtual, "at": "exit", "ready": False},
            ],
            {"run-start": 0, "run-end": 0, "run-flush": 0, "run-exit": 0},
        ),
        "run-udp": (
            [
                {
                    "name": "run-udp",
                    "argv": [*run_virtual[:1], *UDP, *run_virtual[3:], "--out", str(d / "ru")],
                    "storm": "after:rec",
                    "ready": False,
                },
                # ends at once: the storm starts as run's parts are starting
                _rec("rec", at("run-udp"), at="start"),
            ],
            {"run-udp": 0, "rec": 0},
        ),
        # re-transmitting a log, and the live view
        "replay-view": (
            [
                {"name": "replay-start", "argv": replay, "at": "start", "ready": False},
                {"name": "replay-exit", "argv": replay, "at": "exit", "ready": False},
                _view("view-start", at("replay-view"), at="start", keep_stdin=True),
                _view("view-ready", at("replay-view"), at="ready", keep_stdin=True),
                _view("view-exit", at("replay-view"), at="exit"),
            ],
            {"replay-start": 0, "replay-exit": 0, "view-start": 0, "view-ready": 0, "view-exit": 0},
        ),
    }


def _run_case(d: Path, parts: list[dict[str, Any]]) -> dict[str, Any]:
    d.mkdir(parents=True, exist_ok=True)
    for p in parts:
        if p["argv"][0] == "run" and "--out" not in p["argv"]:
            p["argv"] = [*p["argv"], "--out", str(d / p["name"])]
    spec = d / "spec.json"
    spec.write_text(json.dumps({"dir": str(d), "parts": parts}))
    res = subprocess.run(
        transport.sandbox_argv([sys.executable, "-m", "tests.hil.stopdriver", str(spec)]),
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
        cwd=ROOT,
        stdin=subprocess.DEVNULL,
    )
    assert res.returncode == 0, res.stderr
    status: dict[str, Any] = json.loads((d / "status.json").read_text())
    return status


@pytest.fixture(scope="module")
def cases(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    if not SANDBOX_OK:
        pytest.skip(f"no private network namespace: {SANDBOX_WHY}")
    d = tmp_path_factory.mktemp("stop")
    log = d / "replayed" / "run.mcap"
    made = subprocess.run(
        [
            sys.executable,
            "-m",
            "tools.cli",
            "run",
            "--bus",
            "virtual",
            "--scenario",
            "short",
            "--duration",
            "1",
            "--out",
            str(log.parent),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        cwd=ROOT,
    )
    assert made.returncode == 0, made.stderr
    table = _cases(d, log)
    with ThreadPoolExecutor(max_workers=3) as pool:
        futures = {
            name: pool.submit(_run_case, d / name, parts) for name, (parts, _) in table.items()
        }
        results = {name: f.result() for name, f in futures.items()}
    rows = []
    for name, (parts, expected) in table.items():
        for p in parts:
            moment = p.get("at") or (f"storm {p['storm']}" if p.get("storm") else "-")
            code = results[name]["codes"].get(p["name"])
            rows.append(
                f"{name:<12} {p['name']:<13} {moment:<18} {code!s:>6} {expected[p['name']]:>8}"
            )
    print("\ncase         part          moment              status  expected\n" + "\n".join(rows))
    return {"dir": d, "table": table, "results": results}


def _cells(cases: dict[str, Any]) -> list[tuple[str, dict[str, Any], int | None, int]]:
    out = []
    for name, (parts, expected) in cases["table"].items():
        for p in parts:
            out.append(
                (name, p, cases["results"][name]["codes"].get(p["name"]), expected[p["name"]])
            )
    return out


def test_no_part_dies_of_a_stop_signal_and_each_exits_with_its_own_status(
    cases: dict[str, Any],
) -> None:
    wrong = [
        f"{case}/{p['name']} ({p.get('at') or p.get('storm')}): exit {code}, expected {want}: "
        + (cases["dir"] / case / f"{p['name']}.err").read_text()[-600:]
        for case, p, code, want in _cells(cases)
        if code != want
    ]
    assert not wrong, "\n".join(wrong)


def test_every_planned_moment_was_reached_and_every_birth_storm_sent_signals(
    cases: dict[str, Any],
) -> None:
    for case, p, _code, _want in _cells(cases):
        err = (cases["dir"] / case / f"{p['name']}.err").read_text()
        if p.get("at"):
            assert f"SIGTERM to itself at {p['at']}" in err, f"{case}/{p['name']}: {err[-600:]}"
        if p.get("storm") == "birth":  # a storm from birth always reaches its part
            sent = cases["results"][case]["storm_signals"][p["name"]]
            assert sent >= 1, f"{case}/{p['name']}: the storm sent no signal"
        # a storm "after:NAME" may find its part already gone (it ended on Bench_End before
        # NAME's process exited): then it had nothing to hit, which its status still shows


def test_every_recorder_log_reads_back_whole_whatever_moment_it_was_stopped_at(
    cases: dict[str, Any],
) -> None:
    logs = sorted(cases["dir"].glob("*/*/run.mcap"))
    assert len(logs) >= 10, logs
    for log in logs:
        with warnings.catch_warnings():
            warnings.simplefilter("error", TruncatedLogWarning)
            frames = sum(1 for _ in iter_frames(log))
        assert frames >= 0, log
        stats = log.parent / "recorder_stats.json"
        if stats.exists():  # run's own recorders keep theirs beside the log too
            assert json.loads(stats.read_text())["frames"] == frames, log


def test_a_recorder_stopped_while_the_bench_ends_keeps_every_step_of_the_run(
    cases: dict[str, Any],
) -> None:
    """The storm while ending must not cost the log its last steps: it ends on Bench_End."""
    stats = json.loads((cases["dir"] / "storm-ending" / "rec" / "recorder_stats.json").read_text())
    assert stats["missed_steps"] == 0, stats
    assert stats["ended_by"] in ("Bench_End", "stopped"), stats
    bench = json.loads((cases["dir"] / "storm-ending" / "sim" / "bench_stats.json").read_text())
    assert bench["sim_time_s"] >= 5.0 - 1e-6, bench
