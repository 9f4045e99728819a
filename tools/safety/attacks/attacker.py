"""The attacking node: a process on the run's bus that does what a node without the key can do
(docs/safety.md § 5a), started beside bench, controller and recorder (:func:`attacker_part`;
its command line, ``python -m tools.safety.attacks attacker ...``, is
:mod:`tools.safety.attacks.__main__`'s).

* ``forge-both`` / ``forge-left``: right after each of the host's setpoints to a drive, a
  setpoint of 0.907 rev/s (1.71 m/s) of its own, with the host's live freshness + 1 (with
  authentication: and a made-up MAC; without: a plain Set_Input_Vel);
* ``replay``: the host's own setpoint frames from 7 s earlier, replayed in order after each
  live frame, once unchanged and once with the freshness byte re-synced to the live value;
* ``sigkill-rearm``: the controller is killed; 1 s later, for 3 s, every re-arm sequence:
  Clear_Errors, Set_Watchdog with every protection off, Set_Limits, Set_Axis_State
  (CLOSED_LOOP), forged Host_Heartbeats, plain and forged-authenticated setpoints of 0.907
  rev/s; then an Estop.

(``wrong-dbc`` needs no attacking node: the controller is given a DBC whose left Input_Vel
has factor 2, :mod:`tools.safety.attacks.runs`.)
"""

from __future__ import annotations

import json
import random
import signal
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controller.clock import try_realtime
from dbc.codec import (
    DRIVES,
    AxisState,
    BenchEnd,
    BenchStep,
    ClearErrors,
    Codec,
    Estop,
    HostHeartbeat,
    HostState,
    Node,
    SetAxisState,
    SetInputVel,
    SetInputVelAuth,
    SetLimits,
    SetWatchdog,
)
from dbc.errors import DecodeError
from tools.bus import transport
from tools.run.processes import Part, rt_option, signal_part

ATTACKS: tuple[str, ...] = ("forge-both", "forge-left", "replay", "sigkill-rearm", "wrong-dbc")
#: The forged wheel speed of the attacks (rev/s; 1.71 m/s at the 0.30 m rim).
FORGED_REVPS = 0.907
#: How long an attack acts from its onset (s of simulation time).
ATTACK_S = 3.5


@dataclass(frozen=True)
class AttackerOptions:
    """What the attacking node does, and where."""

    #: one of :data:`ATTACKS` but ``wrong-dbc``
    attack: str
    #: the onset (s of simulation time)
    at_s: float
    #: its figures (JSON: onset, frames sent, the host's frames it recorded)
    out: Path
    #: ``sigkill-rearm``: the file with the PID of the ``control`` part to kill
    kill_pid_file: Path | None = None
    #: the run's python-can interface and channel (None: the interface's default)
    bus: str = "udp_multicast"
    channel: str | None = None
    #: SCHED_FIFO priority once started (0: none), as another node's own hardware has
    rt_priority: int = 0


def run_attacker(options: AttackerOptions) -> int:
    """Attack until the bench's Bench_End; write the figures to ``options.out``; 0."""
    codec = Codec.default()
    rng = random.Random(16)
    bus = transport.open_bus(transport.resolve(options.bus, options.channel))
    # A node on the bus reacts in its own hardware's time.  A forged setpoint moves a wheel
    # only if it reaches the drive between the host's setpoint and the drive's step, 1.5 ms
    # later; at normal priority on a loaded machine it came 1-5 ms late, and the unauthenticated
    # forge runs ended with no DISOBEYED.  (Its priority is below the controller's: level with
    # it or above it, two attack runs side by side starved a host at the onset.)
    rt_notes = try_realtime(options.rt_priority) if options.rt_priority > 0 else []
    onset_ns = round(options.at_s * 1e9)
    end_ns = onset_ns + round(ATTACK_S * 1e9)
    sp_ids = {codec.frame_id(SetInputVelAuth, n): n for n in DRIVES}
    sp_ids.update({codec.frame_id(SetInputVel, n): n for n in DRIVES})
    recorded: dict[Node, list[tuple[int, Any]]] = {n: [] for n in DRIVES}
    replay_pos = {n: 0 for n in DRIVES}
    sent = 0
    t_ns = 0
    killed = False
    stopped = False
    hb = 0
    info: dict[str, Any] = {"onset_ns": None, "realtime_notes": rt_notes}

    def send(payload: Any, node: Node | None) -> None:
        nonlocal sent
        try:
            bus.send(codec.encode(payload, node))
            sent += 1
        except Exception:  # the attacker's own trouble must not end the run
            pass

    def send_raw(msg: Any) -> None:
        nonlocal sent
        try:
            bus.send(msg)
            sent += 1
        except Exception:
            pass

    try:
        while True:
            msg = bus.recv(0.5)
            if msg is None:
                continue
            try:
                _node, p = codec.decode(msg)
            except DecodeError:
                continue
            kind = type(p)
            if kind is BenchEnd:
                break
            if kind is BenchStep:
                t_ns = p.sim_time_ns
                if t_ns >= onset_ns and info["onset_ns"] is None:
                    info["onset_ns"] = t_ns
                if options.attack == "sigkill-rearm" and t_ns >= onset_ns:
                    if not killed and options.kill_pid_file:
                        killed = True
                        info["killed"] = _kill_controller(options.kill_pid_file)
                    if onset_ns + 1_000_000_000 <= t_ns < end_ns + 1_000_000_000:
                        hb = (hb + 1) & 0xFF
                        send(HostHeartbeat(HostState.TRACKING, hb), Node.HOST)
                        for n in DRIVES:
                            send(ClearErrors(), n)
                            send(SetWatchdog(0, 0.0, False, 0, False), n)
                            send(SetLimits(20.0, 60.0), n)
                            send(SetAxisState(AxisState.CLOSED_LOOP_CONTROL), n)
                            send(SetInputVel(FORGED_REVPS, 0.0), n)
                            fv = rng.randrange(256)
                            send(SetInputVelAuth(FORGED_REVPS, 0.91, fv, rng.getrandbits(32)), n)
                    elif t_ns >= end_ns + 1_000_000_000 and not stopped:
                        stopped = True
                        for n in DRIVES:
                            send(Estop(), n)
                continue
            target = sp_ids.get(msg.arbitration_id) if not msg.is_extended_id else None
            if target is None:
                continue
            n = target
            # one of the host's setpoints to drive n
            if (
                options.attack == "replay"
                and onset_ns - 7e9 <= t_ns < onset_ns - 7e9 + ATTACK_S * 1e9
            ):
                recorded[n].append((t_ns, msg))
            if not onset_ns <= t_ns < end_ns:
                continue
            if options.attack in ("forge-both", "forge-left"):
                if options.attack == "forge-left" and n != Node.LEFT:
                    continue
                if kind is SetInputVelAuth:
                    fv = (p.freshness + 1) & 0xFF
                    send(SetInputVelAuth(FORGED_REVPS, 0.91, fv, rng.getrandbits(32)), n)
                else:
                    send(SetInputVel(FORGED_REVPS, 0.0), n)
            elif options.attack == "replay":
                rec = recorded[n]
                k = replay_pos[n]
                if k < len(rec):
                    replay_pos[n] = k + 1
                    old = rec[k][1]
                    send_raw(old)
                    if kind is SetInputVelAuth:
                        data = bytearray(old.data)
                        data[3] = (p.freshness + 1) & 0xFF  # re-synced to the live value
                        send_raw(
                            type(old)(
                                arbitration_id=old.arbitration_id, data=data, is_extended_id=False
                            )
                        )
    finally:
        bus.shutdown()
        info["frames_sent"] = sent
        info["recorded"] = {n.name: len(v) for n, v in recorded.items()}
        options.out.write_text(json.dumps(info))
    return 0


def attacker_part(
    out: Path,
    attack: str,
    at_s: float,
    *,
    auth: bool,
    rt_priority: int = 0,
    bus: Sequence[str] = (),
) -> Part:
    """The attacking node as part ``attacker`` of a run in ``out`` (its figures in
    ``out/attacker.json``; ``sigkill-rearm`` kills the part whose PID is in
    ``out/control.pid``); ``bus``: its ``--bus``/``--channel`` (default udp_multicast)."""
    argv = (
        *(sys.executable, "-m", "tools.safety.attacks", "attacker", "--attack", attack),
        *("--at", f"{at_s}", "--auth", "on" if auth else "off"),
        *("--kill-pid-file", f"{out}/control.pid", "--out", f"{out}/attacker.json"),
        *rt_option("attacker", rt_priority),
        *bus,
    )
    return Part("attacker", argv, f"{out}/attacker.err", ready=False, out=f"{out}/attacker.out")


def _kill_controller(pid_file: Path) -> bool:
    """SIGKILL our ``control`` part (its command line checked first: never a recycled PID)."""
    try:
        pid = int(pid_file.read_text())
    except (OSError, ValueError):
        return False
    return signal_part(pid, signal.SIGKILL, b"tools.cli", b"control")
