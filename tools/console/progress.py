"""Progress of a long command (``evaluate``, ``safety-report``, ``replay --bus``) on stderr.

The convention, for every command that shows progress:

* progress goes to stderr only; stdout carries the command's output, so that
  ``safety-report > table.txt`` or a pipe gets the table alone;
* on a terminal it is one line redrawn in place (a tqdm bar, where tqdm is installed: the
  ``bench`` and ``eval`` extras; else the plain lines below);
* when stderr is not a terminal (a CI log, a file) it is plain lines, one per step
  (a safety case) or one per tenth of the work (the runs of a campaign, the frames of a
  replay), each with the count, the time so far and the estimated time left, so that a
  log shows how far the command got without carriage-return noise;
* messages in between (a failed run) go through :meth:`Progress.write`, above the bar;
* ``--no-progress`` silences it.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from types import TracebackType
from typing import IO, Any

#: Steps between plain lines when the total is not known.
UNKNOWN_TOTAL_EVERY = 10_000


def _tqdm() -> Any:
    """tqdm's bar class, or None where tqdm is not installed (a chair's install: the plain
    lines then, a progress bar is no reason to refuse a command)."""
    try:
        from tqdm import tqdm  # lazy: optional (the bench and eval extras)
    except ImportError:
        return None
    return tqdm


def duration(s: float) -> str:
    """``42 s``, ``3 min 05 s``, ``1 h 02 min``."""
    n = max(0, round(s))
    if n < 60:
        return f"{n} s"
    if n < 3600:
        return f"{n // 60} min {n % 60:02d} s"
    return f"{n // 3600} h {n % 3600 // 60:02d} min"


class Progress:
    """``with Progress(total, "replay", "frame") as p: p.update()`` per unit of work.

    ``lines="each"`` prints a plain line per :meth:`update` off a terminal,
    ``"tenths"`` one per tenth of ``total``.  ``clock``: seconds, for the elapsed time and
    the estimate (the monotonic clock).
    """

    def __init__(
        self,
        total: int | None,
        desc: str,
        unit: str,
        *,
        enabled: bool = True,
        lines: str = "tenths",
        stream: IO[str] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if lines not in ("each", "tenths"):
            raise ValueError(f"lines={lines!r}: choose 'each' or 'tenths'")
        self.total, self.desc, self.unit, self.lines = total, desc, unit, lines
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.done = 0
        self._clock = clock
        self._t0 = clock()
        self._next_line = self._step()
        isatty = getattr(self.stream, "isatty", None)
        self.tty = bool(enabled and isatty is not None and isatty())
        self._bar: Any = None
        if self.tty:
            bar = _tqdm()
            if bar is not None:
                self._bar = bar(total=total, desc=desc, unit=unit, file=self.stream, leave=True)

    def _step(self) -> int:
        if self.lines == "each":
            return self.done + 1
        if not self.total:
            return self.done + UNKNOWN_TOTAL_EVERY
        tenth = (10 * self.done) // self.total + 1
        return -(-tenth * self.total // 10)  # ceil: the first count at or past that tenth

    def update(self, n: int = 1, note: str = "") -> None:
        """``n`` more units done; ``note`` (e.g. the case just finished) goes with the line."""
        if not self.enabled:
            return
        self.done += n
        if self._bar is not None:
            if note:
                self._bar.set_postfix_str(note, refresh=False)
            self._bar.update(n)
            return
        if self.done < self._next_line:
            return
        self._next_line = self._step()
        print(self.line(note), file=self.stream, flush=True)

    def line(self, note: str = "") -> str:
        """The plain line for where the work is now, e.g. ``evaluate: 3/12 runs (25 %),
        1 min 05 s elapsed, about 3 min 15 s left``."""
        elapsed = self._clock() - self._t0
        text = f"{self.desc}: {self.done}"
        if self.total:
            text += f"/{self.total} {self.unit}s ({100 * self.done // self.total} %)"
        else:
            text += f" {self.unit}s"
        text += f", {duration(elapsed)} elapsed"
        if self.total and 0 < self.done < self.total:
            text += f", about {duration(elapsed / self.done * (self.total - self.done))} left"
        return f"{text}; {note}" if note else text

    def write(self, message: str) -> None:
        """A line of its own (a failed run): above the bar on a terminal, else plain."""
        if self._bar is not None:
            self._bar.write(message, file=self.stream)
        else:
            print(message, file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
