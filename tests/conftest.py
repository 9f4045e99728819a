"""Shared fixtures: every test fails if it leaks a python-can bus or a child process."""

from __future__ import annotations

import contextlib
import os
import weakref
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

_open_buses: weakref.WeakSet[can.BusABC] = weakref.WeakSet()
_orig_init = can.BusABC.__init__


def _tracking_init(self: can.BusABC, *args: object, **kwargs: object) -> None:
    _orig_init(self, *args, **kwargs)  # type: ignore[arg-type]
    _open_buses.add(self)


can.BusABC.__init__ = _tracking_init  # type: ignore[method-assign]


def _children() -> set[int]:
    pids: set[int] = set()
    for task in Path(f"/proc/{os.getpid()}/task").iterdir():
        with contextlib.suppress(OSError):
            pids.update(int(p) for p in (task / "children").read_text().split())
    return pids


@pytest.fixture(autouse=True)
def no_leaked_buses_or_processes() -> Iterator[None]:
    before_children = _children()
    before_buses = {id(b) for b in _open_buses if not getattr(b, "_is_shutdown", True)}
    yield
    leaked = [
        b
        for b in list(_open_buses)
        if id(b) not in before_buses and not getattr(b, "_is_shutdown", True)
    ]
    for b in leaked:
        b.shutdown()
    assert not leaked, f"test leaked {len(leaked)} open bus(es): {leaked}"
    stray = _children() - before_children
    for pid in stray:
        with contextlib.suppress(OSError):
            os.kill(pid, 9)
    assert not stray, f"test left child processes running: {sorted(stray)}"
