"""A real Linux CAN stack where the host kernel has none: a user-mode Linux guest with vcan0.

``wheelchair-hil sandbox --socketcan -- CMD`` runs CMD where the SocketCAN interface
``vcan0`` is up.  Where the host kernel has CAN (``AF_CAN``) and ``vcan0`` exists or can
be created, CMD runs on the host.  Otherwise this module boots Debian's
``user-mode-linux`` kernel (``linux.uml``) as an ordinary process with the host's root
file system mounted through hostfs, so the host's Python, venv and checkout work
unchanged inside:

* the guest's PID 1 is a shell script written by :func:`init_script`: it mounts
  ``/proc``, ``/sys`` and a tmpfs on ``/dev/shm``, loads ``can``, ``can-raw``,
  ``can-dev`` and ``vcan`` from ``/usr/lib/uml/modules/<release>/kernel/`` (in that
  order: vcan needs can-dev) with ``insmod``, creates ``vcan0``, runs CMD in the
  caller's working directory and environment, writes CMD's exit status to a file
  (the guest's own exit status does not carry it) and powers off;
* CMD's standard output and error reach the caller's on consoles of their own
  (``con1``, ``con2``); the kernel's boot messages go to ``con0``, which this module
  reads and shows only when the guest fails;
* the guest has one CPU and every file access goes through hostfs: it is a
  correctness lane, nothing measured inside it is a performance figure.
"""

from __future__ import annotations

import contextlib
import os
import shlex
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import threading
from collections.abc import Sequence
from pathlib import Path

from dbc.runtime.errors import BusError
from tools.bus import transport

#: Set in the environment of a command that runs inside the guest.
GUEST_ENV = "WHEELCHAIR_HIL_UML_GUEST"
#: The guest's memory (the host's root file system needs none of it).
GUEST_MEM = "2G"
#: Kernel modules that make vcan0, in load order (vcan needs can-dev).
CAN_MODULES = (
    "net/can/can.ko",
    "net/can/can-raw.ko",
    "drivers/net/can/dev/can-dev.ko",
    "drivers/net/can/vcan.ko",
)
MODULES_ROOT = Path("/usr/lib/uml/modules")
#: Where ``tools/bus/uml-kernel.sh`` puts a kernel that boots on this host, when the
#: installed one does not (Debian bookworm's UML 6.1 panics on a CPU with AMX).
ROOT_ENV = "WHEELCHAIR_HIL_UML_ROOT"
DEFAULT_ROOT = Path.home() / ".cache" / "wheelchair-hil" / "uml"
INSTALL_HINT = (
    "install user-mode-linux and kmod (Debian/Ubuntu: apt-get install user-mode-linux kmod "
    "can-utils; on a CPU with AMX also tools/bus/uml-kernel.sh), or run on a kernel with "
    "SocketCAN and vcan"
)
#: Environment variables not handed into the guest (they describe the host's session).
_NOT_INHERITED = frozenset({"TERM", "TERMCAP", "COLUMNS", "LINES", "SHLVL", "_", "OLDPWD"})


def host_can_ready(channel: str = "vcan0") -> tuple[bool, str]:
    """Whether the host kernel has SocketCAN and ``channel`` is up (or why not)."""

    ok, why = transport.socketcan_available()
    if not ok:
        return False, why
    state = Path(f"/sys/class/net/{channel}/operstate")
    if not state.exists():
        return False, f"the kernel has SocketCAN but no {channel}"
    flags = Path(f"/sys/class/net/{channel}/flags")
    try:
        up = int(flags.read_text(), 16) & 0x1
    except (OSError, ValueError):
        up = 0
    if not up:
        return False, f"{channel} exists but is down (ip link set up {channel})"
    return True, ""


def _try_host_vcan(channel: str = "vcan0") -> bool:
    """Create and bring up ``channel`` on the host if the user may (root, vcan module)."""
    if shutil.which("ip") is None:
        return False
    steps = []
    if not Path(f"/sys/class/net/{channel}").exists():
        if shutil.which("modprobe"):
            steps.append(["modprobe", "vcan"])
        steps.append(["ip", "link", "add", "dev", channel, "type", "vcan"])
    steps.append(["ip", "link", "set", "up", channel])
    for argv in steps:
        subprocess.run(argv, capture_output=True, check=False, timeout=10)
    return host_can_ready(channel)[0]


def uml_root() -> Path | None:
    """The prefix ``tools/bus/uml-kernel.sh`` installed a kernel into
    (``$WHEELCHAIR_HIL_UML_ROOT``, else ``~/.cache/wheelchair-hil/uml``), if it holds one."""
    root = Path(os.environ.get(ROOT_ENV) or DEFAULT_ROOT).expanduser()
    return root if os.access(root / "usr" / "bin" / "linux.uml", os.X_OK) else None


def uml_kernel() -> str | None:
    """Path of the user-mode Linux kernel (:func:`uml_root`'s first), or None."""
    root = uml_root()
    if root is not None:
        return str(root / "usr" / "bin" / "linux.uml")
    for name in ("linux.uml", "linux"):
        path = shutil.which(name)
        if path is not None and (name == "linux.uml" or _is_uml(path)):
            return path
    return None


def _is_uml(path: str) -> bool:
    return Path(path).resolve().name.startswith("linux.uml")


def module_dir() -> Path | None:
    """``<root>/usr/lib/uml/modules/<release>/kernel`` of :func:`uml_kernel`, or None."""
    root = uml_root()
    modules = root / "usr" / "lib" / "uml" / "modules" if root is not None else MODULES_ROOT
    if not modules.is_dir():
        return None
    releases = sorted(p for p in modules.iterdir() if (p / "kernel").is_dir())
    return releases[-1] / "kernel" if releases else None


def guest_supported() -> tuple[bool, str]:
    """Whether a UML guest with vcan0 can be booted here, and if not what to install."""
    missing = []
    if uml_kernel() is None:
        missing.append("linux.uml (package user-mode-linux)")
    mods = module_dir()
    if mods is None:
        missing.append(f"{MODULES_ROOT}/<release>/kernel (package user-mode-linux)")
    else:
        missing += [f"{mods / m}" for m in CAN_MODULES if not (mods / m).exists()]
    for tool, pkg in (("insmod", "kmod"), ("ip", "iproute2")):
        if shutil.which(tool) is None:
            missing.append(f"{tool} (package {pkg})")
    if missing:
        return False, f"missing {', '.join(missing)}"
    return True, ""


#: The SCHED_FIFO priority of the guest kernel's softirq thread, above every part's (the
#: controller's 10, the bench's one above, the recorder's one below), as a PREEMPT_RT kernel
#: runs its interrupt threads (50).  Under load the kernel hands the delivery of frames to
#: the sockets (NET_RX) to ksoftirqd, which at SCHED_OTHER the SCHED_FIFO parts can starve:
#: the likely cause of a run whose drives got no setpoint for a second while the receive
#: times the kernel stamped showed them at 100 Hz (six runs since: at most 240 ms).  A
#: chair's computer needs the same (docs/deploy.md § 2).
SOFTIRQ_RT_PRIORITY = 50


def init_script(cmd: Sequence[str], status_path: Path, *, cwd: str, env: dict[str, str]) -> str:
    """The guest's PID 1: CAN modules, vcan0 up, ksoftirqd on SCHED_FIFO
    (:data:`SOFTIRQ_RT_PRIORITY`), CMD, its exit status to ``status_path``."""
    mods = module_dir()
    if mods is None:
        raise BusError(f"cannot boot a CAN guest: no UML kernel modules; {INSTALL_HINT}")
    exports = "\n".join(
        f"export {k}={shlex.quote(v)}"
        for k, v in sorted(env.items())
        if k.isidentifier() and k not in _NOT_INHERITED
    )
    insmods = "\n".join(
        f"insmod {shlex.quote(str(mods / m))} || fail 'insmod {m}'" for m in CAN_MODULES
    )
    status = shlex.quote(str(status_path))
    softirq = (
        "for d in /proc/[0-9]*; do case $(cat $d/comm 2>/dev/null) in ksoftirqd/*) "
        f"chrt -f -p {SOFTIRQ_RT_PRIORITY} ${{d#/proc/}} >/dev/null || "
        "fail 'chrt ksoftirqd';; esac; done"
    )
    return f"""#!/bin/sh
# PID 1 of a user-mode Linux guest started by wheelchair-hil sandbox --socketcan
fail() {{ echo "wheelchair-hil guest: $1" >&2; echo 125 > {status}; poweroff -f; }}
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t tmpfs -o size=256m tmpfs /dev/shm 2>/dev/null || true
for t in /dev/tty1 /dev/tty2; do stty -F $t raw -echo 2>/dev/null; done
{insmods}
ip link set lo up
ip link add dev vcan0 type vcan || fail 'ip link add vcan0'
ip link set up vcan0 || fail 'ip link set up vcan0'
{softirq}
{exports}
export {GUEST_ENV}=1
cd {shlex.quote(cwd)} || fail 'cd {cwd}'
{shlex.join(cmd)} <"$WHEELCHAIR_HIL_STDIN" >/dev/tty1 2>/dev/tty2
echo $? > {status}
sync
poweroff -f
"""


def run_in_guest(cmd: Sequence[str], *, quiet: bool = False) -> int:
    """Boot a UML guest with vcan0 up, run ``cmd`` there, return its exit status.

    ``cmd``'s standard output and error are the caller's; the guest's boot log is
    printed to standard error only if the guest fails before ``cmd`` ends.  The guest
    is ended when ``cmd`` ends, or when this process gets SIGINT or SIGTERM.
    """
    ok, why = guest_supported()
    if not ok:
        raise BusError(f"cannot give a SocketCAN vcan0 here: {why}; {INSTALL_HINT}")
    kernel = uml_kernel()
    assert kernel is not None
    with tempfile.TemporaryDirectory(prefix="wheelchair-hil-uml-") as tmp:
        tmpdir = Path(tmp)
        status = tmpdir / "status"
        init = tmpdir / "init"
        env = dict(os.environ)
        stdin_is_stream = _interactive(0)
        env["WHEELCHAIR_HIL_STDIN"] = "/dev/tty0" if stdin_is_stream else "/dev/null"
        init.write_text(init_script(cmd, status, cwd=os.getcwd(), env=env))
        init.chmod(0o755)
        boot_r, boot_w = os.pipe()  # the kernel's own console and output: the boot log
        out_fd, err_fd = os.dup(1), os.dup(2)  # CMD's stdout and stderr: the caller's
        con0 = f"fd:0,fd:{boot_w}" if stdin_is_stream else f"null,fd:{boot_w}"
        argv = [
            kernel,
            f"mem={GUEST_MEM}",
            "rootfstype=hostfs",
            "rootflags=/",
            "rw",
            "quiet",
            f"init={init}",
            "con=null",
            f"con0={con0}",
            f"con1=null,fd:{out_fd}",
            f"con2=null,fd:{err_fd}",
        ]
        # the guest's memory file goes to TMPDIR
        child_env = {**os.environ, "TMPDIR": str(tmpdir)}
        try:
            proc = subprocess.Popen(
                argv,
                stdin=None if stdin_is_stream else subprocess.DEVNULL,
                stdout=boot_w,
                stderr=boot_w,
                pass_fds=(boot_w, out_fd, err_fd),
                start_new_session=True,
                env=child_env,
                preexec_fn=_raise_priority,
            )
        finally:
            for fd in (boot_w, out_fd, err_fd):
                os.close(fd)
        boot_log: list[bytes] = []
        reader = threading.Thread(target=_drain, args=(boot_r, boot_log), daemon=True)
        reader.start()
        if not quiet:
            print("sandbox: socketcan vcan0 in a user-mode Linux guest", file=sys.stderr)
        interrupted = _wait_guest(proc)
        reader.join(5.0)
        try:
            code = int(status.read_text().strip())
        except (OSError, ValueError):
            code = None
        if code is None:
            if interrupted:
                return 130
            console = b"".join(boot_log).decode(errors="replace")
            tail = console.strip().splitlines()[-15:]
            if "ptrace set fp regs failed" in console:
                tail.append(
                    f"this kernel ({kernel}) cannot run its init on this CPU (AMX's large "
                    "xstate); tools/bus/uml-kernel.sh installs one that can"
                )
            sys.stderr.write(
                "sandbox: the user-mode Linux guest ended without the command's exit status "
                f"(kernel exit {proc.returncode}); its last console lines:\n  "
                + "\n  ".join(tail)
                + "\n"
            )
            return 125
        return code


#: The guest's scheduling where the caller may raise it (root): its one CPU runs the bench,
#: the controller and the recorder in real time, so host load must not starve it.  It asks
#: for SCHED_FIFO at :data:`GUEST_RT_PRIORITY` (a quiet socketcan lane, host reference runs
#: included, used 185 s of CPU in 235 s), else a niceness of :data:`GUEST_NICE` (which a
#: loaded 2-core host still starved: a real-time run in the guest lost 21 bench steps beside
#: two lock-step pytest workers).
GUEST_RT_PRIORITY = 10
GUEST_NICE = -10


def _raise_priority() -> None:
    """In the guest's process before exec: SCHED_FIFO, else nice, where permitted."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(GUEST_RT_PRIORITY))
    except OSError:
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, 0, GUEST_NICE)


def _interactive(fd: int) -> bool:
    """Whether CMD gets the caller's terminal as its input (through the guest's tty0).

    A pipe or file is not passed: the guest's tty would never deliver its end of file,
    so CMD reads ``/dev/null`` instead."""

    try:
        mode = os.fstat(fd).st_mode
    except OSError:
        return False
    return stat.S_ISCHR(mode) and os.isatty(fd)


def _drain(fd: int, sink: list[bytes]) -> None:
    with os.fdopen(fd, "rb", buffering=0) as f:
        while chunk := f.read(4096):
            sink.append(chunk)
            if len(sink) > 256:
                del sink[:128]


def _wait_guest(proc: subprocess.Popen[bytes]) -> bool:
    """Wait for the guest; on SIGINT/SIGTERM end it.  Returns whether it was interrupted."""
    interrupted = False

    def end(signum: int, _frame: object) -> None:
        nonlocal interrupted
        interrupted = True
        _kill_group(proc)

    old = {s: signal.signal(s, end) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        proc.wait()
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        _kill_group(proc)  # the kernel's helper processes end with it
    return interrupted


def _kill_group(proc: subprocess.Popen[bytes]) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)


def run_with_vcan(cmd: Sequence[str]) -> int:
    """``sandbox --socketcan``: CMD on the host's vcan0 if the kernel has CAN, else in a guest."""
    ok, why = host_can_ready()
    if not ok and ("no vcan0" in why or "is down" in why):
        ok = _try_host_vcan()
    if ok:
        print("sandbox: socketcan vcan0 on the host kernel", file=sys.stderr)
        return subprocess.call(list(cmd))
    guest_ok, guest_why = guest_supported()
    if not guest_ok:
        raise BusError(
            f"no SocketCAN vcan0 here: host: {why}; no user-mode Linux guest: {guest_why}; "
            f"{INSTALL_HINT}"
        )
    return run_in_guest(cmd)


def in_guest() -> bool:
    return os.environ.get(GUEST_ENV) == "1"
