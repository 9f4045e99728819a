"""A run's three parts in this process, on python-can's virtual bus (``run --bus virtual``,
one experiment as a function, replay's what-if, the evaluation's branches).

In lock-step the bench and the controller share one thread (:func:`run_threads`: the
controller runs its due ticks whenever the bench would wait for a frame); in real time they
are threads of their own.  The recorder writes from a forked process
(:mod:`tools.logs.bustap`), or from a thread, or not at all (the frames the summary reads are
then kept in memory: :mod:`tools.logs.collect`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dbc.codec import Codec
from dbc.runtime import jsonsafe
from tools.bus.transport import BusSpec
from tools.live.feed import LiveFeed
from tools.live.server import LiveServer
from tools.logs.bustap import ChannelTap, TapError
from tools.logs.collect import FrameCollector
from tools.run.parts import (
    RECORDER_WINDOW_STEPS,
    open_controller,
    recorder_attachments,
    run_bench,
    run_controller,
    run_recorder,
)
from tools.run.plan import RunPlan
from tools.run.processes import PartFailedError
from tools.run.summary import run_info

if TYPE_CHECKING:
    from controller.node import ControllerNode
    from firmware_sim.bench import Bench

log = logging.getLogger(__name__)


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
    # whether this run writes out/run.mcap (build_summary finalizes only a log of this run,
    # never one an earlier run left in ``out``)
    results["logged"] = recorder != "none"
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
            metadata={"run": run_info(plan_, spec)},
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
                "run_info": run_info(plan_, spec),
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
