"""Faults of the machine are named: a full disk and a read-only one.

Each case mounts a small tmpfs in a private mount namespace (``unshare --user
--map-root-user --mount``: no root needed where user namespaces are allowed, and nothing
outside the test sees the mount) and runs ``wheelchair-hil run`` onto it.  What must hold:
one line naming the path and the OS reason, a non-zero exit, no empty file left behind, and
the log written so far readable up to where the disk ran out.
"""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "tools.cli"]


def _mount_ns_ok() -> tuple[bool, str]:
    if shutil.which("unshare") is None:
        return False, "unshare (util-linux) not installed"
    res = subprocess.run(
        ["unshare", "--user", "--map-root-user", "--mount", "sh", "-c", "mount -t tmpfs t /mnt"],
        capture_output=True,
        text=True,
        check=False,
    )
    return res.returncode == 0, res.stderr.strip()


MOUNT_OK, MOUNT_WHY = _mount_ns_ok()
pytestmark = pytest.mark.skipif(
    not MOUNT_OK, reason=f"no private mount namespace for a small tmpfs: {MOUNT_WHY}"
)


def _on_small_disk(mnt: Path, size: str, script: str, *, read_only: bool = False) -> str:
    """Run ``script`` (sh) with a ``size`` tmpfs on ``mnt``; its output, with each
    command's exit status on a line ``rc NAME=N``."""
    mount = f"mount -t tmpfs -o size={size} tmpfs {shlex.quote(str(mnt))}"
    if read_only:
        mount += f" && mount -o remount,ro {shlex.quote(str(mnt))}"
    res = subprocess.run(
        ["unshare", "--user", "--map-root-user", "--mount", "sh", "-c", f"{mount} && {script}"],
        capture_output=True,
        text=True,
        check=False,
        cwd=ROOT,
        timeout=600,
    )
    return res.stdout + res.stderr


def _cmd(name: str, *argv: str) -> str:
    return f"{shlex.join([*CLI, *argv])} 2>&1; echo rc {name}=$?"


def _rc(out: str, name: str) -> int:
    line = next(ln for ln in out.splitlines() if ln.startswith(f"rc {name}="))
    return int(line.split("=", 1)[1])


def test_a_full_disk_is_named_with_its_path_and_the_log_so_far_stays_readable(
    tmp_path: Path,
) -> None:
    mnt = tmp_path / "small"
    mnt.mkdir()
    out = mnt / "out"
    log = out / "run.mcap"
    script = " ; ".join(
        [
            _cmd(
                "run", "run", "--controller", "baseline", "--scenario", "short", "--out", str(out)
            ),
            _cmd("summarize", "summarize", str(log)),
            _cmd("partial", "summarize", str(log), "--partial", "--scenario", "short"),
            f"echo EMPTY: $(find {shlex.quote(str(out))} -type f -size 0)",
        ]
    )
    text = _on_small_disk(mnt, "2m", script)
    errors = [ln for ln in text.splitlines() if ln.startswith("wheelchair-hil: error:")]
    assert _rc(text, "run") != 0, text
    # one line, with the file and the reason, not a traceback or an empty reason: the file is
    # the one whose write failed first, the recorder's run.mcap or the controller's own log
    # (both write to the disk at once; which fills it is the machine's timing)
    written = (str(log), str(out / "controller.mcap"))
    assert any(any(f in ln for f in written) and "ENOSPC" in ln for ln in errors), text
    assert "Traceback" not in text.split("rc run=")[0], text
    # what was written is readable up to where the disk ran out, and says it is cut off
    assert _rc(text, "summarize") == 1 and "cut off" in text, text
    assert _rc(text, "partial") == 0, text
    assert "position RMSE" in text
    empty = next(ln for ln in text.splitlines() if ln.startswith("EMPTY:"))
    assert empty.strip() == "EMPTY:", f"empty files left behind: {empty}"


def test_a_read_only_output_directory_is_named_and_nothing_is_started(tmp_path: Path) -> None:
    mnt = tmp_path / "ro"
    mnt.mkdir()
    out = mnt / "out"
    text = _on_small_disk(
        mnt,
        "1m",
        _cmd("run", "run", "--controller", "baseline", "--scenario", "short", "--out", str(out)),
        read_only=True,
    )
    assert _rc(text, "run") == 1, text
    assert f"wheelchair-hil: error: {out}: EROFS (Read-only file system)" in text, text
    assert "Traceback" not in text and "simulated" not in text, text
