"""The scheduling the real-time tests give their parts: SCHED_FIFO, as the chair's service
runs them (``install-service`` writes ``--rt-priority 80``), where this machine permits it.

A real-time run judged beside other work (a second real-time run, or lock-step tests on
the other core) then keeps its 10 ms ticks: the bench, standing in for the drives' own
hardware, one priority above the controller, the recorder one below it
(:func:`tools.run.processes.realtime_parts`).  Their start-up (imports) happens before
they ask for it, at normal priority, so no test is starved by another's start.  Where
SCHED_FIFO is not permitted (not root, no CAP_SYS_NICE), ``RT_PRIORITY`` is 0 and the
parts run as a user's would.
"""

from __future__ import annotations

import subprocess
import sys

from tools.run.processes import rt_option


def _fifo_permitted() -> bool:
    probe = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
    res = subprocess.run(
        [sys.executable, "-I", "-S", "-c", probe], capture_output=True, check=False
    )
    return res.returncode == 0


#: The controller's SCHED_FIFO priority in the real-time tests (0: not permitted here).
RT_PRIORITY = 20 if _fifo_permitted() else 0


def rt(part: str) -> str:
    """The ``--rt-priority`` option for ``part`` (``sim``, ``control``, ``record``), as
    :func:`tools.run.processes.realtime_parts` gives them; empty where not permitted."""
    return " ".join(rt_option(part, RT_PRIORITY))
