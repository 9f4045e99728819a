"""Real-time scheduling: SCHED_FIFO and locked memory for this process.

Two uses, one implementation: a real-time loop asks for both and keeps what it is granted
(:func:`acquire`: the controller's clock, the bench and the recorder), and the doctor asks
whether the controller will be granted them, trying each and undoing it (:func:`probe`).

Memory is locked as the loop uses it: ``mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT)``
locks every page the process has in memory and every page it touches later, and never loads a
page it does not touch.  Without ``MCL_ONFAULT`` the kernel faults in and locks every page of
every mapping, the libraries' whole files included (numpy, scipy, OSQP): the controller's
resident memory went from 108 to 366 MB at the call, for code the loop never runs.  The
loop's own pages are touched in its first ticks (INIT and ARMING run the same tick as
TRACKING) and stay locked from then on.  A kernel older than 4.4 refuses the flag (EINVAL):
then everything is locked, as before.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import resource

#: mlockall's flags: the pages mapped now and those mapped later (MCL_CURRENT | MCL_FUTURE).
MCL_CURRENT_FUTURE = 3
#: ... each locked when it is faulted in (MCL_ONFAULT, Linux 4.4), not all faulted in now.
MCL_ONFAULT = 4


def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


def set_fifo(priority: int) -> str | None:
    """Put this process on SCHED_FIFO at ``priority``: None if granted, else why not."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except AttributeError:
        return "not available on this system"
    except OSError as err:
        return err.strerror or str(err)
    return None


def lock_memory() -> str | None:
    """Lock this process's memory (``mlockall``): None if locked, else why not (the reason
    and the RLIMIT_MEMLOCK that applies)."""
    try:
        libc = _libc()
        if libc.mlockall(MCL_CURRENT_FUTURE | MCL_ONFAULT) == 0:
            return None
        code = ctypes.get_errno()
        if code == errno.EINVAL and libc.mlockall(MCL_CURRENT_FUTURE) == 0:  # before 4.4
            return None
        reason = os.strerror(ctypes.get_errno() if code == errno.EINVAL else code)
    except (OSError, AttributeError) as err:
        return f"unavailable: {err}"
    soft, _hard = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    limit = "unlimited" if soft == resource.RLIM_INFINITY else f"{soft // 1024} KiB"
    return f"{reason}, memlock {limit}"


def acquire(priority: int) -> list[str]:
    """Ask for SCHED_FIFO at ``priority`` and locked memory, and keep what is granted; what
    the system granted or refused, as notes for the run's statistics."""
    why = set_fifo(priority)
    notes = [
        f"SCHED_FIFO priority {priority}" if why is None else f"SCHED_FIFO not permitted ({why})"
    ]
    why = lock_memory()
    notes.append("memory locked (mlockall)" if why is None else f"mlockall not permitted ({why})")
    return notes


def probe(priority: int) -> tuple[list[str], list[str]]:
    """Would :func:`acquire` (``priority``) be granted?  Each is tried and undone.

    Returns (what is permitted or already held, what is refused and why)."""
    granted: list[str] = []
    denied: list[str] = []
    try:
        policy = os.sched_getscheduler(0)
    except AttributeError:
        denied.append("SCHED_FIFO (not available on this system)")
    else:
        if policy == os.SCHED_FIFO:
            granted.append(f"already SCHED_FIFO priority {os.sched_getparam(0).sched_priority}")
        elif (why := set_fifo(priority)) is not None:
            denied.append(f"SCHED_FIFO priority {priority} ({why})")
        else:
            os.sched_setscheduler(0, policy, os.sched_param(0))
            granted.append(f"SCHED_FIFO priority {priority} permitted")
    why = lock_memory()
    if why is None:
        _libc().munlockall()
        granted.append("mlockall permitted")
    else:
        denied.append(f"mlockall ({why})")
    return granted, denied
