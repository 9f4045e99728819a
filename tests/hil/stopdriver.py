"""Run the parts of one stop-signal case and write their exit statuses (tests/hil/test_stop_signals.py).

``python -m tests.hil.stopdriver SPEC.json``, inside a private network namespace.  SPEC names
the case's directory and its parts in start order; each part is ``wheelchair-hil ARGV``:

* ``at``: the moment the part sends itself SIGTERM (``WHEELCHAIR_HIL_SIGNAL_AT``);
* ``storm``: ``"birth"`` sends it SIGTERM every 10 ms from the moment it is started (it
  starts with the stop signals blocked, as :class:`tools.run.processes.Parts` starts one), or
  ``"after:NAME"`` from the moment part NAME has exited (while it is ending) until it exits;
* ``ready``: wait for its READY before starting the next part;
* ``module``: run ``python -m MODULE ARGV`` instead (the live view);
* ``keep_stdin``: keep its standard input open until it exits (else it is closed once the
  part is started and ready).

The statuses go to ``DIR/status.json`` (``null``: the part did not end in time, then killed).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from dbc.runtime import stopping

#: A guard against a hang, not a criterion: a loaded machine may take minutes.
TIMEOUT_S = 600.0
#: Dense enough to land in every phase of a part's end (its finalization alone takes
#: tens of milliseconds), sparse enough not to slow the part down much.
STORM_PERIOD_S = 0.01


def _storm(proc: subprocess.Popen[bytes], sent: list[int], after: threading.Event | None) -> None:
    if after is not None:
        after.wait()
    while proc.poll() is None:
        try:
            os.kill(proc.pid, signal.SIGTERM)
            sent[0] += 1
        except ProcessLookupError:
            return
        time.sleep(STORM_PERIOD_S)


def run(spec: dict[str, Any]) -> dict[str, Any]:
    d = Path(spec["dir"])
    procs: dict[str, subprocess.Popen[bytes]] = {}
    ended = {p["name"]: threading.Event() for p in spec["parts"]}
    storms: list[threading.Thread] = []
    sent: dict[str, list[int]] = {}
    deadline = time.monotonic() + TIMEOUT_S
    for part in spec["parts"]:
        name = part["name"]
        env = dict(os.environ)
        env.pop(stopping.SIGNAL_AT_ENV, None)
        if part.get("at"):
            env[stopping.SIGNAL_AT_ENV] = part["at"]
        module = part.get("module", "tools.cli")
        argv = [sys.executable, "-m", module, *part["argv"]]
        if module == "tools.cli" and part.get("ready", True):
            argv.append("--ready")
        with (
            open(d / f"{name}.out", "wb") as out,
            open(d / f"{name}.err", "wb") as err,
            stopping.blocked(),
        ):
            procs[name] = proc = subprocess.Popen(
                argv, stdin=subprocess.PIPE, stdout=out, stderr=err, env=env
            )
        storm = part.get("storm")
        if storm:
            sent[name] = [0]
            after = ended[storm.split(":", 1)[1]] if storm.startswith("after:") else None
            t = threading.Thread(target=_storm, args=(proc, sent[name], after), daemon=True)
            t.start()
            storms.append(t)
        while part.get("ready", True) and proc.poll() is None and time.monotonic() < deadline:
            if b"READY" in (d / f"{name}.out").read_bytes():
                break
            time.sleep(0.01)
        assert proc.stdin is not None
        if not part.get("keep_stdin"):
            proc.stdin.close()  # the live view ends when its standard input closes
    codes: dict[str, int | None] = {}
    pending = dict(procs)
    while pending and time.monotonic() < deadline:
        for name, proc in list(pending.items()):
            if proc.poll() is not None:
                codes[name] = proc.returncode
                ended[name].set()
                del pending[name]
        time.sleep(0.005)
    for name, proc in pending.items():
        proc.kill()
        proc.wait()
        codes[name] = None
    for ev in ended.values():
        ev.set()
    for t in storms:
        t.join(5)
    return {"codes": codes, "storm_signals": {n: s[0] for n, s in sent.items()}}


if __name__ == "__main__":
    spec_path = Path(sys.argv[1])
    result = run(json.loads(spec_path.read_text()))
    (Path(json.loads(spec_path.read_text())["dir"]) / "status.json").write_text(json.dumps(result))
