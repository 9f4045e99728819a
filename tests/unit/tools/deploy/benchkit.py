"""What the doctor's tests run it against: the bench in real time (as a chair's drives run),
a drive silenced by a scenario fault, a drive configured with a wrong node ID
(``[bench.drive] right_node_id``), a chair config whose key has a chosen mode.  The HIL
tests use the same pieces across processes."""

from __future__ import annotations

import contextlib
import os
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from dbc.secoc import load_key
from tools.bus.transport import BusSpec, open_bus
from tools.run import scenario as scenario_mod
from tools.run.parts import run_bench
from tools.run.plan import make_plan

ROOT = Path(__file__).resolve().parents[4]
TEST_KEY = ROOT / "dbc" / "keys" / "TEST-ONLY-secoc.key"


def chair_config(
    tmp: Path, *, key_mode: int = 0o600, extra: str = "", chairs_own: bool = False
) -> Path:
    """A chair config naming a copy of the bench's (test) key with ``key_mode``.

    ``chairs_own``: the copy is the same secret without the TEST marker, as a chair's own
    key file reads (the bench still accepts its MACs); the doctor judges its mode."""
    key = tmp / "secoc.key"
    if chairs_own:
        secret = [ln for ln in TEST_KEY.read_text().splitlines() if not ln.startswith("#")]
        key.write_text("\n".join(secret) + "\n")
    else:
        shutil.copyfile(TEST_KEY, key)
    os.chmod(key, key_mode)
    assert load_key(key).is_test is not chairs_own  # the copy is a valid key, of that kind
    cfg = tmp / "chair.toml"
    cfg.write_text(f'[auth]\nkey_file = "{key}"\n{extra}')
    return cfg


def wrong_node_scenario(tmp: Path, right_node_id: int = 5) -> Path:
    """The short route with the right drive configured as node ``right_node_id``."""
    path = tmp / f"right-at-node-{right_node_id}.toml"
    path.write_text(
        f'[scenario]\nroute = "short"\n\n[bench.drive]\nright_node_id = {right_node_id}\n'
    )
    return path


def silent_drive_scenario(tmp: Path, side: str) -> Path:
    """The short route with drive ``side`` silent from t = 0 (not on the bus)."""
    path = tmp / f"silent-{side}.toml"
    path.write_text(
        '[scenario]\nroute = "short"\n\n[[faults]]\ntype = "node-silent"\n'
        f'node = "{side}"\nonset_s = 0.0\n'
    )
    return path


@contextlib.contextmanager
def bench_running(spec: BusSpec, scenario: str = "short") -> Iterator[None]:
    """The bench in real time on ``spec`` until the block ends; its first frames have arrived."""
    plan = make_plan(scenario_mod.load(scenario), None, realtime=True, duration_s=600.0)
    stop = threading.Event()
    failed: list[BaseException] = []

    def run() -> None:
        try:
            run_bench(spec, plan, stop_event=stop)
        except BaseException as err:  # reported by the block's end
            failed.append(err)

    listener = open_bus(spec)
    thread = threading.Thread(target=run, name="bench", daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and listener.recv(0.1) is None and not failed:
            pass
        listener.shutdown()
        yield
    finally:
        listener.shutdown()
        stop.set()
        thread.join(30.0)
    assert not failed, failed
