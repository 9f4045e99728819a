"""The three parts of a run — bench, controller, recorder — each as one function.

``wheelchair-hil sim|control|record`` call these in their own process;
``run --bus virtual`` calls all three in threads of one process
(:mod:`tools.run.in_process`), each with its own bus object on the same virtual channel.
Each function opens its bus, calls ``on_ready`` once it can receive, runs until the run ends
and writes its statistics into the output directory.  Also here: the parts' scheduling on a
shared machine (:func:`part_scheduling`), a controller's new log directory per start
(:func:`new_run_dir`) and the recorder process that feeds ``control --live``'s view
(:func:`bus_feed`).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import select
import signal
import socket as _socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can
import numpy as np

from controller.clock import try_realtime
from controller.config import ControllerConfig, load_config, node_map
from controller.link import host_filters
from controller.telemetry import (
    ForkedTelemetry,
    McapTelemetry,
    NullTelemetry,
    Telemetry,
    open_telemetry,
)
from controller.tracking import registry
from dbc.codec import DBC_PATH, Codec
from dbc.runtime import jsonsafe, params
from dbc.runtime.errors import WheelchairError
from dbc.runtime.mcapwriter import Mirror
from firmware_sim.bench import Bench, BenchStats
from firmware_sim.config import load_bench_config
from tools.bus import transport
from tools.bus.rxloss import kernel_drops, kernel_socket
from tools.bus.transport import BusSpec, LightVirtualBus, open_bus
from tools.logs.recorder import BusRecorder, RecorderStats
from tools.run import build
from tools.run.plan import RunPlan
from tools.run.scenario import Scenario

if TYPE_CHECKING:
    from controller.node import ControllerNode, NodeStats

log = logging.getLogger(__name__)

Ready = Callable[[], None] | None
#: A lock-step bench started by ``run`` stays at most this many steps ahead of its recorder.
RECORDER_WINDOW_STEPS = 100


def _write_json(path: Path | None, data: dict[str, Any]) -> None:
    if path is not None:
        jsonsafe.write(path, data, indent=2, default=_json_default)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.integer | np.floating):
        return o.item()
    if isinstance(o, set | tuple):
        return list(o)
    return str(o)


# ------------------------------------------------------------------------- bench


def run_bench(
    spec: BusSpec,
    plan_: RunPlan,
    *,
    out_dir: Path | None = None,
    stop_event: threading.Event | None = None,
    on_ready: Ready = None,
    codec: Codec | None = None,
    recorder_window_steps: int = 0,
    on_idle: Callable[[], object] | None = None,
    rt_priority: int = 0,
    on_bench: Callable[[Bench], None] | None = None,
) -> BenchStats:
    """The bench; ``recorder_window_steps`` > 0 keeps it that close behind a lock-step recorder.

    ``on_bench`` is called with the bench once it is built, before it runs (a harness's
    hooks, e.g. :attr:`Bench.on_step`).

    ``rt_priority`` > 0 (real time): the bench asks for SCHED_FIFO at that priority.  It
    stands in for the drives, which on a chair are hardware of their own that the host's
    load cannot starve.

    ``on_idle`` (virtual bus only) is called whenever the bench would wait for a frame:
    the controller of a one-thread run works there (:mod:`tools.run.in_process`).
    """
    cfg = load_bench_config(plan_.scenario.bench, source=f"{plan_.scenario.path} [bench]")
    if recorder_window_steps:
        cfg = params.replace(
            cfg, {"bench": {"recorder_window_steps": recorder_window_steps}}, source="run"
        )
    bus = open_bus(spec, part="sim")
    try:
        if on_idle is not None:
            if not isinstance(bus, LightVirtualBus):
                raise ValueError(f"on_idle needs the virtual bus, not {spec.describe()}")
            bus.on_idle = on_idle
        if on_ready:
            on_ready()
        bench = build.bench(bus, cfg, plan_, codec=codec, stop_event=stop_event)
        if on_bench is not None:
            on_bench(bench)
        notes = try_realtime(rt_priority) if rt_priority > 0 and plan_.realtime else []
        stats = bench.run()
        stats.realtime_notes = notes
        stats.rx_dropped, stats.rx_buffer_bytes = rx_figures(bus)
    finally:
        bus.shutdown()
    if out_dir is not None:
        _write_json(out_dir / "bench_stats.json", asdict(stats))
    return stats


def rx_figures(bus: can.BusABC) -> tuple[int, int]:
    """(frames the kernel dropped for ``bus``, its receive buffer in bytes; 0 without a socket)."""
    sock = kernel_socket(bus)
    if sock is None or sock.fileno() < 0:
        return 0, 0

    return kernel_drops(bus), int(sock.getsockopt(_socket.SOL_SOCKET, _socket.SO_RCVBUF))


# -------------------------------------------------------------------- controller


def peak_rss_mb() -> float:
    """Peak resident memory of this process (VmHWM), MiB; NaN where /proc is not available."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


def controller_stats(stats: NodeStats) -> dict[str, Any]:
    step_us = np.asarray(stats.step_ns, dtype=float) / 1000.0
    tick_us = np.asarray(stats.tick_ns, dtype=float) / 1000.0

    def pct(a: np.ndarray, q: float) -> float:
        return float(np.percentile(a, q)) if a.size else math.nan

    return {
        "ticks": stats.ticks,
        "tracking_ticks": stats.tracking_ticks,
        "controller_step_us_p50": pct(step_us, 50),
        "controller_step_us_p99": pct(step_us, 99),
        "tick_us_p50": pct(tick_us, 50),
        "tick_us_p99": pct(tick_us, 99),
        "tick_us_max": pct(tick_us, 100),
        "tick_s_total": float(tick_us.sum()) / 1e6,
        "deadline_misses": stats.deadline_misses,
        "tick_overruns": stats.overruns,
        "exceptions": stats.exceptions,
        "non_finite_commands": stats.non_finite_commands,
        "arm_resent": stats.arm_resent,
        "final_state": stats.final_state,
        "stop_reason": stats.stop_reason,
        "stop_detail": stats.stop_detail,
        "tracking_start_ns": stats.tracking_start_ns,
        "route_done_ns": stats.route_done_ns,
        "encoder_age_max_ms": stats.encoder_age_max_ms,
        "encoder_stale_limit_ms": stats.encoder_stale_limit_ms,
        "rx_invalid": dict(stats.rx_invalid),
        "obey_worst_revps": stats.obey_worst_revps,
        "obey_peak_v_mps": stats.obey_peak_v_mps,
        "obey_peak_omega_radps": stats.obey_peak_omega_radps,
        "estimate_step_max_m": stats.estimate_step_max_m,
        "estimate_step_max_rad": stats.estimate_step_max_rad,
        "rate_limits": dict(stats.rate_limits),
        "law_activity": dict(stats.law_activity),
        "estimator": dict(stats.estimator),
    }


def config_record(
    controller: str, cfg: ControllerConfig, gains: dict[str, Any] | None = None
) -> dict[str, str]:
    """The ``controller_config`` metadata record: what ``replay --verify`` rebuilds from."""
    return {
        "controller": controller,
        "config": json.dumps(asdict(cfg), default=_json_default),
        "gains": json.dumps(asdict(registry.load_params(controller, gains)), default=_json_default),
    }


def run_controller(
    spec: BusSpec,
    plan_: RunPlan,
    *,
    config: ControllerConfig | None = None,
    out_dir: Path | None = None,
    stop_event: threading.Event | None = None,
    on_ready: Ready = None,
    codec: Codec | None = None,
    telemetry: bool = True,
    rt_priority: int = 0,
    live: Mirror | None = None,
) -> dict[str, Any]:
    """The controller: build it, run its loop until the run ends, return its results."""
    run = open_controller(
        spec,
        plan_,
        config=config,
        out_dir=out_dir,
        stop_event=stop_event,
        codec=codec,
        telemetry=telemetry,
        rt_priority=rt_priority,
        live=live,
    )
    try:
        if on_ready:
            on_ready()
        run.node.run()
    except BaseException:
        run.abandon()
        raise
    finally:
        run.note_rx()
        run.bus.shutdown()
    return run.finish()


@dataclass
class ControllerRun:
    """A controller on its bus, ready to run (:func:`open_controller`)."""

    name: str
    node: ControllerNode
    bus: can.BusABC
    clock: Any
    telemetry: Telemetry
    realtime: bool
    out_dir: Path | None
    #: the controller's configuration record (its log's ``controller_config`` metadata)
    config: dict[str, str] = field(default_factory=dict)
    rx_dropped: int = 0
    rx_buffer_bytes: int = 0

    def note_rx(self) -> None:
        """Read the socket's drop counter; call it before the bus is shut down."""
        self.rx_dropped, self.rx_buffer_bytes = rx_figures(self.bus)

    def abandon(self) -> None:
        """Close the log of a run that failed (what was written stays readable)."""
        try:
            self.telemetry.close()
        except Exception as err:  # the run's own error is the one to report
            log.warning("closing the controller's log: %s", err)

    def finish(self) -> dict[str, Any]:
        """The controller's results once its loop is over (also into its log and
        ``controller_stats.json``); closes the log.  The caller shuts the bus down."""
        node, clock, tel = self.node, self.clock, self.telemetry
        result = controller_stats(node.stats)
        result.update(
            controller=self.name,
            link_rejected=dict(node.link.counters.rejected),
            link_unused=dict(node.link.counters.unused),
            link_sent=node.link.counters.sent,
            send_failed=node.link.counters.send_failed,
            limiter=asdict(node.limiter.counters),
            clock_ended_by=getattr(clock, "ended_by", ""),
            peak_rss_mb=peak_rss_mb(),
            realtime_notes=list(clock.stats.realtime_notes),
            rx_dropped=self.rx_dropped,
            rx_buffer_bytes=self.rx_buffer_bytes,
        )
        if self.realtime and clock.stats.lateness_ns:
            lat = np.asarray(clock.stats.lateness_ns, dtype=float) / 1000.0
            result.update(
                lateness_us_p50=float(np.percentile(lat, 50)),
                lateness_us_p99=float(np.percentile(lat, 99)),
                lateness_us_p999=float(np.percentile(lat, 99.9)),
                lateness_us_max=float(lat.max()),
                missed_ticks=clock.stats.missed_ticks,
                late_ticks=clock.stats.late_drains,
            )
        tel.metadata(
            "controller_stats",
            {k: jsonsafe.dumps(v, default=_json_default) for k, v in result.items()},
        )
        tel.close()
        if self.out_dir is not None:
            _write_json(self.out_dir / "controller_stats.json", result)
        return result


def controller_config(plan_: RunPlan, config: ControllerConfig | None = None) -> ControllerConfig:
    """The controller's configuration in ``plan_``: ``config`` (default: the deployment file)
    with the scenario's ``[controller]`` table and fault setting (diagnosis feedback, sensor
    faults)."""
    return params.replace(
        config or load_config(),
        plan_.scenario.controller_overrides(),
        source=f"{plan_.scenario.path} [controller]",
    )


def open_controller(
    spec: BusSpec,
    plan_: RunPlan,
    *,
    config: ControllerConfig | None = None,
    out_dir: Path | None = None,
    stop_event: threading.Event | None = None,
    codec: Codec | None = None,
    telemetry: bool = True,
    rt_priority: int = 0,
    wait: bool = True,
    live: Mirror | None = None,
) -> ControllerRun:
    """The controller of ``plan_`` on a bus of its own, its log open, its loop not started.

    ``wait=False`` (lock-step only) gives it a clock that does not wait, for a caller
    that drives the loop with :meth:`ControllerNode.poll` (:mod:`tools.run.in_process`).
    ``live`` sees every message of the controller's log (a live view's feed); without
    ``out_dir`` the log then goes to the null device, so that the view has it all the same.
    """
    if not wait and plan_.realtime:
        raise ValueError("a real-time controller's clock waits (wait=False is for lock-step)")
    cfg = controller_config(plan_, config)
    gains = plan_.scenario.gains_for(plan_.controller)
    ctl = build.law(plan_.controller, cfg, plan_.trajectory, overrides=gains)
    codec = codec or Codec.default()
    stop_event = stop_event or threading.Event()
    tel: Telemetry
    live_options = {} if live is None else {"mirror": live}
    if telemetry and out_dir is not None:
        tel = open_telemetry(out_dir / "controller.mcap", **live_options)
    elif telemetry and live is not None:
        tel = open_telemetry(os.devnull, **live_options)
    else:
        tel = NullTelemetry()
    # the kernel (SocketCAN) or the bus passes only what the DBC has the host receive
    bus = open_bus(
        spec,
        part="control",
        can_filters=host_filters(codec, lockstep=not plan_.realtime, nodes=node_map(cfg)),
    )
    try:
        clock = build.clock(
            bus,
            cfg,
            realtime=plan_.realtime,
            codec=codec,
            stop_event=stop_event,
            duration_s=plan_.duration_s,
            rt_priority=rt_priority,
            wait=wait,
        )
        record = config_record(plan_.controller, cfg, gains)
        if isinstance(tel, McapTelemetry | ForkedTelemetry):  # every tick and the config
            clock = tel.wrap_clock(clock)
            tel.metadata("controller_config", record)
        node = build.node(
            bus,
            cfg,
            ctl,
            plan_.trajectory,
            clock,
            codec=codec,
            telemetry=tel,
            start_pose=plan_.start_pose,
            stop_event=stop_event,
        )
    except BaseException:
        bus.shutdown()
        tel.close()
        raise
    return ControllerRun(plan_.controller, node, bus, clock, tel, plan_.realtime, out_dir, record)


# ---------------------------------------------------------------------- recorder


def recorder_attachments(scenario: Scenario | None, codec: Codec | None) -> dict[str, bytes]:
    """The files a run's log carries: the DBC, and the scenario and route files."""
    attachments = {"wheelchair.dbc": (codec.path if codec else DBC_PATH).read_bytes()}
    if scenario is not None:
        attachments[f"scenario/{scenario.path.name}"] = scenario.path.read_bytes()
        attachments[f"route/{scenario.route_path.name}"] = scenario.route_path.read_bytes()
    return attachments


def run_recorder(
    spec: BusSpec,
    out_path: Path,
    *,
    lockstep: bool,
    scenario: Scenario | None = None,
    stop_event: threading.Event | None = None,
    on_ready: Ready = None,
    duration_s: float | None = None,
    codec: Codec | None = None,
    run_info: dict[str, str] | None = None,
    live: Mirror | None = None,
) -> RecorderStats:
    """Record ``spec``'s bus into ``out_path`` (``live`` sees every message of the log)."""
    attachments = recorder_attachments(scenario, codec)
    metadata = {"run": dict(run_info or {})}
    bus = open_bus(spec, part="record")
    try:
        rec = BusRecorder(
            bus,
            out_path,
            lockstep=lockstep,
            codec=codec,
            stop_event=stop_event,
            attachments=attachments,
            metadata=metadata,
            mirror=live,
        )
        stats = rec.run(duration_s=duration_s, on_ready=on_ready)
        stats.rx_dropped, stats.rx_buffer_bytes = rx_figures(bus)
    except OSError as err:
        if err.filename is None and err.errno is not None:  # a write: name the log it was for
            raise OSError(err.errno, err.strerror, str(out_path)) from err
        raise
    finally:
        bus.shutdown()
    return stats


# -------------------------------------------------------------- on a shared machine


def part_scheduling(part: str, realtime: bool) -> None:
    """Scheduling of the parts of a run on a shared machine.

    The recorder is always niced (it buffers; the loops must not wait for it).  In
    lock-step the bench and the controller are throughput jobs: SCHED_BATCH stops each
    frame's wake-up from preempting its sender (~100 us per multicast frame on two cores).
    In real time the controller may ask for SCHED_FIFO with ``--rt-priority``.
    """
    try:
        if part == "record":
            os.nice(10)
        elif not realtime:
            os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    except (AttributeError, OSError) as err:
        log.debug("scheduling policy not available: %s", err)


def new_run_dir(root: Path) -> Path:
    """A directory under ``root`` that no earlier run used, named by the UTC start time
    (``20260102T030405Z``, ``...Z-2`` for a second start in the same second), created."""
    root.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    for n in range(1, 1000):
        out = root / (stamp if n == 1 else f"{stamp}-{n}")
        try:
            out.mkdir()
        except FileExistsError:
            continue
        return out
    raise WheelchairError(f"{root}: 999 runs started in the second {stamp}")


#: How long ``control --live`` waits for its bus recorder to listen.
_RECORDER_START_S = 30.0


@contextlib.contextmanager
def bus_feed(
    spec: BusSpec, live_socket: str, *, realtime: bool, dbc: str | None = None
) -> Iterator[None]:
    """``control --live``: every frame on the bus for the view whose feed is ``live_socket``,
    recorded by a ``record`` process of its own (its log goes to the null device), so that
    decoding the bus costs the controller's process nothing."""
    if not transport.profile(spec.interface).between_processes:
        log.warning("live: a virtual bus is private to this process; the view shows no frames")
        yield
        return
    argv = [*transport.bus_argv(spec), "--out", os.devnull, "--live-feed", live_socket]
    if realtime:
        argv.append("--realtime")
    if dbc:
        argv += ["--dbc", dbc]
    proc = subprocess.Popen(
        transport.python_argv("record", *argv, "--ready"), stdout=subprocess.PIPE, text=True
    )
    try:
        # the controller starts once the recorder listens, so that the view has every frame
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], _RECORDER_START_S)
        line = proc.stdout.readline() if ready else ""
        if line.strip() != "READY":
            log.warning(
                "live: the bus recorder did not start within %.0f s; the view may lack frames",
                _RECORDER_START_S,
            )
        yield
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
