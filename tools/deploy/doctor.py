"""``wheelchair-hil doctor``: what the controller needs before it may arm, checked without
moving a wheel.

It prints one line per check: ``ok``, ``warning`` or ``FAIL`` followed by the fix, and
``n/a`` where a check does not apply (udp_multicast and the virtual bus have no CAN
controller, so no bitrate and no error state).  It returns 1 on any failure, so that a
service's ``ExecStartPre=`` refuses to start the controller.

What it sends: only requests a drive answers without acting on them, RTRs (Get_Error, and
Get_Version where the wire contract has that frame) and RxSdo *reads* (opcode 0) of the
wire-contract hash, which a drive answers without authentication.  No setpoint, no state
request, no configuration, no Host_Heartbeat.  For ``window_s`` (2 s) it listens to
everything: the drives' heartbeats and encoder estimates, other hosts, and every frame for
the bus load.

The checks, in the order printed: ``config`` (the chair's TOML loads), ``limits`` (the
controller's limits against the ones it pushes to the drives with Set_Limits and
Set_Watchdog), ``key`` (readable by this user, by nobody else), ``realtime`` (SCHED_FIFO and
mlockall permitted), ``clock`` (monotonic, its source, its rate), ``interface`` (up,
bitrate, error state from ``ip -details -json link``), ``bus`` (opened), ``drive left`` /
``drive right`` (heartbeat, axis state, error bits, encoder estimates), ``nodes`` (no
heartbeat from a node ID the contract does not know, no other host), ``version``
(Get_Version), ``contract`` (the drives' wire-contract hash equals the host's) and
``busload``.
"""

from __future__ import annotations

import argparse
import contextlib
import enum
import getpass
import json
import math
import os
import shutil
import subprocess
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

from controller.config import ControllerConfig, load_config
from controller.kinematics import TWO_PI
from dbc.codec import (
    DRIVES,
    AxisError,
    AxisState,
    Cmd,
    Codec,
    EncoderEstimates,
    GetError,
    Heartbeat,
    HostHeartbeat,
    Node,
    RxSdo,
    SdoEndpoint,
    SdoOpcode,
    TxSdo,
)
from dbc.errors import CodecError, DecodeError
from dbc.runtime import realtime
from dbc.runtime.busio import recv_dropping
from dbc.runtime.errors import ConfigError, WheelchairError
from dbc.secoc import load_key
from tools.bus import busload
from tools.bus.transport import BusSpec, open_bus
from tools.run import from_args

#: How long the doctor listens to the bus (the bus load is measured over it).
WINDOW_S = 2.0
#: The drives' nominal bitrate (docs/architecture.md, "The wire").
NOMINAL_BITRATE = 500_000
#: A bus busier than this (worst-case stuffing) leaves too little room for a burst.
BUSLOAD_WARN_PCT = 50.0
BUSLOAD_FAIL_PCT = 80.0
#: NTP slews a clock by at most 500 ppm; a monotonic clock off its raw rate by more is broken.
CLOCK_RATE_MAX_PPM = 500.0
#: The most Set_Input_Vel_Auth carries (rev/s, dbc/wheelchair.dbc).
AUTH_VEL_MAX_REVPS = 3.2767
#: Error bits of a latched stop (a watchdog or host-timeout expiry, an Estop): what the
#: person who starts the controller again decides to clear.  Any other bit is a fault.
LATCHED_STOPS = (
    AxisError.WATCHDOG_TIMER_EXPIRED | AxisError.MISSING_INPUT | AxisError.ESTOP_REQUESTED
)
_SIDE = {Node.LEFT: "left", Node.RIGHT: "right"}


class Status(enum.Enum):
    OK = "ok"
    WARN = "warning"
    FAIL = "FAIL"
    NA = "n/a"


@dataclass(frozen=True)
class Check:
    """One line of the doctor's report."""

    name: str
    status: Status
    detail: str
    fix: str = ""

    def line(self) -> str:
        text = f"{self.status.value:<8}{self.name:<12}{self.detail}"
        return f"{text} -- fix: {self.fix}" if self.fix else text


@dataclass
class Capture:
    """What the doctor heard in its window."""

    seconds: float = 0.0
    frames: int = 0
    bits: int = 0
    #: node ID -> heartbeats (also from node IDs the contract does not know)
    heartbeats: dict[int, list[Heartbeat]] = field(default_factory=dict)
    encoder: Counter[int] = field(default_factory=Counter)
    sdo: dict[tuple[int, int], int] = field(default_factory=dict)
    errors: dict[int, GetError] = field(default_factory=dict)
    versions: dict[int, dict[str, Any]] = field(default_factory=dict)
    host_heartbeats: int = 0
    bench_frames: int = 0
    bench_bits: int = 0
    rx_dropped: dict[str, int] = field(default_factory=dict)
    send_failed: list[str] = field(default_factory=list)
    #: (monotonic, monotonic raw) ns at the window's start and end
    clocks: list[tuple[int, int]] = field(default_factory=list)


# ------------------------------------------------------------------ the report


def run_checks(
    config_path: str | Path | None,
    spec: BusSpec | None,
    *,
    window_s: float = WINDOW_S,
    rt_priority: int = 0,
    codec: Codec | None = None,
    spec_error: str = "",
) -> list[Check]:
    """Every check, in report order.  Never raises for what it checks: each problem is a line.

    ``spec`` None (with ``spec_error``) when the bus could not even be resolved.
    """
    codec = codec or Codec.default()
    checks: list[Check] = []
    cfg: ControllerConfig | None = None
    try:
        cfg = load_config(config_path)
        where = config_path or "controller/controller.toml (the defaults: a chair names its own)"
        checks.append(Check("config", Status.OK, f"{where}: valid"))
    except ConfigError as err:
        checks.append(
            Check(
                "config",
                Status.FAIL,
                str(err),
                "correct that key (`wheelchair-hil params` lists every key, unit and bound)",
            )
        )
    if cfg is not None:
        checks += check_limits(cfg, codec)
        checks.append(check_key(cfg))
    else:
        checks.append(Check("limits", Status.FAIL, "not checked: the config did not load"))
        checks.append(Check("key", Status.FAIL, "not checked: the config did not load"))
    checks.append(check_realtime(rt_priority))
    clock_start = _clocks()
    if spec is None:
        checks.append(
            Check("bus", Status.FAIL, spec_error, "name the bus: --bus/--channel or [bus]")
        )
        checks.append(check_clock([clock_start, _clocks()]))
        return checks
    checks.append(check_interface(spec))
    cap: Capture | None = None
    try:
        bus = open_bus(spec)
    except WheelchairError as err:
        checks.append(Check("bus", Status.FAIL, str(err), _bus_fix(spec)))
    else:
        try:
            checks.append(Check("bus", Status.OK, f"{spec.describe()} open"))
            cap = listen(bus, codec, window_s, check_version=True)
        finally:
            bus.shutdown()
    if cap is None:
        checks.append(check_clock([clock_start, _clocks()]))
        for name in ("drive left", "drive right", "contract", "busload"):
            checks.append(Check(name, Status.FAIL, "not checked: the bus did not open"))
        return checks
    checks.append(check_clock(cap.clocks))
    cfg_or_default = cfg or ControllerConfig()
    checks += [check_drive(cap, n, codec) for n in DRIVES]
    checks.append(check_nodes(cap, codec))
    checks.append(check_version(cap, codec))
    checks.append(check_contract(cap, cfg_or_default, codec))
    checks.append(check_busload(cap, spec))
    return checks


def report(checks: list[Check], out: Callable[[str], object] = print) -> int:
    """Print the lines and a verdict; 1 if any check failed, else 0."""
    for c in checks:
        out(c.line())
    fails = sum(c.status is Status.FAIL for c in checks)
    warns = sum(c.status is Status.WARN for c in checks)
    warnings = f"{warns} warning{'' if warns == 1 else 's'}"
    if fails:
        out(f"doctor: {fails} failed, {warnings}: the controller must not arm")
        return 1
    out(f"doctor: no failure ({warnings})")
    return 0


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """``wheelchair-hil doctor``."""
    if not 0.1 <= args.window <= 60.0:
        raise WheelchairError(f"doctor --window {args.window:g} is outside [0.1, 60] s")
    codec = from_args.codec_for(args)
    bus_cfg = None
    with contextlib.suppress(ConfigError):  # reported by the config check
        bus_cfg = load_config(args.config).bus
    spec: BusSpec | None = None
    spec_error = ""
    try:
        spec = from_args.bus_spec(args, bus_cfg)
    except WheelchairError as err:
        spec_error = str(err)
    checks = run_checks(
        args.config,
        spec,
        window_s=args.window,
        rt_priority=args.rt_priority,
        codec=codec,
        spec_error=spec_error,
    )
    return report(checks)


# ------------------------------------------------------------------ the bus


def listen(bus: can.BusABC, codec: Codec, window_s: float, *, check_version: bool) -> Capture:
    """Ask the drives for what they answer without acting, and listen for ``window_s``."""
    cap = Capture()
    cap.clocks.append(_clocks())
    requests = _requests(codec, check_version)
    _send_all(bus, requests, cap)
    t0 = time.monotonic()
    end = t0 + window_s
    resent = False
    while (now := time.monotonic()) < end:
        if not resent and now - t0 >= window_s / 2:
            resent = True  # once more for a drive that was still booting
            unanswered = [(n, m) for n, m in requests if not _answered(cap, n, m, codec)]
            _send_all(bus, unanswered, cap)
        msg = recv_dropping(bus, min(0.05, end - now), cap.rx_dropped)
        if msg is not None:
            _take(cap, msg, codec)
    cap.seconds = time.monotonic() - t0
    cap.clocks.append(_clocks())
    return cap


def _requests(codec: Codec, check_version: bool) -> list[tuple[Node, can.Message]]:
    out: list[tuple[Node, can.Message]] = []
    for n in DRIVES:
        out.append((n, codec.encode(RxSdo(SdoOpcode.READ, SdoEndpoint.CONTRACT_HASH), n)))
        out.append((n, codec.request(GetError, n)))
        vid = _version_id(codec, n)
        if check_version and vid is not None:
            out.append(
                (
                    n,
                    can.Message(
                        arbitration_id=vid, is_remote_frame=True, dlc=8, is_extended_id=False
                    ),
                )
            )
    return out


def _answered(cap: Capture, node: Node, msg: can.Message, codec: Codec) -> bool:
    if msg.is_remote_frame:
        if msg.arbitration_id == _version_id(codec, node):
            return int(node) in cap.versions
        return int(node) in cap.errors
    return (int(node), int(SdoEndpoint.CONTRACT_HASH)) in cap.sdo


def _send_all(bus: can.BusABC, msgs: list[tuple[Node, can.Message]], cap: Capture) -> None:
    for _n, m in msgs:
        try:
            bus.send(m)
        except (can.CanError, OSError) as err:
            cap.send_failed.append(f"0x{m.arbitration_id:03X}: {err}")


def _version_id(codec: Codec, node: Node) -> int | None:
    """The Get_Version frame's ID for ``node`` if the wire contract has one (ODrive cmd 0x00)."""
    prefix = codec.message_name(Heartbeat, node).split("_", 1)[0]
    try:
        frame_id, _ext = codec.frame_key(f"{prefix}_Get_Version")
    except CodecError:
        return None
    return frame_id


def _take(cap: Capture, msg: can.Message, codec: Codec) -> None:
    cap.frames += 1
    n_bytes = 0 if msg.is_remote_frame else len(msg.data)
    cap.bits += busload.frame_bits(n_bytes, msg.is_extended_id)
    if msg.is_extended_id:
        cap.bench_frames += 1
        cap.bench_bits += busload.frame_bits(n_bytes, True)
        return
    if msg.is_remote_frame or msg.is_error_frame:
        return
    node_id, cmd = msg.arbitration_id >> 5, msg.arbitration_id & 0x1F
    for n in DRIVES:
        if msg.arbitration_id == _version_id(codec, n):
            with contextlib.suppress(DecodeError):
                cap.versions[int(n)] = dict(codec.decode_signals(msg)[1])
            return
    try:
        frame = codec.decode(msg)
    except DecodeError:
        if cmd == Cmd.HEARTBEAT and node_id not in (int(n) for n in Node):
            # a node the contract does not know: read its heartbeat as a drive's would be
            hb = _as_drive_frame(msg, codec)
            if isinstance(hb, Heartbeat):
                cap.heartbeats.setdefault(node_id, []).append(hb)
        return
    p = frame.payload
    if isinstance(p, Heartbeat) and frame.node is not None:
        cap.heartbeats.setdefault(int(frame.node), []).append(p)
    elif isinstance(p, EncoderEstimates) and frame.node is not None:
        cap.encoder[int(frame.node)] += 1
    elif isinstance(p, TxSdo) and frame.node is not None:
        cap.sdo[(int(frame.node), p.endpoint_id)] = p.value
    elif isinstance(p, GetError) and frame.node is not None:
        cap.errors[int(frame.node)] = p
    elif isinstance(p, HostHeartbeat):
        cap.host_heartbeats += 1


def _as_drive_frame(msg: can.Message, codec: Codec) -> object:
    """Decode a frame of an unknown node as if the left drive had sent it."""
    alias = can.Message(
        arbitration_id=(int(Node.LEFT) << 5) | (msg.arbitration_id & 0x1F),
        data=msg.data,
        dlc=msg.dlc,
        is_extended_id=False,
    )
    try:
        return codec.decode(alias).payload
    except DecodeError:
        return None


# ------------------------------------------------------------------ the checks


def check_limits(cfg: ControllerConfig, codec: Codec) -> list[Check]:
    """The controller's limits against what it pushes to the drives when arming.

    A drive cannot report its own limits over CAN Simple: the ones that count are those the
    controller sends with Set_Limits and Set_Watchdog at every arming (controller/node.py).
    """
    d, lim, g, lp, s = cfg.drives, cfg.limits, cfg.geometry, cfg.loop, cfg.safety
    r = g.wheel_radius_m
    period_ms = lp.period_s * 1e3
    problems: list[Check] = []

    def fail(detail: str, fix: str) -> None:
        problems.append(Check("limits", Status.FAIL, detail, fix))

    def warn(detail: str, fix: str) -> None:
        problems.append(Check("limits", Status.WARN, detail, fix))

    wheel_revps = lim.wheel_max_radps / TWO_PI
    if wheel_revps > d.velocity_limit_revps:
        fail(
            f"limits.wheel_max_radps = {lim.wheel_max_radps:g} rad/s ({wheel_revps:.3f} rev/s) "
            f"is above drives.velocity_limit_revps = {d.velocity_limit_revps:g} rev/s: the "
            "drives would clip commands the limiter allows (the chair leaves its arc)",
            "lower limits.wheel_max_radps or raise drives.velocity_limit_revps",
        )
    if d.require_auth and d.velocity_limit_revps > AUTH_VEL_MAX_REVPS:
        fail(
            f"drives.velocity_limit_revps = {d.velocity_limit_revps:g} rev/s is above "
            f"{AUTH_VEL_MAX_REVPS} rev/s, the most Set_Input_Vel_Auth carries",
            f"drives.velocity_limit_revps <= {AUTH_VEL_MAX_REVPS}",
        )
    if d.watchdog_timeout_ms == 0:
        fail(
            "drives.watchdog_timeout_ms = 0: the drives' setpoint watchdog is off, a host that "
            "dies leaves both wheels at their last setpoint",
            "drives.watchdog_timeout_ms = 100 (10 control periods)",
        )
    elif d.watchdog_timeout_ms < 3 * period_ms:
        fail(
            f"drives.watchdog_timeout_ms = {d.watchdog_timeout_ms} ms is under 3 control periods "
            f"({3 * period_ms:g} ms): one late tick stops the chair",
            f"drives.watchdog_timeout_ms >= {math.ceil(3 * period_ms)}",
        )
    hb_ms = lp.host_heartbeat_period_s * 1e3
    if d.host_timeout_ms == 0:
        warn(
            "drives.host_timeout_ms = 0: the drives do not watch Host_Heartbeat (a host whose "
            "loop hangs but whose setpoints keep coming is not caught by the drives)",
            f"drives.host_timeout_ms = {round(3 * hb_ms)} (3 heartbeats)",
        )
    elif d.host_timeout_ms < 2 * hb_ms:
        fail(
            f"drives.host_timeout_ms = {d.host_timeout_ms} ms is under 2 Host_Heartbeat periods "
            f"({2 * hb_ms:g} ms): one late heartbeat stops the chair",
            f"drives.host_timeout_ms >= {round(3 * hb_ms)}",
        )
    drive_stop_mps2 = d.stop_decel_revps2 * TWO_PI * r
    if abs(drive_stop_mps2 - lim.safe_stop_decel_mps2) > 0.2 * lim.safe_stop_decel_mps2:
        warn(
            f"the drives' stop ramp (drives.stop_decel_revps2 = {d.stop_decel_revps2:g} rev/s^2 "
            f"= {drive_stop_mps2:.2f} m/s^2 at r = {r:g} m) and the host's "
            f"(limits.safe_stop_decel_mps2 = {lim.safe_stop_decel_mps2:g} m/s^2) differ by "
            "more than 20 %: a wheel stopped by its watchdog and one stopped by the host "
            "decelerate differently, the chair turns while it stops",
            f"drives.stop_decel_revps2 = {lim.safe_stop_decel_mps2 / (TWO_PI * r):.2f}",
        )
    enc_ms = codec.cycle_time_ms(EncoderEstimates, Node.LEFT) or 10
    if s.encoder_stale_periods * period_ms <= enc_ms:
        fail(
            f"safety.encoder_stale_periods = {s.encoder_stale_periods} periods "
            f"({s.encoder_stale_periods * period_ms:g} ms) is not above the encoder cycle "
            f"({enc_ms} ms): every tick would look stale",
            f"safety.encoder_stale_periods >= {math.floor(enc_ms / period_ms) + 2}",
        )
    v_wheel = lim.v_max_mps / r
    if v_wheel > lim.wheel_max_radps * 1.0001:
        warn(
            f"limits.v_max_mps = {lim.v_max_mps:g} m/s needs {v_wheel:.2f} rad/s at the wheel, "
            f"above limits.wheel_max_radps = {lim.wheel_max_radps:g}: the top speed is "
            f"{lim.wheel_max_radps * r:.2f} m/s",
            "make them agree",
        )
    if problems:
        return problems
    return [
        Check(
            "limits",
            Status.OK,
            f"wheel limit {wheel_revps:.3f} rev/s under the drives' {d.velocity_limit_revps:g} "
            f"rev/s (Set_Limits at arming, with {d.current_limit_a:g} A); watchdog "
            f"{d.watchdog_timeout_ms} ms = {d.watchdog_timeout_ms / period_ms:g} periods; host "
            f"timeout {d.host_timeout_ms} ms; stop ramps {drive_stop_mps2:.2f} (drives) and "
            f"{lim.safe_stop_decel_mps2:.2f} (host) m/s^2",
        )
    ]


def check_key(cfg: ControllerConfig) -> Check:
    """The authentication key: present, readable by this user, not the test key, and (a
    chair's own key) readable by nobody else."""
    path = Path(cfg.auth.key_file)
    user = getpass.getuser()
    if not cfg.drives.require_auth:
        return Check(
            "key",
            Status.WARN,
            "drives.require_auth = false: setpoints travel without MAC (a stock ODrive); only "
            "the host's plausibility check is left against a foreign node (docs/safety.md § 1a)",
        )
    try:
        st = path.stat()
    except OSError as err:
        return Check(
            "key",
            Status.FAIL,
            f"{path}: {err.strerror} (auth.key_file)",
            "install the chair's key there (docs/deploy.md, 'The key') or correct auth.key_file",
        )
    mode = st.st_mode & 0o777
    if not os.access(path, os.R_OK):
        return Check(
            "key",
            Status.FAIL,
            f"{path}: not readable by user {user} (mode {mode:04o}, owner uid {st.st_uid})",
            f"chown {user} {path} && chmod 600 {path}",
        )
    try:
        key = load_key(path)
    except ConfigError as err:
        return Check("key", Status.FAIL, str(err), "write one line of >= 32 hex digits")
    if key.is_test:
        # public anyway, and a clone has it with git's mode 0644: its mode is no secret's
        return Check(
            "key",
            Status.WARN,
            f"{path} is the repository's public TEST key: anyone can forge setpoints (fine on "
            "the bench, never on a chair)",
            "generate the chair's own key and load it into the drives (docs/deploy.md)",
        )
    if mode & 0o077:
        return Check(
            "key",
            Status.FAIL,
            f"{path} has mode {mode:04o}: group or others may read or write the key that "
            "authenticates every setpoint",
            f"chmod 600 {path}",
        )
    return Check("key", Status.OK, f"{path}: {len(key.secret) * 8}-bit key, mode {mode:04o}")


def check_realtime(rt_priority: int) -> Check:
    """SCHED_FIFO at ``rt_priority`` (1 if 0) and mlockall, tried and undone."""
    prio = rt_priority or 1
    user = getpass.getuser()
    notes, denied = realtime.probe(prio)
    if not denied:
        return Check("realtime", Status.OK, "; ".join(notes))
    fix = (
        f"add to /etc/security/limits.d/99-wheelchair-hil.conf the lines '{user} - rtprio "
        f"{max(prio, 80)}' and '{user} - memlock unlimited', then log in again (a systemd "
        "service sets LimitRTPRIO= and LimitMEMLOCK= instead: wheelchair-hil install-service)"
    )
    status = Status.FAIL if rt_priority else Status.WARN
    what = "not permitted: " + ", ".join(denied)
    if not rt_priority:
        what += " (the controller would run without real-time priority; --rt-priority N asks)"
    return Check("realtime", status, "; ".join([what, *notes]), fix)


def _clocks() -> tuple[int, int]:
    raw = getattr(time, "CLOCK_MONOTONIC_RAW", None)
    return time.monotonic_ns(), (time.clock_gettime_ns(raw) if raw is not None else -1)


def check_clock(pairs: list[tuple[int, int]]) -> Check:
    """The monotonic clock: monotonic by construction and by sampling, its source, its rate."""
    info = time.get_clock_info("monotonic")
    if not info.monotonic:
        return Check(
            "clock", Status.FAIL, f"time.monotonic is not monotonic ({info.implementation})"
        )
    prev = time.monotonic_ns()
    backwards = 0
    for _ in range(100_000):
        now = time.monotonic_ns()
        if now < prev:
            backwards += 1
        prev = now
    if backwards:
        return Check(
            "clock",
            Status.FAIL,
            f"CLOCK_MONOTONIC went backwards {backwards} times in 100000 reads",
            "a kernel or virtualisation fault: use another clocksource (clocksource= boot option)",
        )
    src_file = Path("/sys/devices/system/clocksource/clocksource0/current_clocksource")
    try:
        source = src_file.read_text().strip()
    except OSError:
        source = "unknown"
    parts = [f"monotonic ({info.implementation}, resolution {info.resolution * 1e9:g} ns)"]
    parts.append(f"clocksource {source}")
    status, fix = Status.OK, ""
    (m0, r0), (m1, r1) = pairs[0], pairs[-1]
    if r0 >= 0 and r1 > r0 and m1 - m0 > 100_000_000:
        ppm = ((m1 - m0) - (r1 - r0)) / (r1 - r0) * 1e6
        parts.append(f"rate {round(ppm):+d} ppm against the raw clock over {(m1 - m0) / 1e9:.1f} s")
        if abs(ppm) > CLOCK_RATE_MAX_PPM:
            status = Status.FAIL
            fix = "the monotonic clock is being slewed beyond NTP's 500 ppm: check timesyncd/chrony"
    if status is Status.OK and (info.resolution > 1e-6 or source == "jiffies"):
        status = Status.WARN
        fix = "a clocksource with microsecond resolution (tsc, arch_sys_counter)"
    return Check("clock", status, ", ".join(parts), fix)


def check_interface(spec: BusSpec) -> Check:
    """The CAN interface: up, bitrate, error state (SocketCAN); honest n/a elsewhere."""
    if spec.interface == "socketcan":
        return _check_socketcan(spec)
    if spec.interface == "udp_multicast":
        up = _iface_up("lo")
        if up is False:
            return Check(
                "interface",
                Status.FAIL,
                "udp_multicast: loopback lo is down, no frame can pass",
                "ip link set lo up (or run inside wheelchair-hil sandbox)",
            )
        return Check(
            "interface",
            Status.NA,
            f"udp_multicast ({spec.channel}) has no CAN controller: no bitrate, no error state "
            "(loopback up; the bench's bus, never a chair's)",
        )
    if spec.interface == "virtual":
        return Check("interface", Status.NA, "virtual bus: in this process only, no controller")
    return Check(
        "interface",
        Status.NA,
        f"{spec.interface}: the adapter's state is not readable here; python-can sets "
        f"{spec.bitrate} bit/s when it opens it",
    )


def _iface_up(name: str) -> bool | None:
    """Whether interface ``name`` of this network namespace is up (None: cannot tell).

    Asked of the kernel through ``ip``: /sys/class/net shows the namespace that mounted
    /sys, which inside ``wheelchair-hil sandbox`` is the host's.
    """
    try:
        link = ip_link(name)
    except (WheelchairError, OSError, subprocess.TimeoutExpired):
        return None
    return "UP" in link.get("flags", [])


def _bus_fix(spec: BusSpec) -> str:
    if spec.interface == "socketcan":
        return _bringup(spec.channel, spec.bitrate)
    if spec.interface == "udp_multicast":
        return "run inside wheelchair-hil sandbox (loopback up, 224.0.0.0/4 routed to it)"
    return "check the adapter and its driver"


def _bringup(channel: str, bitrate: int) -> str:
    return (
        f"sudo ip link set {channel} down; sudo ip link set {channel} type can bitrate {bitrate} "
        f"restart-ms 100; sudo ip link set {channel} txqueuelen 1000; sudo ip link set {channel} up"
    )


def ip_link(channel: str) -> dict[str, Any]:
    """``ip -details -statistics -json link show dev CHANNEL`` as a dict (WheelchairError if not)."""
    ip = shutil.which("ip")
    if ip is None:
        raise WheelchairError("ip (iproute2) is not installed")
    res = subprocess.run(
        [ip, "-details", "-statistics", "-json", "link", "show", "dev", channel],
        capture_output=True,
        text=True,
        timeout=10,
        check=False,
    )
    if res.returncode != 0:
        raise WheelchairError(res.stderr.strip() or f"ip exited with {res.returncode}")
    try:
        data = json.loads(res.stdout)
    except json.JSONDecodeError as err:
        raise WheelchairError(f"ip -json gave no JSON ({err}): iproute2 too old?") from err
    if not isinstance(data, list) or not data or not isinstance(data[0], dict):
        raise WheelchairError(f"ip -json link show {channel}: unexpected output {res.stdout!r}")
    link: dict[str, Any] = data[0]
    return link


def judge_socketcan(link: dict[str, Any], channel: str, bitrate: int) -> Check:
    """Judge one ``ip -json`` link record (separate from :func:`ip_link` so it can be tested)."""
    flags = link.get("flags", [])
    info = link.get("linkinfo", {}) or {}
    kind = info.get("info_kind", "?")
    data = info.get("info_data", {}) or {}
    txq = link.get("txqlen")
    if "UP" not in flags:
        fix = f"sudo ip link set {channel} up" if kind == "vcan" else _bringup(channel, bitrate)
        return Check("interface", Status.FAIL, f"{channel} ({kind}) is down", fix)
    if kind == "vcan":
        return Check(
            "interface",
            Status.OK,
            f"{channel} up (vcan: virtual CAN, no bitrate and no error state; txqueuelen {txq})",
        )
    if kind != "can":
        return Check(
            "interface", Status.FAIL, f"{channel} is a {kind} link, not a CAN interface", ""
        )
    state = data.get("state", "?")
    have = (data.get("bittiming") or {}).get("bitrate")
    restart_ms = data.get("restart_ms", 0)
    berr = data.get("berr_counter") or {}
    stats = (link.get("stats64") or link.get("stats") or {}).get("rx", {}) or {}
    detail = (
        f"{channel} up, {have} bit/s, {state}, restart-ms {restart_ms}, txqueuelen {txq}, "
        f"error counters tx {berr.get('tx', 0)} rx {berr.get('rx', 0)}, "
        f"rx errors {stats.get('errors', 0)}"
    )
    if have != bitrate:
        return Check(
            "interface",
            Status.FAIL,
            f"{detail}: bitrate {have}, the drives' is {bitrate}",
            _bringup(channel, bitrate),
        )
    if state in ("BUS-OFF", "STOPPED", "ERROR-PASSIVE"):
        return Check(
            "interface",
            Status.FAIL,
            f"{detail}: the controller is {state}",
            "check CAN_H/CAN_L wiring, one 120 ohm terminator at each end, every node's bitrate; "
            + _bringup(channel, bitrate),
        )
    if state == "ERROR-WARNING":
        return Check("interface", Status.WARN, detail, "check wiring and termination")
    if not restart_ms:
        return Check(
            "interface",
            Status.WARN,
            f"{detail}: restart-ms 0, a bus-off never recovers by itself",
            _bringup(channel, bitrate),
        )
    if isinstance(txq, int) and txq < 100:
        return Check(
            "interface",
            Status.WARN,
            f"{detail}: a short transmit queue fails a burst of frames with ENOBUFS",
            f"sudo ip link set {channel} txqueuelen 1000",
        )
    return Check("interface", Status.OK, detail)


def _check_socketcan(spec: BusSpec) -> Check:
    try:
        link = ip_link(spec.channel)
    except (WheelchairError, OSError, subprocess.TimeoutExpired) as err:
        return Check(
            "interface",
            Status.FAIL,
            f"{spec.channel}: {err}",
            f"is the adapter plugged in and its driver loaded? {_bringup(spec.channel, spec.bitrate)}",
        )
    return judge_socketcan(link, spec.channel, spec.bitrate)


def check_drive(cap: Capture, node: Node, codec: Codec) -> Check:
    """One drive: heartbeats, axis state, error bits, encoder estimates, Get_Error."""
    side = _SIDE[node]
    name = f"drive {side}"
    hb_id = codec.frame_id(Heartbeat, node)
    beats = cap.heartbeats.get(int(node), [])
    if not beats:
        strangers = _unknown_nodes(cap)
        if strangers:
            ids = ", ".join(f"{n} (0x{(n << 5) | Cmd.HEARTBEAT:03X})" for n in strangers)
            return Check(
                name,
                Status.FAIL,
                f"no heartbeat from node {int(node)} (0x{hb_id:03X}) in {cap.seconds:.1f} s; "
                f"a drive sends heartbeats as node {ids}: the {side} drive with a wrong node ID?",
                f"set that drive's node ID to {int(node)}: odrv.axis0.config.can.node_id = "
                f"{int(node)}; odrv.save_configuration()",
            )
        return Check(
            name,
            Status.FAIL,
            f"no heartbeat from node {int(node)} (0x{hb_id:03X}) in {cap.seconds:.1f} s: the "
            f"{side} drive is not on the bus",
            "check its power and CAN wiring, its bitrate (500 kbit/s) and node ID "
            f"({int(node)}); candump shows who talks",
        )
    last = beats[-1]
    state = AxisState(last.axis_state).name
    rate = len(beats) / cap.seconds if cap.seconds else 0.0
    enc = cap.encoder.get(int(node), 0)
    enc_rate = enc / cap.seconds if cap.seconds else 0.0
    detail = (
        f"node {int(node)}: {state}, axis error 0x{last.axis_error:X}, "
        f"{rate:.0f} heartbeats/s, {enc_rate:.0f} encoder estimates/s"
    )
    err = cap.errors.get(int(node))
    if err is not None:
        detail += f", Get_Error active 0x{err.active_errors:X} disarm 0x{err.disarm_reason:X}"
    if last.axis_error & ~LATCHED_STOPS:
        return Check(
            name,
            Status.FAIL,
            f"{detail}: drive error {_error_names(last.axis_error)}",
            "a fault of the drive, motor or supply: find and fix it (odrivetool: "
            "dump_errors(odrv)); the controller would clear it when arming",
        )
    if last.axis_error:
        return Check(
            name,
            Status.WARN,
            f"{detail}: latched stop {_error_names(last.axis_error)}",
            "starting the controller clears it (Clear_Errors) and arms: do so only once the "
            "cause of the stop is understood (the last run's logs)",
        )
    if last.axis_state == AxisState.CLOSED_LOOP_CONTROL:
        return Check(
            name,
            Status.FAIL,
            f"{detail}: already armed, another host is driving it",
            "stop the other controller (systemctl stop wheelchair-hil) and idle the drive",
        )
    if enc == 0:
        exp = codec.cycle_time_ms(EncoderEstimates, node) or 10
        return Check(
            name,
            Status.FAIL,
            f"{detail}: no Get_Encoder_Estimates, the controller needs them every {exp} ms",
            f"ODrive: odrv.axis0.config.can.encoder_msg_rate_ms = {exp}",
        )
    if last.axis_state != AxisState.IDLE:
        return Check(name, Status.WARN, f"{detail}: not IDLE", "wait for its start-up to end")
    return Check(name, Status.OK, detail)


def _error_names(bits: int) -> str:
    names = [f.name for f in AxisError if f.value and bits & f.value and f.name]
    unknown = bits & ~sum(f.value for f in AxisError)
    if unknown:
        names.append(f"0x{unknown:X}")
    return "|".join(str(n) for n in names)


def _unknown_nodes(cap: Capture) -> list[int]:
    known = {int(n) for n in Node}
    return sorted(n for n in cap.heartbeats if n not in known)


def check_nodes(cap: Capture, codec: Codec) -> Check:
    """Heartbeats from node IDs the contract does not know; another host on the bus."""
    strangers = _unknown_nodes(cap)
    if strangers:
        return Check(
            "nodes",
            Status.FAIL,
            "heartbeats from node " + ", ".join(map(str, strangers)) + ", which the wire contract "
            f"does not know (left = {int(Node.LEFT)}, right = {int(Node.RIGHT)})",
            "give each drive its node ID (odrv.axis0.config.can.node_id; save_configuration)",
        )
    if cap.host_heartbeats:
        return Check(
            "nodes",
            Status.FAIL,
            f"{cap.host_heartbeats} Host_Heartbeat frames: another controller is on the bus",
            "stop it before this one arms (systemctl stop wheelchair-hil)",
        )
    seen = sorted(cap.heartbeats)
    extra = f"; {cap.bench_frames} bench frames (emulated drives)" if cap.bench_frames else ""
    heard = f"heartbeats from node {', '.join(map(str, seen))} only" if seen else "no heartbeat"
    return Check("nodes", Status.OK, f"{heard}, no other host{extra}")


def check_version(cap: Capture, codec: Codec) -> Check:
    """Get_Version, where the wire contract has that frame."""
    present = [n for n in DRIVES if int(n) in cap.heartbeats]
    if not any(_version_id(codec, n) is not None for n in DRIVES):
        return Check(
            "version",
            Status.WARN,
            f"drive did not answer Get_Version: {codec.path.name} has no Get_Version frame, so the "
            "firmware version is not read; the contract hash below checks the protocol",
        )
    missing = [n for n in present if int(n) not in cap.versions]
    found = "; ".join(
        f"{_SIDE[Node(n)]}: " + " ".join(f"{k}={v}" for k, v in sorted(sig.items()))
        for n, sig in sorted(cap.versions.items())
    )
    if missing:
        who = ", ".join(_SIDE[n] for n in missing)
        return Check(
            "version",
            Status.WARN,
            f"drive did not answer Get_Version ({who}){'; ' + found if found else ''}",
            "ODrive answers Get_Version from firmware 0.6.9 on: update the firmware",
        )
    if not cap.versions:
        return Check("version", Status.WARN, "no drive on the bus to ask for Get_Version")
    return Check("version", Status.OK, found)


def check_contract(cap: Capture, cfg: ControllerConfig, codec: Codec) -> Check:
    """The drives' wire-contract hash (RxSdo read of CONTRACT_HASH) equals the host's."""
    host = codec.contract_hash
    ep = int(SdoEndpoint.CONTRACT_HASH)
    if not cfg.auth.check_contract:
        return Check(
            "contract",
            Status.NA,
            f"auth.check_contract = false (a stock ODrive): host {host:08x} ({codec.path.name}) "
            "is not compared",
        )
    got = {n: cap.sdo.get((int(n), ep)) for n in DRIVES if int(n) in cap.heartbeats}
    if not got:
        return Check("contract", Status.FAIL, "not checked: no drive on the bus")
    wrong = {n: h for n, h in got.items() if h is not None and h != host}
    if wrong:
        what = ", ".join(f"{_SIDE[n]} {h:08x}" for n, h in wrong.items())
        return Check(
            "contract",
            Status.FAIL,
            f"host {host:08x} ({codec.path}), drive {what}: the controller would refuse to arm "
            "(CONTRACT_MISMATCH)",
            "flash the drives built from this DBC, or run with the DBC they were built from (--dbc)",
        )
    silent = [n for n, h in got.items() if h is None]
    if silent:
        return Check(
            "contract",
            Status.FAIL,
            f"{', '.join(_SIDE[n] for n in silent)} did not answer the RxSdo read of endpoint "
            f"0x{ep:04X}: the controller would refuse to arm",
            "a stock ODrive has no such endpoint: set auth.check_contract = false",
        )
    missing = [_SIDE[n] for n in DRIVES if n not in got]
    tail = f" (not asked: {', '.join(missing)} absent)" if missing else ""
    return Check(
        "contract",
        Status.OK,
        f"{' and '.join(_SIDE[n] for n in got)} {host:08x} = host's ({codec.path.name}){tail}",
    )


def check_busload(cap: Capture, spec: BusSpec) -> Check:
    """The load of what was heard, at the bus's bitrate, worst-case bit stuffing."""
    bitrate = (
        spec.bitrate if spec.interface not in ("udp_multicast", "virtual") else NOMINAL_BITRATE
    )
    pct = busload.load_pct(cap.bits, cap.seconds, bitrate)
    where = "" if spec.interface not in ("udp_multicast", "virtual") else " (on a real bus)"
    detail = (
        f"{pct:.1f} % of {bitrate // 1000} kbit/s{where} over {cap.seconds:.1f} s: "
        f"{cap.frames} frames, {cap.bits} bits worst-case stuffing"
    )
    if cap.bench_frames:
        own = busload.load_pct(cap.bits - cap.bench_bits, cap.seconds, bitrate)
        detail += f" ({own:.1f} % without the bench's {cap.bench_frames} frames)"
    if cap.rx_dropped:
        detail += f"; dropped receives {cap.rx_dropped}"
    if cap.send_failed:
        detail += f"; requests not sent: {cap.send_failed[0]}"
    if pct > BUSLOAD_FAIL_PCT:
        return Check("busload", Status.FAIL, detail, "find the node that floods the bus (candump)")
    if pct > BUSLOAD_WARN_PCT:
        return Check("busload", Status.WARN, detail, "reduce cyclic rates or raise the bitrate")
    return Check("busload", Status.OK, detail)
