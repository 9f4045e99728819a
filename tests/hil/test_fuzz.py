"""No input kills a part: 100,000 random and mutated datagrams into a running
lock-step run over udp_multicast, bench, controller and recorder as processes in a
private network namespace.

Every part must survive, each must count what it dropped by reason so that the counts
add up to what was sent (less what the kernel dropped), and, since no fuzz datagram is a
frame a drive acts on, the run's tracking figures must equal a clean run's: the same
lock-step run on the virtual bus, in the test's process.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.integration.conftest import run_stack
from tools.bus import transport

pytestmark = [pytest.mark.hil, pytest.mark.alone]

SANDBOX_OK, SANDBOX_WHY = transport.sandbox_supported()
FIGURES = ("rmse_xe_m", "rmse_ye_m", "rmse_phie_rad", "rmse_pos_m", "max_pos_err_m", "max_phie_rad")
COUNT = 100_000


def _rx(counts: dict[str, int]) -> int:
    return sum(v for k, v in counts.items() if k.startswith("rx_"))


def _udp_rcvbuf_errors(snmp: str) -> int:
    lines = [ln.split() for ln in snmp.splitlines() if ln.startswith("Udp:")]
    head, values = lines[0], lines[1]
    return int(values[head.index("RcvbufErrors")])


def _stats(out: Path, summary: dict[str, Any]) -> dict[str, Any]:
    return {
        "summary": summary,
        "controller": json.loads((out / "controller_stats.json").read_text()),
        "bench": json.loads((out / "bench_stats.json").read_text()),
        "recorder": json.loads((out / "recorder_stats.json").read_text()),
    }


def _clean(out: Path) -> dict[str, Any]:
    """The reference: the same lock-step run on the virtual bus, in this process.  A
    lock-step run's figures do not depend on the bus (tests/hil/socketcan's equality test:
    three processes over vcan0 match the virtual bus), and no kernel queue can drop a frame
    of it, so its figures are never withheld."""
    return {**_stats(out, run_stack(out, "fault-free", "baseline")), "kernel_drops": 0}


def _fuzzed(out: Path) -> dict[str, Any]:
    """Three processes over udp_multicast in a private namespace, and the fuzzer beside them."""
    run = (
        f"{sys.executable} -m tools.cli run --bus udp_multicast --scenario fault-free "
        f"--controller baseline --out {out}"
    )
    # bursts of 64: all 100,000 land while the lock-step run still runs, even where it
    # takes only about 10 s (a quiet machine); the fuzzer slows down on kernel drops
    script = (
        f"{sys.executable} -m tests.hil.fuzzer --count {COUNT} --burst 64 --report {out}/fuzz.json & "
        f"{run}; rc=$?; wait; cat /proc/net/snmp > {out}/snmp.txt; exit $rc"
    )
    res = subprocess.run(
        [sys.executable, "-m", "tools.cli", "sandbox", "--", "sh", "-c", script],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    return {
        **_stats(out, json.loads((out / "summary.json").read_text())),
        "kernel_drops": _udp_rcvbuf_errors((out / "snmp.txt").read_text()),
        "fuzz": json.loads((out / "fuzz.json").read_text()),
    }


@pytest.mark.skipif(not SANDBOX_OK, reason=f"no private network namespace: {SANDBOX_WHY}")
def test_a_hundred_thousand_bad_datagrams_kill_no_part_and_change_no_figure(
    tmp_path: Path,
) -> None:
    (tmp_path / "fuzz").mkdir()
    clean = _clean(tmp_path / "clean")
    fz = _fuzzed(tmp_path / "fuzz")
    report = fz["fuzz"]
    print("fuzz:", json.dumps(report))
    for part in ("controller", "bench", "recorder"):
        print(part, "rejected:", json.dumps(_part_rejected(fz, part)))
    print("kernel receive-buffer drops:", fz["kernel_drops"])

    # sent into a running run
    assert report["sent"] >= COUNT
    assert report["bench_running_at_last"]
    # every part survived to the end of the route
    s = fz["summary"]
    assert s["stop_reason"] == "ROUTE_DONE"
    assert fz["controller"]["final_state"] == "DONE"
    assert fz["controller"]["exceptions"] == 0
    assert fz["bench"]["aborted"] is None and fz["bench"]["missed_acks"] == 0
    assert fz["recorder"]["ended_by"] == "Bench_End"
    # the counts add up: each part dropped every datagram that was no frame, by reason,
    # and rejected every frame the DBC does not define
    # (exactly, unless the kernel dropped datagrams for want of buffer: then a part may have
    # counted fewer, by no more than the namespace's receive-buffer drops)
    # The controller's bus passes only the IDs the DBC has the host receive (its receive
    # filters), so frames on unknown IDs never reach it and its sum is the datagrams that are
    # no frame; it ignores frames on its own IDs unread, so its sum leaves out "length" too.
    drops = fz["kernel_drops"]
    by_kind = report["by_kind"]
    # A few datagrams the fuzzer means as no frame unpack as frames on unknown IDs (the
    # bench and the recorder count them there); the controller's filters keep those out.
    bench_got, bench_base = _part_rejected(fz, "bench"), _part_rejected(clean, "bench")
    as_frames = max(
        0,
        bench_got.get("unknown_id", 0) - bench_base.get("unknown_id", 0) - by_kind["unknown_id"],
    )
    for part, kinds in (
        ("controller", ("transport",)),
        ("bench", ("transport", "unknown_id", "length")),
        ("recorder", ("transport", "unknown_id", "length")),
    ):
        got, base = _part_rejected(fz, part), _part_rejected(clean, part)
        counted = _rx(got) + sum(
            got.get(k, 0) - base.get(k, 0) for k in ("unknown_id", "length") if k in kinds
        )
        sent = sum(by_kind[k] for k in kinds) - (as_frames if part == "controller" else 0)
        assert sent - drops <= counted <= sent, (part, counted, sent, drops)
    # the fuzz never reached the drives: the same run, figure for figure
    for key in FIGURES:
        assert s[key] == pytest.approx(clean["summary"][key], abs=1e-12), key


def _part_rejected(r: dict[str, Any], part: str) -> dict[str, int]:
    if part == "controller":
        return dict(r["controller"]["link_rejected"])
    if part == "bench":
        return dict(r["bench"]["frames_rejected_by_reason"])
    return dict(r["recorder"].get("rejected", {}))
