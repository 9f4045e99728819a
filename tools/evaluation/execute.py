"""Executing a campaign's runs: here one after the other, in a pool of processes, or on Dask.

:func:`execute` runs :func:`~tools.evaluation.task.run_task` for every task, the longest
first; in the pool, the runs without a log that differ only in their faults share their start
(:func:`groups`, :func:`~tools.evaluation.task.run_group`).  Whatever the executor and the
number of workers, every run gives the same figures.
"""

from __future__ import annotations

import logging
import multiprocessing
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from tools.console.progress import Progress
from tools.evaluation.plan import EvaluationError
from tools.evaluation.task import Task, run_group, run_task


def _cost(task: Task) -> float:
    """Rough relative cost, to start the longest runs first."""
    c = {"adaptive": 1.4}.get(task.controller, 1.0)
    d = task.duration_s if task.duration_s is not None else 90.0
    return c * d


ProgressFn = Callable[[dict[str, Any]], None]


def execute(
    tasks: Sequence[Task],
    root: Path,
    *,
    workers: int = 1,
    scheduler: Any = None,
    progress: bool = True,
    table: Sequence[str] = (),
) -> dict[str, dict[str, Any]]:
    """Run ``tasks``; return each one's :func:`run_task` output by key.

    ``scheduler`` (a Dask scheduler address, or a ``distributed`` cluster object) runs
    them on a Dask cluster; otherwise ``workers`` > 1 uses a pool of that many worker
    processes (spawned: no state is inherited) and 1 runs them here, one after the other.
    In the pool, the runs without a log on the ``table``'s scenarios share their start
    (:func:`groups`, :func:`run_group`): the same figures as run one by one.
    """

    order = sorted(tasks, key=lambda t: (-_cost(t), t.key))
    out: dict[str, dict[str, Any]] = {}
    # a bar on a terminal; elsewhere (a CI log) a plain line per tenth of the runs
    bar = Progress(len(order), "evaluate", "run", enabled=progress)

    def done(res: dict[str, Any]) -> None:
        out[res["key"]] = res
        if res.get("error"):
            bar.write(f"run {res['key']} failed: {res['error']}")
        bar.update(1, note=f"last: {res['key']}")

    with bar:
        if scheduler is not None:
            _execute_dask(order, root, scheduler, done)
        elif workers > 1 and len(order) > 1:
            _execute_pool(order, root, workers, done, table)
        else:
            for t in order:
                done(run_task(t, str(root)))
    return out


def _worker_init() -> None:
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)


def groups(tasks: Sequence[Task], table: Sequence[str]) -> list[list[Task]]:
    """``tasks`` as units of work: the runs without a log of one controller, variation and
    fault setting on the ``table``'s scenarios (which differ only in their faults) form one
    group, run as branches of one run (:func:`run_group`); every other task is a unit of its
    own.  In the order of ``tasks``' first members."""
    units: dict[Any, list[Task]] = {}
    for t in tasks:
        shared = not t.log and t.scenario in table
        key: Any = (
            (t.controller, t.variation, t.setting, t.base_seed, t.duration_s, t.gains)
            if shared
            else t.key
        )
        units.setdefault(key, []).append(t)
    return list(units.values())


def _execute_pool(
    tasks: Sequence[Task],
    root: Path,
    workers: int,
    done: ProgressFn,
    table: Sequence[str] = (),
) -> None:
    ctx = multiprocessing.get_context("spawn")
    units = groups(tasks, table)
    with ProcessPoolExecutor(
        max_workers=min(workers, len(units)), mp_context=ctx, initializer=_worker_init
    ) as pool:
        futures = [pool.submit(run_group if len(u) > 1 else _run_unit, u, str(root)) for u in units]
        for fut in as_completed(futures):
            for r in fut.result():
                done(r)


def _run_unit(tasks: Sequence[Task], root: str) -> list[dict[str, Any]]:
    """:func:`run_task` of a unit of one task, as a list (the pool's other worker function)."""
    return [run_task(t, root) for t in tasks]


def _execute_dask(tasks: Sequence[Task], root: Path, scheduler: Any, done: ProgressFn) -> None:
    try:
        from distributed import Client, as_completed  # lazy: the optional [dask] extra
    except ImportError as err:
        raise EvaluationError(
            f"--scheduler needs dask.distributed ({err}); install the optional extra: "
            "pip install 'wheelchair-hil[dask]'"
        ) from err
    try:
        client = Client(scheduler, set_as_default=False)
    except OSError as err:
        raise EvaluationError(f"--scheduler {scheduler}: cannot reach it: {err}") from err
    with client:
        futures = [
            client.submit(run_task, t, str(root), key=f"evaluate-{t.key}", pure=False)
            for t in tasks
        ]
        for fut in as_completed(futures, loop=client.loop):
            done(fut.result())
