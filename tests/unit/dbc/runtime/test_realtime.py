"""SCHED_FIFO and locked memory: kept by a loop (acquire), tried and undone by the doctor
(probe).  The system calls are faked: granted here they would change the test process."""

from __future__ import annotations

import ctypes
import errno
import os
from typing import Any

import pytest

from dbc.runtime import realtime


class FakeLibc:
    def __init__(self, *, lock: bool, onfault: bool = True) -> None:
        self.lock = lock
        self.onfault = onfault  # a kernel older than 4.4 refuses MCL_ONFAULT with EINVAL
        self.calls: list[str] = []

    def mlockall(self, flags: int) -> int:
        self.calls.append(f"mlockall({flags})")
        if flags & 4 and not self.onfault:
            ctypes.set_errno(errno.EINVAL)
            return -1
        if self.lock:
            return 0
        ctypes.set_errno(errno.ENOMEM)
        return -1

    def munlockall(self) -> int:
        self.calls.append("munlockall")
        return 0


@pytest.fixture
def system(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """A process on SCHED_OTHER whose scheduler and memory calls are recorded."""
    state: dict[str, Any] = {"policy": os.SCHED_OTHER, "calls": [], "fifo": True}

    def setscheduler(pid: int, policy: int, param: os.sched_param) -> None:
        if policy == os.SCHED_FIFO and not state["fifo"]:
            raise PermissionError(errno.EPERM, "Operation not permitted")
        state["calls"].append((policy, param.sched_priority))
        state["policy"] = policy

    monkeypatch.setattr(os, "sched_getscheduler", lambda _pid: state["policy"])
    monkeypatch.setattr(os, "sched_setscheduler", setscheduler)
    state["libc"] = FakeLibc(lock=True)
    monkeypatch.setattr(realtime, "_libc", lambda: state["libc"])
    return state


def test_a_loop_keeps_what_it_is_granted(system: dict[str, Any]) -> None:
    assert realtime.acquire(80) == ["SCHED_FIFO priority 80", "memory locked (mlockall)"]
    assert system["policy"] == os.SCHED_FIFO and system["calls"] == [(os.SCHED_FIFO, 80)]
    # the pages it has and those it touches: never the untouched rest of the libraries
    assert system["libc"].calls == ["mlockall(7)"]


def test_a_kernel_without_mcl_onfault_locks_everything(system: dict[str, Any]) -> None:
    system["libc"] = FakeLibc(lock=True, onfault=False)
    assert realtime.acquire(80)[1] == "memory locked (mlockall)"
    assert system["libc"].calls == ["mlockall(7)", "mlockall(3)"]


def test_a_loop_refused_says_why_and_runs_on(system: dict[str, Any]) -> None:
    system["fifo"] = False
    system["libc"] = FakeLibc(lock=False)
    notes = realtime.acquire(80)
    assert notes[0] == "SCHED_FIFO not permitted (Operation not permitted)"
    assert notes[1].startswith("mlockall not permitted (Cannot allocate memory, memlock ")
    assert system["policy"] == os.SCHED_OTHER


def test_the_doctors_probe_undoes_what_it_tried(system: dict[str, Any]) -> None:
    granted, denied = realtime.probe(80)
    assert granted == ["SCHED_FIFO priority 80 permitted", "mlockall permitted"] and not denied
    assert system["calls"] == [(os.SCHED_FIFO, 80), (os.SCHED_OTHER, 0)]
    assert system["policy"] == os.SCHED_OTHER
    assert system["libc"].calls == ["mlockall(7)", "munlockall"]


def test_the_doctors_probe_names_each_refusal(system: dict[str, Any]) -> None:
    system["fifo"] = False
    system["libc"] = FakeLibc(lock=False)
    granted, denied = realtime.probe(80)
    assert not granted
    assert denied[0] == "SCHED_FIFO priority 80 (Operation not permitted)"
    assert denied[1].startswith("mlockall (Cannot allocate memory, memlock ")
