"""Shared fixtures: every test fails if it leaks a python-can bus or a child process.

In CI (``CI`` set to ``true`` or ``1``, as ``.ci/run`` and most CI services do) a test that
skips fails instead, unless its reason is one of :data:`ALLOWED_SKIPS`: a check that cannot
do its job (a missing tool or package, a real-time run that never got going) must not pass
quietly.
"""

from __future__ import annotations

import contextlib
import os
import re
import weakref
from collections.abc import Generator, Iterator
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


#: The skips CI allows: a pattern of the skip's reason, and why that skip is right in CI.
#: Any other skip fails there (see the module docstring); this is the one reviewed list.
ALLOWED_SKIPS: dict[str, str] = {
    r"^README\.md:\d+: ": (
        "a README block marked not to run says why (hardware, root, the whole campaign, a lane "
        "that another test runs); test_every_readme_block_is_run_or_says_why_not holds that "
        "each says why"
    ),
    r"^vcan0 is up on this kernel": (
        "where the kernel has vcan0 the socketcan lane runs directly, not in a guest"
    ),
    r"^this kernel has SocketCAN; the error path cannot be exercised": (
        "the error of a kernel without AF_CAN cannot happen on a kernel with it"
    ),
    r"^this test process already runs in a private namespace": (
        "the check that a part refuses udp_multicast outside a private namespace needs to "
        "start outside one"
    ),
}


def in_ci() -> bool:
    """Whether this is a CI run (``CI`` is ``true`` or ``1``)."""
    return os.environ.get("CI", "").strip().lower() in ("true", "1")


def _skip_reason(report: pytest.TestReport) -> str:
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        reason = str(longrepr[2])
    else:
        reason = str(longrepr)
    return reason.removeprefix("Skipped: ")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, pytest.TestReport, None]:
    outcome = yield
    report: pytest.TestReport = outcome.get_result()
    if not (report.skipped and in_ci()) or hasattr(report, "wasxfail"):
        return
    reason = _skip_reason(report)
    if any(re.search(pattern, reason) for pattern in ALLOWED_SKIPS):
        return
    report.outcome = "failed"
    report.longrepr = (
        f"skipped in CI, and the reason is not one of tests/conftest.py's ALLOWED_SKIPS: {reason}"
    )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The files that declare their length (``pytest.mark.heavy(seconds=N)``) first, heaviest
    first, the others in their order.  make test gives each file to one of two workers in this
    order (``--dist loadfile --no-loadscope-reorder``): the README's install, the soak and the
    attacks start at once and the short files fill in beside them and at the end.
    pytest-xdist's own order, most tests first, started the 3-minute soak's one test behind
    the other paired files (the paired tests 283 s instead of about 225) and the README's
    install block among the last lock-step files."""

    def declared(item: pytest.Item) -> float:
        mark = item.get_closest_marker("heavy")
        if mark is None:
            return 0.0
        seconds = mark.kwargs.get("seconds", mark.args[0] if mark.args else None)
        if not isinstance(seconds, int | float):
            raise pytest.UsageError(f"{item.nodeid}: heavy needs seconds=N, got {mark}")
        return -float(seconds)

    items.sort(key=declared)  # stable: everything else keeps its order
