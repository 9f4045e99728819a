"""Real time on vcan0: ``ip link set vcan0 down`` while the chair drives a route.

What must happen (docs/safety.md § 3, the link goes down): the controller brakes and names
the interface (it stops with ``BUS_DOWN`` and exits non-zero saying ``vcan0``), the bench's
drives, hearing nothing, stop by their own watchdog, and the recorder's log up to that moment
is readable.  The interface comes back up after a few seconds, so that the drives' own frames
show how they stopped: both at standstill with WATCHDOG_TIMER_EXPIRED latched, and the
controller still latched (it never re-arms by itself).

The test waits for events on the bus (its own socket), never for a guessed time: for both
wheels to drive before the down, and after it for each drive's frames from past the
watchdog's moment.  The parts run on SCHED_FIFO (``conftest.start_part``): the log is
what the test judges.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import math
import os
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from dbc.codec import (
    AxisError,
    BenchStep,
    Codec,
    EncoderEstimates,
    Heartbeat,
    Node,
    SetInputVel,
    SetInputVelAuth,
)
from dbc.errors import CodecError
from tools.logs import mcap_io
from tools.safety.criteria import STANDSTILL_MPS

from .conftest import (
    REALTIME_VCAN,
    TOLERANT_WATCHDOG_S,
    WHEEL_RADIUS_M,
    BusWatch,
    start_part,
    wait_until_driving,
)

pytestmark = pytest.mark.hil
#: how long the interface stays down (wall time): well past the drives' watchdog (1 s)
DOWN_S = 3.0
#: the longest the test waits, once the interface is up again, for each drive's heartbeat and
#: encoder frame from past the watchdog's moment (wall time: a one-CPU guest on a loaded host
#: is descheduled for seconds, so the test waits for the frames, not for a guessed time)
UP_DEADLINE_S = 120.0


#: the SCHED_FIFO priority of this test's thread while it takes the interface down and up:
#: above the parts' (9-11), below the guest's ksoftirqd (tools.bus.umlguest.SOFTIRQ_RT_PRIORITY)
IP_RT_PRIORITY = 20


def _ip(*argv: str) -> None:
    subprocess.run(["ip", "link", "set", *argv], check=True, capture_output=True, text=True)


@contextlib.contextmanager
def _above_the_parts() -> Iterator[None]:
    """This thread (and the ``ip`` it starts) on SCHED_FIFO above the parts, then back.  At
    normal priority, beside the parts on SCHED_FIFO in the one-CPU guest, it once woke from
    its 3 s sleep 2.6 s late, and brought the interface up past the recorder's 5 s of
    silence; a helper it started for the down and up (``chrt``) once started after the
    route had ended."""
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(IP_RT_PRIORITY))
    try:
        yield
    finally:
        os.sched_setscheduler(0, before[0], before[1])


def test_vcan0_going_down_mid_route_brakes_names_it_and_the_drives_stop_by_watchdog(
    tmp_path: Path, tolerant_chair: Path
) -> None:
    log_path = tmp_path / "rec" / "run.mcap"
    procs: dict[str, subprocess.Popen[str]] = {}
    # 0.5 s past the moment the test judges: the watchdog's timeout and 1 s of stop ramp
    watch = BusWatch(Codec.default(), TOLERANT_WATCHDOG_S + 1.0 + 0.5)
    try:
        procs["rec"] = start_part(tmp_path, "rec", "record", *REALTIME_VCAN,
                                  "--out", str(log_path), realtime=True)  # fmt: skip
        # the controller before the bench, as a chair's host may come up before its drives:
        # it waits in INIT, and its start-up (seconds of imports in the one-CPU guest) does
        # not compete with a bench that is already keeping real time
        ctl = procs["ctl"] = start_part(tmp_path, "ctl", "control", *REALTIME_VCAN,
                                        "--duration", "120", "--controller", "baseline",
                                        "--config", str(tolerant_chair),
                                        "--out", str(tmp_path / "ctl"), realtime=True)  # fmt: skip
        procs["sim"] = start_part(tmp_path, "sim", "sim", *REALTIME_VCAN, "--duration", "120",
                                  "--out", str(tmp_path / "sim"), realtime=True)  # fmt: skip
        # armed and driving the route: events, not a guessed start-up time (a loaded host
        # slows the one-CPU guest's start-up by seconds)
        wait_until_driving(ctl, tmp_path / "ctl.err", watch)
        assert ctl.poll() is None, (tmp_path / "ctl.err").read_text()
        with _above_the_parts():
            down_wall_ns = time.time_ns()
            _ip("vcan0", "down")
            time.sleep(DOWN_S)
            _ip("vcan0", "up")
            up_wall_ns = time.time_ns()
        deadline = time.monotonic() + UP_DEADLINE_S
        while not watch.done(up_wall_ns):
            assert time.monotonic() < deadline, (
                f"{UP_DEADLINE_S:.0f} s after the interface came up, not each drive's heartbeat "
                f"and encoder frame from 1.5 s of bench time past the last setpoint "
                f"(at {watch.last_setpoint_ns / 1e9:.2f} s; bench at {watch.sim_ns / 1e9:.2f} s)"
            )
            time.sleep(0.1)
        # the controller ends by itself once its latched stop has idled the chair for 1 s
        procs["ctl"].wait(120)
        for name in ("sim", "rec"):  # the recorder last: it logs the bench's end
            procs[name].send_signal(signal.SIGTERM)
            procs[name].wait(60)
    finally:
        with_up = subprocess.run(["ip", "link", "set", "vcan0", "up"], check=False)
        watch.close()
        assert with_up.returncode == 0
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()

    assert watch.dropped == 0, f"the test's own watcher lost {watch.dropped} frames"
    ctl_err = (tmp_path / "ctl.err").read_text()
    stats = json.loads((tmp_path / "ctl" / "controller_stats.json").read_text())
    # the controller braked, named the interface and exited non-zero (a stop before the down,
    # DRIVE_ERROR with the drives' watchdog expired while the recorder saw setpoints at 100 Hz,
    # was seen in this one-CPU guest: the bench's side is in the message for that case)
    bench_json = tmp_path / "sim" / "bench_stats.json"
    bench_stats = bench_json.read_text() if bench_json.exists() else "(no bench_stats.json)"
    assert stats["stop_reason"] == "BUS_DOWN", (stats, bench_stats)
    assert "vcan0" in stats["stop_detail"], stats["stop_detail"]
    assert stats["final_state"] == "FAULT", stats
    assert procs["ctl"].returncode == 1, ctl_err
    assert "the bus went down" in ctl_err and "vcan0" in ctl_err, ctl_err
    assert procs["sim"].returncode == 0, (tmp_path / "sim.err").read_text()

    # The recorder's log is readable, whole up to the down, and carries the frames after it.
    # The down is found by the wall clock (a real-time log's times are the kernel's receive
    # times): frames received before `ip link set vcan0 down` was run, and after `up` returned.
    # In bench time it is a gap only if the bench kept stepping while the interface was down
    # (its sends then fail and those steps are missing); a bench descheduled through the down
    # catches its late steps up afterwards and leaves none missing: both are its real
    # behaviour, and the recorder's status says which (3 for a log with steps missing, else 0).
    codec = Codec.default()
    period_ns = 10_000_000
    sim_ns = 0
    steps: list[int] = []  # bench time of each Bench_Step received before the down
    last_setpoint_ns = 0  # bench time of the controller's last setpoint in the log
    speeds: dict[Node, list[tuple[int, float]]] = {Node.LEFT: [], Node.RIGHT: []}
    after: dict[Node, list[tuple[int, float]]] = {Node.LEFT: [], Node.RIGHT: []}
    errors: dict[Node, list[tuple[int, int]]] = {Node.LEFT: [], Node.RIGHT: []}
    all_steps: list[int] = []
    for t, msg in mcap_io.iter_frames(log_path):
        try:
            node, payload = codec.decode(msg)
        except CodecError:  # a frame this test does not read (RTR, authentication PDU)
            continue
        if isinstance(payload, BenchStep):
            sim_ns = payload.sim_time_ns
            all_steps.append(sim_ns)
            if t <= down_wall_ns:
                steps.append(sim_ns)
        elif isinstance(payload, SetInputVel | SetInputVelAuth):
            last_setpoint_ns = max(last_setpoint_ns, sim_ns)
        elif isinstance(payload, EncoderEstimates) and node in speeds:
            v = abs(payload.vel_revps) * math.tau * WHEEL_RADIUS_M
            speeds[node].append((sim_ns, v))
            if t >= up_wall_ns:
                after[node].append((sim_ns, v))
        elif isinstance(payload, Heartbeat) and node in errors and t >= up_wall_ns:
            errors[node].append((sim_ns, int(payload.axis_error)))
    assert steps, "no Bench_Step before the down"
    # every step missing from the log (the down's, and any a starved guest lost before it) is
    # counted by the recorder, and its status says so
    missing = sum((b - a) // period_ns - 1 for a, b in itertools.pairwise(all_steps) if b > a)
    before = sum((b - a) // period_ns - 1 for a, b in itertools.pairwise(steps) if b > a)
    rec = json.loads((tmp_path / "rec" / "recorder_stats.json").read_text())
    rec_err = (tmp_path / "rec.err").read_text()
    assert rec["missed_steps"] >= missing, (rec, missing)
    if rec["missed_steps"]:
        assert procs["rec"].returncode == 3, rec_err
        assert "Bench_Step periods are missing" in rec_err
    elif rec["rx_dropped"]:  # a loss the kernel counted: said, and the status says it
        assert procs["rec"].returncode == 3, rec_err
        assert "the kernel dropped" in rec_err
    else:
        assert procs["rec"].returncode == 0, rec_err
    # the drives, hearing no setpoint, stop by their own watchdog: once the watchdog's
    # timeout (and 1 s of the drive's stop ramp) has passed since the last setpoint, every
    # frame received after the interface came back shows the wheel at rest, watchdog latched
    stopped_ns = last_setpoint_ns + int((TOLERANT_WATCHDOG_S + 1.0) * 1e9)
    for node in (Node.LEFT, Node.RIGHT):
        moving = [v for t, v in speeds[node] if t <= last_setpoint_ns]
        assert moving and max(moving) > 0.1, f"{node.name} was not moving before the down"
        rest = [v for t, v in after[node] if t >= stopped_ns]
        assert rest, f"no {node.name} encoder frame 1.5 s after the last setpoint, once up again"
        assert max(rest) < STANDSTILL_MPS, f"{node.name} still turning after the down: {rest}"
        latched = [e for t, e in errors[node] if t >= stopped_ns]
        assert latched and all(e & AxisError.WATCHDOG_TIMER_EXPIRED for e in latched), (
            f"{node.name}: axis errors after the down {latched}: the watchdog did not stop it"
        )
    print(
        f"last step before the down at {steps[-1] / 1e9:.2f} s of bench time, last setpoint "
        f"at {last_setpoint_ns / 1e9:.2f} s, {missing} steps missing ({before} before the down); "
        f"{stats['stop_detail']}"
    )
