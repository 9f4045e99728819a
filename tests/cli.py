"""``wheelchair-hil ARGS`` in the test's own process.

:func:`tools.cli.main` is the program's own path after its signal set-up; run here, a
command skips the 3-4 s a new interpreter spends importing the stack (a loaded CI machine:
twice that).  Its stdout and stderr, and what it logs, are captured as a program's would be,
and the environment it changes (``--scenario-dir``) is restored.
"""

from __future__ import annotations

import io
import logging
import os
import subprocess
from contextlib import redirect_stderr, redirect_stdout

from tools.cli import main as cli_main


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    """Run one command; its status, stdout and stderr (log records included)."""
    out, err = io.StringIO(), io.StringIO()
    env = dict(os.environ)
    root = logging.getLogger()
    handler = logging.StreamHandler(err)
    handler.setFormatter(logging.Formatter("%(name)s %(levelname)s: %(message)s"))
    level = root.level
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    try:
        with redirect_stdout(out), redirect_stderr(err):
            status = cli_main(list(args))
    finally:
        root.removeHandler(handler)
        root.setLevel(level)
        os.environ.clear()
        os.environ.update(env)
    return subprocess.CompletedProcess(list(args), status, out.getvalue(), err.getvalue())
