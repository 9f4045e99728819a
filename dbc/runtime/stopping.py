"""Stop signals over a part's whole life: SIGTERM and SIGINT ask it to end, never kill it.

A part (``sim``, ``control``, ``record``, ``run``, ``replay``, ``live`` ...) reports what happened
through its exit status: 0 whole, 1 failed, 3 partial log.  systemd stops the chair's service
with SIGTERM, the launcher and the tests stop parts with SIGTERM, a terminal sends SIGINT; the
signal may come at any moment, before the part is ready, while it runs, while it is already
ending or flushing its log.  So:

* :func:`install` (the first thing ``tools.cli.main`` does) makes both signals set one
  process-wide :data:`STOP` event, before any heavy import, and unblocks them: a process
  started with them blocked (:func:`blocked_for_child`, what :class:`tools.run.processes.Parts`
  does) has no moment at all where a signal kills it; the signal waits until the handler is in
  place and is then seen as a stop request;
* every loop takes :func:`stop_event` as its stop event, so a stop that came before the loop
  started ends it at once, cleanly;
* a command that has no loop to end (``evaluate``, ``replay --verify`` ...) calls
  :func:`raise_on_stop`: the signal then raises :class:`StopRequested` in the main thread,
  as SIGINT's KeyboardInterrupt would, and ``main`` exits with ``128 + signal``;
* :func:`seal` (when the program has its status: ``tools.cli.entry``, never a command run
  in-process by ``tools.cli.main``, see :func:`handled`) sets both signals to be ignored.  CPython resets a
  Python handler to the default action while the interpreter finalizes, and a SIGTERM then
  killed a part that had already written its log and chosen its status (it reported -15).
  An ignored signal stays ignored through finalization, so the status is what the part said.

``WHEELCHAIR_HIL_SIGNAL_AT=MOMENT[,MOMENT...]`` (``MOMENT`` as in :data:`MOMENTS`, optionally
``MOMENT:INT`` for SIGINT) makes the part send itself SIGTERM at that moment of its life, so
that tests can stop it at an exact point instead of guessing one with a timer.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType

#: Set by SIGTERM or SIGINT: the part should end as soon as it can, with its real status.
STOP = threading.Event()
#: The signals that ask a part to stop.
SIGNALS = (signal.SIGTERM, signal.SIGINT)
#: The moments :envvar:`WHEELCHAIR_HIL_SIGNAL_AT` can name.
MOMENTS = (
    "start",  # the handlers are installed, nothing else is done
    "ready",  # the part said READY
    "bench-end",  # the bench sent Bench_End, or the recorder or the controller read it
    "flush",  # the log is being closed (its last chunk and summary)
    "exit",  # the status is chosen, the interpreter is about to finalize
)
SIGNAL_AT_ENV = "WHEELCHAIR_HIL_SIGNAL_AT"

#: the first and the latest stop signal received, and how many
_received: list[int] = []
_count = 0
_installed = False
_raise = False
_raised = False


class StopRequested(BaseException):
    """A stop signal came to a command that does not poll :data:`STOP` (:func:`raise_on_stop`)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _handler(signum: int, _frame: FrameType | None) -> None:
    # A signal can interrupt this very handler (a storm of them, or SIGINT on SIGTERM): the
    # nested call must return at once, never take STOP's lock again (held by the outer call:
    # a deadlock) nor nest further (a RecursionError).  Only the first call does anything.
    global _count, _raised
    _count += 1
    if len(_received) < 2:
        _received.append(signum)
    else:
        _received[1] = signum
    if _count == 1:
        STOP.set()
    if _raise and not _raised:
        _raised = True
        raise StopRequested(signum)


def raise_on_stop() -> None:
    """This command does not poll :data:`STOP`: a stop signal raises :class:`StopRequested`
    from now on (at once if one has come already)."""
    global _raise, _raised
    _raise = True
    if _received and not _raised:
        _raised = True
        raise StopRequested(_received[-1])


def install() -> threading.Event:
    """Both stop signals set :data:`STOP` from now on (idempotent; main thread only)."""
    global _installed
    if not _installed and threading.current_thread() is threading.main_thread():
        for sig in SIGNALS:
            signal.signal(sig, _handler)
        _installed = True
        # a parent may have started us with them blocked (no moment without a handler)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, SIGNALS)
    return STOP


@contextmanager
def handled() -> Iterator[threading.Event]:
    """A command run inside a longer-lived process (``tools.cli.main`` called by a test or a
    script): a fresh :data:`STOP`, the handlers installed for the block and the process's own
    handlers back afterwards (so that its children do not inherit ignored signals, and its
    own Ctrl-C works again)."""
    global _installed, _count, _raise, _raised
    if threading.current_thread() is not threading.main_thread():
        yield STOP
        return
    previous = {sig: signal.getsignal(sig) for sig in SIGNALS}
    was_installed = _installed
    STOP.clear()
    _received.clear()
    _count, _raise, _raised, _installed = 0, False, False, False
    try:
        yield install()
    finally:
        _raise = False
        for sig, h in previous.items():
            if h is not None:  # None: a handler not set from Python, left as it is
                signal.signal(sig, h)
        _installed = was_installed
        STOP.clear()  # the command is over: its stop is not the process's


def stop_event() -> threading.Event:
    """The process's stop event, with the handlers installed (:func:`install`)."""
    return install()


def received() -> list[str]:
    """The first and the latest stop signal received so far, by name (``["SIGTERM"]``)."""
    return [signal.Signals(s).name for s in _received]


def seal() -> None:
    """The status is chosen: from now on a stop signal changes nothing (see the module doc)."""
    global _raise
    _raise = False
    if threading.current_thread() is threading.main_thread():
        for sig in SIGNALS:
            signal.signal(sig, signal.SIG_IGN)
    at("exit")  # a signal now (as in the interpreter's finalization) is ignored


def ignore_in_child() -> None:
    """In a helper process forked by a part (a log writer): stop signals are its parent's
    business; the parent ends it by closing its pipe."""
    for sig in SIGNALS:
        signal.signal(sig, signal.SIG_IGN)


def blocked_for_child() -> Callable[[], None]:
    """A ``preexec_fn`` that starts a child part with the stop signals blocked; the child's
    :func:`install` unblocks them once its handlers are in place."""

    def block() -> None:
        signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)

    return block


@contextmanager
def blocked() -> Iterator[None]:
    """The stop signals held back in this thread for the block, so that a child started
    meanwhile starts with them blocked (a signal mask is inherited across fork and exec).
    A signal for the process may still be taken by another thread of it (and is then
    handled as usual); one for this thread waits until the block ends."""
    old = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _planned() -> dict[str, int]:
    plan: dict[str, int] = {}
    for item in os.environ.get(SIGNAL_AT_ENV, "").split(","):
        moment, _, sig = item.strip().partition(":")
        if moment:
            plan[moment] = signal.SIGINT if sig.upper() in ("INT", "SIGINT") else signal.SIGTERM
    return plan


_PLAN = _planned()


def at(moment: str) -> None:
    """Mark ``moment`` of the part's life; under :envvar:`WHEELCHAIR_HIL_SIGNAL_AT` send this
    process the signal planned for it (a test hook; nothing happens otherwise)."""
    sig = _PLAN.pop(moment, None)
    if sig is not None:
        name = signal.Signals(sig).name
        os.write(2, f"wheelchair-hil: {name} to itself at {moment} ({SIGNAL_AT_ENV})\n".encode())
        os.kill(os.getpid(), sig)
