"""The parts of a run as OS processes: each started in turn, its READY awaited, all watched to
the end and stopped together.

One runner serves every cross-process run:

* ``run`` over udp_multicast or socketcan (:func:`tools.run.cross_process.run_processes`), already
  inside its private namespace, starts record, control and sim with :class:`Parts`;
* the safety suite's real-time signal runs (:func:`tools.safety.realtime.realtime_signal_run`)
  and the attacks (:mod:`tools.safety.attacks.runs`) start theirs from outside a namespace with
  :class:`SandboxedParts`: this module runs in a new private namespace
  (``python -m tools.run.processes SPEC.json``, :func:`tools.bus.transport.sandbox_argv`)
  around the same :class:`Parts`, and tells the caller each part's PID and when all are up.

A part that says ``READY`` on its stdout (``--ready``) is waited for before the next one
starts; its stderr goes into its log file, and its last lines are kept in memory so that its
own error can be quoted even when the log could not be written.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Collection, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from types import FrameType
from typing import IO, Any

from dbc.runtime import stopping
from dbc.runtime.errors import WheelchairError
from tools.bus import transport

READY = "READY"
#: How a part's own one-line error starts (tools.cli): left out when it is quoted.
ERROR_PREFIX = "wheelchair-hil: error: "


class PartFailedError(WheelchairError):
    """A part of a run (sim, control, record ...) did not start or exited with an error."""


@dataclass(frozen=True)
class Part:
    """One process of a run."""

    name: str
    argv: tuple[str, ...]
    #: its stderr
    log: str
    #: wait for its ``READY`` line before the next part starts
    ready: bool = True
    #: its stdout, if it is kept (else only its last lines, in memory)
    out: str | None = None


def cli_part(workdir: Path, command: str, *argv: str, ready: bool = True) -> Part:
    """``wheelchair-hil COMMAND ARGV`` as part ``command`` (with ``--ready`` if it is waited
    for), its stderr and stdout in ``workdir/COMMAND.err`` and ``.out``."""
    return Part(
        command,
        tuple(transport.python_argv(command, *argv, *(("--ready",) if ready else ()))),
        str(workdir / f"{command}.err"),
        ready=ready,
        out=str(workdir / f"{command}.out"),
    )


#: Each part's SCHED_FIFO priority relative to the controller's in a real-time run: the bench,
#: which stands in for the drives' own hardware, one above it, the recorder and an attacking
#: node one below it (above everything that is not real-time, never ahead of bench or host).
RT_OFFSETS = {"sim": 1, "control": 0, "record": -1, "attacker": -1}


def part_rt_priority(part: str, rt_priority: int) -> int:
    """``part``'s SCHED_FIFO priority where the controller runs at ``rt_priority`` (0: none),
    kept inside Linux's 1-99."""
    if rt_priority <= 0:
        return 0
    return min(max(rt_priority + RT_OFFSETS[part], 1), 99)


def rt_option(part: str, rt_priority: int) -> tuple[str, ...]:
    """``--rt-priority N`` for ``part`` (:func:`part_rt_priority`), or nothing for 0."""
    prio = part_rt_priority(part, rt_priority)
    return ("--rt-priority", str(prio)) if prio else ()


def realtime_parts(
    workdir: Path,
    scenario: str,
    duration_s: float,
    *,
    control: Sequence[str] = (),
    rt_priority: int = 0,
    others: Sequence[Part] = (),
    bus: Sequence[str] = ("--bus", "udp_multicast"),
) -> list[Part]:
    """Recorder, ``others`` (e.g. an attacker), controller and bench of a real-time run over
    ``bus`` (the parts' bus options: udp_multicast, or socketcan with its ``--channel``), in
    the order they start; the log is ``workdir/run.mcap``, the controller's and the bench's
    statistics go into ``workdir/ctl`` and ``workdir/sim``.

    ``control``: the controller's own options (``--config``, ``--controller`` ...).  Its clock
    starts before the bench's, so it gets 15 s more (in real time it ends by itself 1 s after
    reaching FAULT or DONE).  ``rt_priority`` > 0: the controller runs on SCHED_FIFO at that
    priority, the bench, which stands in for the drives' own hardware, one above it, and the
    recorder one below it (a starved recorder loses frames: the attacks are judged from its log).
    """
    bus = (*bus, "--realtime")
    common = (*bus, "--scenario", scenario)
    ctl_rt = rt_option("control", rt_priority)
    sim_rt = rt_option("sim", rt_priority)
    rec_rt = rt_option("record", rt_priority)
    return [
        cli_part(workdir, "record", *bus, *rec_rt, "--out", str(workdir / "run.mcap")),
        *others,
        cli_part(
            workdir,
            "control",
            *common,
            *("--duration", f"{duration_s + 15}", *control, *ctl_rt),
            *("--out", str(workdir / "ctl")),
        ),
        cli_part(
            workdir,
            "sim",
            *common,
            *("--duration", f"{duration_s}", *sim_rt, "--out", str(workdir / "sim")),
        ),
    ]


class _Tee:
    """A part's output stream: into its file (if any), its last lines kept in memory, and
    its ``READY`` line noticed.

    When the file cannot be written (the disk is full, or it is the disk that failed), the
    lines still reach the memory tail, so that the part's own error (``ENOSPC`` and its
    path) can be reported; the write error is kept too.
    """

    TAIL = 200

    def __init__(self, stream: IO[str], path: Path | None) -> None:
        self.lines: collections.deque[str] = collections.deque(maxlen=self.TAIL)
        self.write_error: OSError | None = None
        self.ready = threading.Event()
        self._path = path
        name = path.name if path is not None else "stdout"
        self._thread = threading.Thread(
            target=self._pump, args=(stream,), name=f"tee {name}", daemon=True
        )
        self._thread.start()

    def _pump(self, stream: IO[str]) -> None:
        fh = None
        if self._path is not None:
            try:
                fh = self._path.open("w")
            except OSError as err:
                self.write_error = err
        for line in stream:
            if line.strip() == READY:
                self.ready.set()
            self.lines.append(line.rstrip("\n"))
            if fh is not None and self.write_error is None:
                try:
                    fh.write(line)
                    fh.flush()
                except OSError as err:
                    self.write_error = err
        if fh is not None:
            with contextlib.suppress(OSError):
                fh.close()
        if self.write_error is not None and self._path is not None:
            with contextlib.suppress(OSError):
                if self._path.exists() and self._path.stat().st_size == 0:
                    self._path.unlink()  # no empty log left behind

    def join(self, timeout: float = 5.0) -> None:
        self._thread.join(timeout)

    def last_error(self) -> str:
        """The part's own one-line error if it gave one, else its last line naming an error."""
        lines = [ln.strip() for ln in self.lines if ln.strip()]
        for ln in reversed(lines):
            if ln.startswith(ERROR_PREFIX):
                return ln.removeprefix(ERROR_PREFIX)
        for ln in reversed(lines):
            if "error" in ln.lower():
                return ln
        return lines[-1] if lines else ""


class Parts:
    """Processes started in turn and stopped together (``with Parts() as parts: ...``).

    ``pid_dir``: each part's PID is written to ``pid_dir/NAME.pid`` as it starts.
    ``ready_timeout_s``: how long a part may take to say ``READY`` (generous: a loaded machine
    can take tens of seconds to import the stack; a part that ends first fails at once).
    """

    def __init__(self, *, pid_dir: Path | None = None, ready_timeout_s: float = 120.0) -> None:
        self.procs: dict[str, subprocess.Popen[str]] = {}
        self._err: dict[str, _Tee] = {}
        self._out: dict[str, _Tee] = {}
        self._pid_dir = pid_dir
        self._ready_timeout_s = ready_timeout_s

    def start(self, part: Part) -> subprocess.Popen[str]:
        """Start ``part``; with ``part.ready``, return once it said ``READY``
        (:class:`PartFailedError` with its own error if it ended or timed out first)."""
        # a part of ours starts with the stop signals blocked and unblocks them once its
        # handlers are in place (dbc.runtime.stopping): no SIGTERM of stop() can kill it
        held = stopping.blocked() if _is_cli(part.argv) else contextlib.nullcontext()
        with held:
            proc = subprocess.Popen(
                list(part.argv),
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                bufsize=1,
            )
        assert proc.stdout is not None and proc.stderr is not None
        self.procs[part.name] = proc
        self._err[part.name] = _Tee(proc.stderr, Path(part.log))
        self._out[part.name] = _Tee(proc.stdout, Path(part.out) if part.out else None)
        if self._pid_dir is not None:
            _write_atomic(self._pid_dir / f"{part.name}.pid", f"{proc.pid}\n")
        if part.ready:
            self._wait_ready(part.name)
        return proc

    def _wait_ready(self, name: str) -> None:
        proc, ready = self.procs[name], self._out[name].ready
        deadline = time.monotonic() + self._ready_timeout_s
        while not ready.wait(0.05):
            if proc.poll() is not None or time.monotonic() > deadline:
                why = self.last_error(name) or f"no READY within {self._ready_timeout_s:.0f} s"
                raise PartFailedError(f"{name} did not start: {why}")

    def codes(self) -> dict[str, int | None]:
        """Each part's exit code (None while it runs)."""
        return {n: p.poll() for n, p in self.procs.items()}

    def wait(
        self,
        timeout_s: float,
        *,
        ok: Collection[int] | None = (0,),
        what: str = "run",
        stop_event: threading.Event | None = None,
    ) -> dict[str, int]:
        """Until every part has ended; their exit codes.

        A part that ends with a code not in ``ok`` (``None``: any code is fine) fails the
        run at once (:class:`PartFailedError` with its own error), as does ``timeout_s``.
        Once ``stop_event`` is set, every part still running is sent SIGTERM (once) and
        waited for: each ends with its own status.
        """
        deadline = time.monotonic() + timeout_s
        stopped = False
        while True:
            if stop_event is not None and stop_event.is_set() and not stopped:
                stopped = True
                for p in self.procs.values():
                    if p.poll() is None:
                        p.send_signal(signal.SIGTERM)
            codes = self.codes()
            if ok is not None:
                failed = [n for n, c in codes.items() if c is not None and c not in ok]
                if failed:
                    n = failed[0]
                    raise PartFailedError(f"{n} failed (exit {codes[n]}): {self.last_error(n)}")
            if all(c is not None for c in codes.values()):
                return {n: c for n, c in codes.items() if c is not None}
            if time.monotonic() > deadline:
                raise PartFailedError(f"{what} did not finish within {timeout_s:.0f} s")
            time.sleep(0.05)

    def last_error(self, name: str) -> str:
        """The part's last error line (from memory: its log file may be what failed)."""
        tee, proc = self._err.get(name), self.procs.get(name)
        if tee is None or proc is None:
            return ""
        if proc.poll() is not None:
            tee.join()  # the part ended: read its stderr to the end
        why = tee.last_error()
        if tee.write_error is not None:
            why += f" (and its log could not be written: {tee.write_error})"
        return why

    def stop(self) -> None:
        """SIGTERM to every part still running, SIGKILL 5 s later; idempotent."""
        for p in self.procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + 5.0
        for p in self.procs.values():
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for tee in (*self._err.values(), *self._out.values()):
            tee.join()

    def __enter__(self) -> Parts:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _is_cli(argv: Sequence[str]) -> bool:
    """Whether ``argv`` runs this project's command line (``python -m tools.cli ...``)."""
    return any(a == "-m" and b == "tools.cli" for a, b in itertools.pairwise(argv))


def signal_part(pid: int, sig: int, *words: bytes) -> bool:
    """Send ``sig`` to our part ``pid``; False if it has already exited.

    Its command line must hold every one of ``words`` (e.g. ``b"tools.cli", b"control"``),
    so that a recycled PID is never signalled.
    """
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return False
    if any(w not in cmdline for w in words):
        return False
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        return False
    return True


def _write_atomic(path: Path, text: str) -> None:
    """``text`` into ``path`` as a whole: a reader never sees it half written."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


# ------------------------------------------------------------ from outside a namespace

_SPEC = "parts.json"
_STARTED = "parts.started"
_EXITS = "parts.exits.json"
#: The runner in the namespace gives up this long after its caller would have (the caller
#: ends it first; this only matters if the caller died).
_GRACE_S = 30.0


class SandboxedParts:
    """:class:`Parts` in a new private network namespace, from a process outside it.

    ``with SandboxedParts(parts, workdir, timeout_s=...) as run``: :meth:`wait_started` until
    every part is up, :meth:`pid` of a part (the PIDs are this machine's: only the network is
    private), :meth:`wait` for their end.  A part may take up to ``timeout_s`` to say
    ``READY`` (a starved machine is then a timeout, :class:`subprocess.TimeoutExpired`,
    not a failure); a part that ends before it does fails the run
    (:class:`PartFailedError`).  Leaving the block ends whatever still runs.
    """

    def __init__(self, parts: Sequence[Part], workdir: Path, *, timeout_s: float) -> None:
        self.parts = tuple(parts)
        self.workdir = workdir.resolve()
        self.timeout_s = timeout_s
        self._proc: subprocess.Popen[str] | None = None
        self._deadline = 0.0

    def __enter__(self) -> SandboxedParts:
        self.workdir.mkdir(parents=True, exist_ok=True)
        for name in (_STARTED, _EXITS, *(f"{p.name}.pid" for p in self.parts)):
            (self.workdir / name).unlink(missing_ok=True)
        spec = {
            "workdir": str(self.workdir),
            "timeout_s": self.timeout_s + _GRACE_S,
            "ready_timeout_s": self.timeout_s + _GRACE_S,
            "parts": [asdict(p) for p in self.parts],
        }
        (self.workdir / _SPEC).write_text(json.dumps(spec, indent=2) + "\n")
        self._deadline = time.monotonic() + self.timeout_s
        self._proc = subprocess.Popen(
            transport.sandbox_argv(
                [sys.executable, "-m", "tools.run.processes", str(self.workdir / _SPEC)]
            ),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        return self

    @property
    def remaining_s(self) -> float:
        return self._deadline - time.monotonic()

    def wait_started(self) -> bool:
        """Until every part is up (True), the runner ended or the time is up (False)."""
        proc = self._require()
        while self.remaining_s > 0 and proc.poll() is None:
            if (self.workdir / _STARTED).exists():
                return True
            time.sleep(0.01)
        return (self.workdir / _STARTED).exists()

    def pid(self, name: str) -> int | None:
        """The PID of part ``name``, once it has started."""
        try:
            return int((self.workdir / f"{name}.pid").read_text())
        except (OSError, ValueError):
            return None

    def wait(self) -> dict[str, int]:
        """Until every part has ended (within the time left; else
        :class:`subprocess.TimeoutExpired`); their exit codes."""
        proc = self._require()
        _, err = proc.communicate(timeout=max(1.0, self.remaining_s))
        if proc.returncode != 0:
            raise PartFailedError(f"the parts' runner failed ({proc.returncode}): {err[-2000:]}")
        codes: dict[str, int] = json.loads((self.workdir / _EXITS).read_text())
        return codes

    def _require(self) -> subprocess.Popen[str]:
        if self._proc is None:
            raise RuntimeError("SandboxedParts: use it in a with block")
        return self._proc

    def __exit__(self, *exc: object) -> None:
        proc = self._proc
        if proc is None or proc.poll() is not None:
            return
        proc.terminate()  # the runner stops its parts
        try:
            proc.communicate(timeout=10.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


def _runner(spec_path: Path) -> int:
    """Inside the namespace: start the parts of ``spec_path``, wait for them, write their
    exit codes.  Exit 1 with the error if a part did not start or the time ran out."""
    spec: dict[str, Any] = json.loads(spec_path.read_text())
    workdir = Path(spec["workdir"])

    def terminated(signum: int, frame: FrameType | None) -> None:
        raise SystemExit(128 + signum)  # leaves the with block: the parts are stopped

    signal.signal(signal.SIGTERM, terminated)
    try:
        with Parts(pid_dir=workdir, ready_timeout_s=spec["ready_timeout_s"]) as parts:
            for p in spec["parts"]:
                parts.start(Part(**{**p, "argv": tuple(p["argv"])}))
            _write_atomic(workdir / _STARTED, "")
            codes = parts.wait(spec["timeout_s"], ok=None)
    except PartFailedError as err:
        print(f"{ERROR_PREFIX}{err}", file=sys.stderr)
        return 1
    _write_atomic(workdir / _EXITS, json.dumps(codes) + "\n")
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python -m tools.run.processes SPEC.json")
    raise SystemExit(_runner(Path(sys.argv[1])))
