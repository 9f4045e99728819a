"""``wheelchair-hil run``: bench, controller and recorder together, then the summary.

* ``--bus virtual``: bench and controller are threads of this process; the recorder
  writes from a forked process (:mod:`tools.logs.bustap`), or from a third thread.
* ``--bus udp_multicast`` / ``socketcan``: three OS processes (``sim``, ``control``,
  ``record``) on one bus, started and watched by :mod:`tools.run.processes`.  For
  udp_multicast outside a private namespace, ``run`` has re-executed itself inside one
  (``unshare -rn``) before it came here (:mod:`tools.run.entry`).

Everything is validated before a process starts (scenario, route, controller,
DBC), so bad input fails with one line and leaves nothing running.  If a part
fails, the others are stopped and the first error is reported.
"""

from __future__ import annotations

import contextlib
import json
import logging
import sys
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dbc.codec import Codec
from dbc.runtime import jsonsafe, stopping
from tools.bus import transport
from tools.bus.rxloss import LOSS_EXIT
from tools.bus.transport import BusSpec
from tools.live.feed import LiveFeed
from tools.live.server import LiveServer, format_live_stats
from tools.logs import mcap_io, runlog
from tools.logs.bustap import ChannelTap, TapError
from tools.logs.collect import FrameCollector
from tools.logs.runlog import loss_message, lost_from_stats
from tools.metrics.tracking import BusCollector
from tools.run import scenario as scenario_mod
from tools.run.from_args import bus_argv
from tools.run.processes import Part, PartFailedError, Parts
from tools.run.runner import (
    RECORDER_WINDOW_STEPS,
    RunPlan,
    make_plan,
    open_controller,
    recorder_attachments,
    run_bench,
    run_controller,
    run_recorder,
)

if TYPE_CHECKING:
    from controller.node import ControllerNode
    from firmware_sim.bench import Bench

log = logging.getLogger(__name__)

# ---------------------------------------------------------------------- threads


def run_threads(
    spec: BusSpec,
    plan_: RunPlan,
    out: Path,
    codec: Codec,
    *,
    recorder: str = "process",
    one_thread: bool = True,
    live: LiveServer | None = None,
    stop_event: threading.Event | None = None,
    collect: bool = False,
    on_parts: Callable[[Bench, ControllerNode], None] | None = None,
) -> dict[str, Any]:
    """All three parts on the virtual bus, in this process.

    ``live``: the recorder's and the controller's logs are also fed to this live view.
    ``stop_event`` (``run``'s: a stop signal sets it) ends the run early, as a part that
    fails does.

    Lock-step with ``one_thread`` (the default): the bench and the controller share this
    thread.  The controller's clock does not wait; whenever the bench would wait for a
    frame, the controller runs the ticks that are due (:func:`_run_together`).  Nothing
    is handed between threads, which is what a lock-step step mostly cost.  Otherwise
    (real time, or ``one_thread=False``) they are two threads.

    ``recorder="process"`` records through a :class:`~tools.logs.bustap.ChannelTap` (the
    log is written by a forked process, off this interpreter's lock); if this process
    cannot fork, or with ``recorder="thread"``, the recorder is a thread of its own
    reading the bus like the others (then the bench waits for its ``Bench_Record_Ack``).
    ``collect`` (one-thread lock-step runs): a :class:`~tools.logs.collect.FrameCollector`
    also keeps, in this process, what the summary reads (``results["frames"]``; with
    ``results["control_config"]``, the controller's configuration record,
    :func:`build_summary` makes the summary from it instead of reading the log back).
    ``recorder="none"`` writes no log at all and implies ``collect``; the controller then
    keeps no log either.  ``on_parts`` (one-thread lock-step runs) is called with the bench
    and the controller's node once both are built, before the bench runs.
    """
    if recorder not in ("process", "thread", "none"):
        raise ValueError(f"recorder={recorder!r}: choose 'process', 'thread' or 'none'")
    collect = collect or recorder == "none"
    if (collect or on_parts is not None) and (plan_.realtime or not one_thread):
        raise ValueError("collecting frames and on_parts are for one-thread lock-step runs")
    if recorder == "none" and live is not None:
        raise ValueError("a run without a log has nothing to show a live view")
    stop = stop_event if stop_event is not None else threading.Event()
    results: dict[str, Any] = {}
    errors: list[BaseException] = []
    ready = {name: threading.Event() for name in ("record", "control")}

    def guard(name: str, fn: Any, *a: Any, **kw: Any) -> None:
        try:
            results[name] = fn(*a, **kw)
        except BaseException as err:
            errors.append(err)
            stop.set()
        finally:
            if name in ready:
                ready[name].set()

    lockstep = not plan_.realtime
    tap: ChannelTap | None = None
    collector: FrameCollector | None = None
    if collect:
        collector = FrameCollector(spec.channel, lockstep=True, codec=codec)
        collector.start()
    if recorder == "process":
        tap = ChannelTap(
            spec.channel,
            out / "run.mcap",
            lockstep=lockstep,
            codec=codec,
            attachments=recorder_attachments(plan_.scenario, codec),
            metadata={"run": _run_info(plan_, spec)},
            mirror=live.feed() if live else None,
        )
        try:
            tap.start()
        except TapError as err:
            log.warning("recording from a thread instead: %s", err)
            tap = None
    rec: threading.Thread | None = None
    if tap is None and recorder != "none":
        rec = threading.Thread(
            target=guard,
            name="record",
            daemon=True,
            args=("record", run_recorder, spec, out / "run.mcap"),
            kwargs={
                "lockstep": lockstep,
                "scenario": plan_.scenario,
                "stop_event": stop,
                "on_ready": ready["record"].set,
                "codec": codec,
                "run_info": _run_info(plan_, spec),
                "live": live.feed() if live else None,
            },
        )
        rec.start()
        ready["record"].wait(10)
    window = 0 if (plan_.realtime or rec is None) else RECORDER_WINDOW_STEPS
    try:
        ctl_feed = live.feed() if live else None
        if lockstep and one_thread:
            _run_together(
                spec,
                plan_,
                out,
                codec,
                stop,
                window,
                results,
                errors,
                ctl_feed,
                telemetry=recorder != "none",
                on_parts=on_parts,
            )
        else:
            _run_apart(
                spec, plan_, out, codec, stop, window, guard, ready["control"], rec, ctl_feed
            )
    finally:
        if tap is not None:
            try:
                results["record"] = tap.stop()
            except TapError as err:
                errors.append(PartFailedError(f"record: {err}"))
        if collector is not None:
            stats = collector.stop()
            results.setdefault("record", stats)
            results["frames"] = collector
    if rec is not None:
        rec.join(30.0)
        if rec.is_alive():
            stop.set()
            rec.join(5)
    if errors:
        raise errors[0]
    rstats = results.get("record")
    if rstats is not None:
        jsonsafe.write(out / "recorder_stats.json", rstats.as_dict(), indent=2)
    return results


def _run_together(
    spec: BusSpec,
    plan_: RunPlan,
    out: Path,
    codec: Codec,
    stop: threading.Event,
    window: int,
    results: dict[str, Any],
    errors: list[BaseException],
    live: LiveFeed | None = None,
    *,
    telemetry: bool = True,
    on_parts: Callable[[Bench, ControllerNode], None] | None = None,
) -> None:
    """Lock-step with the bench and the controller in this thread.

    The bench runs as it always does; its bus calls the controller's
    :meth:`~controller.node.ControllerNode.poll` whenever the bench would wait for a
    frame, and the controller runs the ticks that are due then.  Both parts are the
    same code as in their own threads or processes.  A part that fails stops the run
    (recorded in ``errors``), as in :func:`_run_apart`.
    """
    ctl = open_controller(
        spec,
        plan_,
        out_dir=out,
        stop_event=stop,
        codec=codec,
        wait=False,
        live=live,
        telemetry=telemetry,
    )
    results["control_config"] = ctl.config
    node = ctl.node
    alive = True

    def poll_controller() -> None:
        nonlocal alive
        if not alive:
            return
        try:
            alive = node.poll()
        except BaseException as err:  # the controller failed: the bench ends after this step
            alive = False
            errors.append(err)
            stop.set()

    try:
        node.begin()
        try:
            results["sim"] = run_bench(
                spec,
                plan_,
                out_dir=out,
                stop_event=stop,
                codec=codec,
                recorder_window_steps=window,
                on_idle=poll_controller,
                on_bench=None if on_parts is None else (lambda bench: on_parts(bench, node)),
            )
        except BaseException as err:
            errors.append(err)
            stop.set()
        poll_controller()  # Bench_End (or the stop) ends the controller's run
        if alive:
            log.warning("controller still running after the bench ended; stopping it")
        node.end()
    except BaseException:
        ctl.abandon()
        raise
    finally:
        ctl.bus.shutdown()
    results["control"] = ctl.finish()


def _run_apart(
    spec: BusSpec,
    plan_: RunPlan,
    out: Path,
    codec: Codec,
    stop: threading.Event,
    window: int,
    guard: Any,
    control_ready: threading.Event,
    rec: threading.Thread | None,
    live: LiveFeed | None = None,
) -> None:
    """The bench and the controller in threads of their own."""
    ctl = threading.Thread(
        target=guard,
        name="control",
        daemon=True,
        args=("control", run_controller, spec, plan_),
        kwargs={
            "out_dir": out,
            "stop_event": stop,
            "on_ready": control_ready.set,
            "codec": codec,
            "live": live,
        },
    )
    sim = threading.Thread(
        target=guard,
        name="sim",
        daemon=True,
        args=("sim", run_bench, spec, plan_),
        kwargs={
            "out_dir": out,
            "stop_event": stop,
            "codec": codec,
            "recorder_window_steps": window,
        },
    )
    ctl.start()
    control_ready.wait(10)
    sim.start()
    sim.join()
    stop_after = time.monotonic() + 30.0
    others = [t for t in (ctl, rec) if t is not None]
    for t in others:
        t.join(max(0.0, stop_after - time.monotonic()))
    if any(t.is_alive() for t in others):
        stop.set()
        for t in others:
            t.join(5)


# -------------------------------------------------------------------- processes


def _run_info(plan_: RunPlan, spec: BusSpec) -> dict[str, str]:
    return {
        "controller": plan_.controller,
        "scenario": plan_.scenario.name,
        "bus": spec.describe(),
        "mode": "realtime" if plan_.realtime else "lockstep",
        "seed": str(plan_.seed),
        "duration_s": f"{plan_.duration_s:.3f}",
        "fault_setting": plan_.scenario.setting,
    }


def lost_frames(out: Path) -> dict[str, int]:
    """Frames each part lost, from its statistics in ``out`` (parts that lost none are left out)."""
    stats = {}
    for name in ("bench_stats.json", "controller_stats.json", "recorder_stats.json"):
        try:
            stats[name] = json.loads((out / name).read_text())
        except (OSError, ValueError):
            stats[name] = {}
    return lost_from_stats(
        stats["bench_stats.json"], stats["controller_stats.json"], stats["recorder_stats.json"]
    )


def run_processes(
    spec: BusSpec,
    plan_: RunPlan,
    out: Path,
    dbc: str | None,
    rt_priority: int = 0,
    live: LiveServer | None = None,
    stop_event: threading.Event | None = None,
) -> dict[str, Any]:
    """The three parts as separate OS processes on ``spec`` (``live``: the recorder and the
    controller feed this live view), started and watched by :class:`~tools.run.processes.Parts`.
    ``stop_event`` set (a stop signal to ``run``): each part is sent SIGTERM and ends with its
    own status."""
    logs = out / "logs"
    logs.mkdir(exist_ok=True)

    common = [
        *bus_argv(spec),
        "--scenario",
        str(plan_.scenario.path),
        "--duration",
        repr(plan_.duration_s),
        "--seed",
        str(plan_.seed),
        "--ready",
    ]
    if plan_.realtime:
        common.append("--realtime")
    if dbc:
        common += ["--dbc", dbc]
    feed = ["--live-feed", live.socket_path] if live else []
    control_extra = ["--rt-priority", str(rt_priority)] if rt_priority else []
    # the bench stands in for the drives' own hardware: one priority above the host's
    sim_extra = ["--rt-priority", str(min(rt_priority + 1, 99))] if rt_priority else []
    # the recorder one priority below the host: the loops first, but no starved black box
    record_extra = ["--rt-priority", str(max(rt_priority - 1, 1))] if rt_priority else []
    record = transport.python_argv(
        "record", *common, *record_extra, *feed, "--out", str(out / "run.mcap")
    )
    control = transport.python_argv(
        "control",
        *common,
        *control_extra,
        *feed,
        "--controller",
        plan_.controller,
        "--out",
        str(out),
    )
    sim = transport.python_argv(
        "sim",
        *common,
        *sim_extra,
        "--out",
        str(out),
        "--recorder-window",
        str(RECORDER_WINDOW_STEPS),
    )
    with Parts() as parts:
        parts.start(Part("record", tuple(record), str(logs / "record.log")))
        parts.start(Part("control", tuple(control), str(logs / "control.log")))
        parts.start(Part("sim", tuple(sim), str(logs / "sim.log"), ready=False))
        timeout = plan_.duration_s * (1.5 if plan_.realtime else 3.0) + 60.0
        # a part that lost frames ends with LOSS_EXIT after a whole run: the summary says so
        parts.wait(timeout, ok=(0, LOSS_EXIT), stop_event=stop_event)
    return {}


# ----------------------------------------------------------------------- summary


def build_summary(
    out: Path,
    plan_: RunPlan,
    spec: BusSpec,
    wall_total_s: float,
    collector: BusCollector | None = None,
    results: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Finalize the run's log (``tools.logs.runlog.finalize``) and compute the summary from it.

    The log is read once, while it is merged; ``collector`` (give one to collect more
    topics, e.g. the controller's) holds what was read afterwards.  A run whose frames were
    collected in this process (:func:`run_threads`'s ``collect``: pass its ``results``) is
    summarized from them and the parts' statistics, by the same code; its log, if it has
    one, is still merged, and ``collector`` then sees only what the merge writes.
    """
    frames: FrameCollector | None = (results or {}).get("frames")
    if frames is None and collector is not None and collector.wanted is not None:
        raise ValueError("build_summary needs a BusCollector of every /can/ channel (names=None)")
    info = {
        **_run_info(plan_, spec),
        "bitrate": str(spec.bitrate),
        "wall_total_s": repr(wall_total_s),
    }
    if frames is not None:
        if (out / "run.mcap").exists():
            runlog.finalize(out, info, on_message=collector)
        md = {
            "run": info,
            "recorder": frames.metadata(),
            "controller_config": dict((results or {}).get("control_config") or {}),
        }
        bus = frames.series.series(md, {})
        summary = runlog.summarize(None, trajectory=plan_.trajectory, fallback_dir=out, bus=bus)
    else:
        collector = BusCollector() if collector is None else collector
        contents = runlog.finalize(out, info, on_message=collector)
        if contents is None:  # not merged: read what the recorder wrote
            collector.clear()
            contents = mcap_io.scan(out / "run.mcap", collector)
        bus = collector.series(contents.metadata, contents.attachments)
        summary = runlog.summarize(
            out / "run.mcap", trajectory=plan_.trajectory, fallback_dir=out, bus=bus
        )
    # what the launcher knows first-hand wins over the log (e.g. a log whose merge failed)
    summary.update(
        controller=plan_.controller,
        scenario=plan_.scenario.name,
        bus=spec.describe(),
        mode="realtime" if plan_.realtime else "lockstep",
        seed=plan_.seed,
        fault_setting=plan_.scenario.setting,
        wall_total_s=wall_total_s,
    )
    return summary  # runlog.summarize marked it complete or not, from the parts' statistics


# --------------------------------------------------------------------------- run


def run_here(args: Any, spec: BusSpec, why: str) -> int:
    """``wheelchair-hil run`` in this process, on ``spec`` (chosen for ``why``), once
    :func:`tools.run.entry.run` has decided it runs here: validates every input before any
    part starts, runs, then writes and prints the summary."""

    codec = Codec(args.dbc) if args.dbc else Codec.default()
    scen = scenario_mod.load(args.scenario)
    plan_ = make_plan(
        scen, args.controller, realtime=args.realtime, duration_s=args.duration, seed=args.seed
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    transport.profile(spec.interface).check(spec)  # socketcan without AF_CAN: said here
    print(
        f"bus: {spec.describe()} ({why}); controller {plan_.controller}; scenario {scen.name}; "
        f"{'real time' if plan_.realtime else 'lock-step'}; {plan_.duration_s:.1f} s simulated",
        file=sys.stderr,
    )
    with contextlib.ExitStack() as stack:
        live = None
        if args.live_feed:
            live = LiveServer.attached(args.live_feed)
        elif args.live is not None:
            live = stack.enter_context(LiveServer(args.live))
            print(f"live: {live.url} (open it in Foxglove)", file=sys.stderr, flush=True)
        t0 = time.monotonic()
        stop = stopping.stop_event()
        if not transport.profile(spec.interface).between_processes:  # one process's bus
            run_threads(spec, plan_, out, codec, live=live, stop_event=stop)
        else:
            run_processes(
                spec, plan_, out, args.dbc, rt_priority=args.rt_priority, live=live, stop_event=stop
            )
        wall = time.monotonic() - t0
    if live is not None and not args.live_feed:
        jsonsafe.write(out / "live_stats.json", live.stats, indent=2)
        print(f"live: {format_live_stats(live.stats)}", file=sys.stderr)
    summary = build_summary(out, plan_, spec, wall)
    if stopping.received():  # ended early on request: the log is what the parts recorded
        summary["stopped_by"] = stopping.received()[0]
    jsonsafe.write(out / "summary.json", summary, indent=2, default=str)
    print(format_summary(summary))
    if not summary["complete"]:
        print(f"wheelchair-hil: error: {loss_message(summary['lost_frames'])}", file=sys.stderr)
        return LOSS_EXIT
    return 0


def format_summary(s: dict[str, Any]) -> str:
    def f(key: str, scale: float = 1.0, unit: str = "", fmt: str = ".4f") -> str:
        v = s.get(key)
        return "n/a" if v is None or v != v else f"{v * scale:{fmt}}{unit}"

    if s.get("complete") is False and s.get("lost_frames"):
        return "\n".join(
            [
                f"{s['controller']} on {s['scenario']} ({s['mode']}, {s['bus']}): INCOMPLETE",
                f"  {loss_message(s.get('lost_frames') or {})}",
                f"  {s.get('frames_total')} frames recorded; stop: {s.get('stop_reason')}; "
                "figures of the partial log are under 'partial' in summary.json",
            ]
        )

    def t(key: str) -> str:
        v = s.get(key)
        return "n/a" if v is None or v == "" else str(v)

    lines = [
        f"{t('controller')} on {t('scenario')} ({t('mode')}, {t('bus')})",
        f"  position RMSE {f('rmse_pos_m', 100, ' cm', '.2f')}, max {f('max_pos_err_m', 100, ' cm', '.2f')}; "
        f"heading RMSE {f('rmse_phie_rad', 57.29578, ' deg', '.2f')}, max {f('max_phie_rad', 57.29578, ' deg', '.2f')}",
        f"  x_e RMSE {f('rmse_xe_m', 1, ' m')}, y_e RMSE {f('rmse_ye_m', 1, ' m')}, phi_e RMSE {f('rmse_phie_rad', 1, ' rad')}",
        f"  {f('sim_duration_s', 1, ' s', '.1f')} simulated in {f('wall_s', 1, ' s', '.2f')} "
        f"({f('real_time_factor', 1, 'x', '.1f')} real time); {t('frames_total')} frames; "
        f"{t('deadline_misses')} deadline misses; stop: {t('stop_reason')}",
    ]
    for gap in s.get("missing") or []:
        lines.append(f"  MISSING: {gap}")
    b = s.get("lockstep_budget_us")
    if isinstance(b, dict) and all(v == v for v in b.values()):
        lines.append(
            f"  per step: physics {b['physics']:.0f} us, controller tick {b['controller_tick']:.0f} us, "
            f"the rest {b['rest']:.0f} us (physics and ticks alone: {b['rtf_ceiling']:.1f}x)"
        )
    return "\n".join(lines)
