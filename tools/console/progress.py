"""Progress of a long command (``safety-report``, ``replay --bus``) on stderr.

The convention, for every command that shows progress:

* progress goes to stderr only; stdout carries the command's output, so that
  ``safety-report > table.txt`` or a pipe gets the table alone;
* on a terminal it is one line redrawn in place (a tqdm bar);
* when stderr is not a terminal (a CI log, a file) it is plain lines, one per step
  (a safety case) or one per tenth of the work (frames of a replay), so that a log
  shows how far the command got without carriage-return noise;
* ``--no-progress`` silences it.
"""

from __future__ import annotations

import sys
from types import TracebackType
from typing import IO

from tqdm import tqdm

#: Steps between plain lines when the total is not known.
UNKNOWN_TOTAL_EVERY = 10_000


class Progress:
    """``with Progress(total, "replay", "frame") as p: p.update()`` per unit of work.

    ``lines="each"`` prints a plain line per :meth:`update` off a terminal,
    ``"tenths"`` one per tenth of ``total``.
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
    ) -> None:
        if lines not in ("each", "tenths"):
            raise ValueError(f"lines={lines!r}: choose 'each' or 'tenths'")
        self.total, self.desc, self.unit, self.lines = total, desc, unit, lines
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.done = 0
        self._next_line = self._step()
        isatty = getattr(self.stream, "isatty", None)
        self.tty = bool(enabled and isatty is not None and isatty())
        self._bar: tqdm[None] | None = None
        if self.tty:
            self._bar = tqdm(total=total, desc=desc, unit=unit, file=self.stream, leave=True)

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
        of = f"/{self.total}" if self.total else ""
        pct = f" ({100 * self.done // self.total} %)" if self.total else ""
        tail = f" {note}" if note else ""
        print(f"{self.desc}: {self.done}{of} {self.unit}s{pct}{tail}", file=self.stream, flush=True)

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
