"""The one runner of cross-process runs: parts start in turn after each one's READY, a part
that fails is reported with its own error, PIDs are published, and the same runner works
from outside a private namespace."""

from __future__ import annotations

import json
import signal
import sys
from pathlib import Path

import pytest

from tools.bus import transport
from tools.run import processes
from tools.run.processes import Part, PartFailedError, Parts, SandboxedParts

SANDBOX_OK, SANDBOX_WHY = transport.sandbox_supported()


def _py(tmp: Path, name: str, code: str, *, ready: bool = True) -> Part:
    return Part(
        name,
        (sys.executable, "-c", code),
        str(tmp / f"{name}.err"),
        ready=ready,
        out=str(tmp / f"{name}.out"),
    )


def _stamp(path: Path, name: str) -> str:
    """Code that appends ``name`` to ``path`` (the order the parts ran in)."""
    return f"open({str(path)!r}, 'a').write({name + chr(10)!r})"


def test_each_part_starts_only_after_the_one_before_said_ready(tmp_path: Path) -> None:
    order = tmp_path / "order"
    # the first part is slow to get ready, and stamps only just before it says so
    first = f"import time; time.sleep(0.3); {_stamp(order, 'first')}; print('READY', flush=True)"
    second = f"{_stamp(order, 'second')}; print('READY', flush=True); print('done')"
    with Parts(pid_dir=tmp_path) as parts:
        parts.start(_py(tmp_path, "first", first))
        parts.start(_py(tmp_path, "second", second))
        codes = parts.wait(30.0)
    assert codes == {"first": 0, "second": 0}
    assert order.read_text().split() == ["first", "second"]
    assert (tmp_path / "second.out").read_text() == "READY\ndone\n"
    for name in ("first", "second"):
        assert int((tmp_path / f"{name}.pid").read_text()) > 0


def test_a_part_that_ends_before_ready_fails_with_its_own_error(tmp_path: Path) -> None:
    code = "import sys; print('wheelchair-hil: error: no such scenario x', file=sys.stderr); sys.exit(2)"
    after = tmp_path / "after"
    with Parts() as parts, pytest.raises(PartFailedError) as err:
        parts.start(_py(tmp_path, "control", code))
        parts.start(_py(tmp_path, "sim", _stamp(after, "sim"), ready=False))
    assert str(err.value) == "control did not start: no such scenario x"
    assert not after.exists()  # nothing after the failed part was started
    assert "no such scenario x" in (tmp_path / "control.err").read_text()


def test_a_part_that_fails_later_fails_the_run_unless_any_exit_is_expected(
    tmp_path: Path,
) -> None:
    code = "import sys; print('READY', flush=True); print('bus down: error', file=sys.stderr); sys.exit(3)"
    with Parts() as parts:
        parts.start(_py(tmp_path, "record", code))
        with pytest.raises(PartFailedError, match=r"record failed \(exit 3\): bus down: error"):
            parts.wait(30.0)
    with Parts() as parts:
        parts.start(_py(tmp_path, "record", code))
        assert parts.wait(30.0, ok=None) == {"record": 3}


def test_stopping_ends_every_part_still_running(tmp_path: Path) -> None:
    forever = "import time; print('READY', flush=True); time.sleep(600)"
    with Parts() as parts:
        p = parts.start(_py(tmp_path, "sim", forever))
        with pytest.raises(PartFailedError, match="run did not finish within 0 s"):
            parts.wait(0.2)
    assert p.returncode == -signal.SIGTERM


def test_a_pid_is_only_signalled_while_it_runs_the_command_it_should(tmp_path: Path) -> None:
    forever = "import time; print('READY', flush=True); time.sleep(600)"
    with Parts() as parts:
        p = parts.start(_py(tmp_path, "control", forever))
        assert not processes.signal_part(p.pid, signal.SIGKILL, b"tools.cli", b"control")
        assert p.poll() is None
        assert processes.signal_part(p.pid, signal.SIGKILL, b"-c")
        assert p.wait(10.0) == -signal.SIGKILL
    assert not processes.signal_part(p.pid, signal.SIGKILL, b"-c")  # gone


def test_a_real_time_run_starts_record_others_control_and_sim_in_that_order(
    tmp_path: Path,
) -> None:
    other = _py(tmp_path, "attacker", "pass", ready=False)
    parts = processes.realtime_parts(
        tmp_path, "short", 8.0, control=("--config", "c.toml"), rt_priority=80, others=[other]
    )
    assert [p.name for p in parts] == ["record", "attacker", "control", "sim"]
    assert [p.ready for p in parts] == [True, False, True, True]
    record, _, control, sim = (list(p.argv) for p in parts)
    assert record[-3:] == ["--out", str(tmp_path / "run.mcap"), "--ready"]
    assert control[control.index("--duration") + 1] == "23.0"
    assert control[control.index("--rt-priority") + 1] == "80"
    assert sim[sim.index("--rt-priority") + 1] == "81"
    assert record[record.index("--rt-priority") + 1] == "79"  # below the loops, above the rest
    assert sim[sim.index("--duration") + 1] == "8.0"
    assert "--config" in control and "--config" not in sim
    assert all(a[a.index("--bus") + 1] == "udp_multicast" for a in (record, control, sim))


@pytest.mark.skipif(not SANDBOX_OK, reason=f"no private network namespace: {SANDBOX_WHY}")
def test_from_outside_a_namespace_the_parts_run_inside_one_and_report_pids_and_exits(
    tmp_path: Path,
) -> None:
    # the part records the interfaces it sees: only loopback in a private namespace
    probe = (
        "import socket, time; "
        f"open({str(tmp_path / 'ifaces')!r}, 'w').write(' '.join(sorted(n for _, n in socket.if_nameindex()))); "
        "print('READY', flush=True); time.sleep(0.5)"
    )
    parts = [
        _py(tmp_path, "control", probe),
        _py(tmp_path, "sim", "import sys; sys.exit(4)", ready=False),
    ]
    with SandboxedParts(parts, tmp_path, timeout_s=60.0) as run:
        assert run.wait_started()
        pid = run.pid("control")
        assert pid is not None and pid > 0
        assert run.wait() == {"control": 0, "sim": 4}
    assert (tmp_path / "ifaces").read_text() == "lo"
    spec = json.loads((tmp_path / "parts.json").read_text())
    assert [p["name"] for p in spec["parts"]] == ["control", "sim"]


@pytest.mark.skipif(not SANDBOX_OK, reason=f"no private network namespace: {SANDBOX_WHY}")
def test_from_outside_a_part_that_never_starts_fails_the_run_with_its_error(
    tmp_path: Path,
) -> None:
    code = "import sys; print('wheelchair-hil: error: bad config', file=sys.stderr); sys.exit(2)"
    with SandboxedParts([_py(tmp_path, "control", code)], tmp_path, timeout_s=120.0) as run:
        assert not run.wait_started()
        # the part's own end, not the 120 s timeout (that would be subprocess.TimeoutExpired)
        with pytest.raises(PartFailedError, match="control did not start: bad config"):
            run.wait()


def test_realtime_parts_put_the_bench_above_the_controller_and_the_recorder_below() -> None:
    parts = {
        p.name: p.argv for p in processes.realtime_parts(Path("w"), "short", 5.0, rt_priority=20)
    }

    def prio(argv: tuple[str, ...]) -> int:
        return int(argv[argv.index("--rt-priority") + 1])

    assert (prio(parts["sim"]), prio(parts["control"]), prio(parts["record"])) == (21, 20, 19)
    # inside Linux's 1..99 at the edges, and no option at all without SCHED_FIFO
    assert processes.part_rt_priority("sim", 99) == 99
    assert processes.part_rt_priority("record", 1) == 1
    plain = processes.realtime_parts(Path("w"), "short", 5.0)
    assert not any("--rt-priority" in p.argv for p in plain)
