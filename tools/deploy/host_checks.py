"""The doctor's checks of the controller's own computer and configuration (no bus needed).

``limits`` (the controller's limits against the ones it pushes to the drives with Set_Limits
and Set_Watchdog), ``key`` (readable by this user, by nobody else), ``realtime`` (SCHED_FIFO
and mlockall permitted), ``compiled`` (the controller's float kernels compiled, or why they
run from source), ``clock`` (monotonic, its source, its rate).
"""

from __future__ import annotations

import getpass
import math
import os
import time
from pathlib import Path

import controller
from controller import kernels
from controller.config import ControllerConfig
from controller.kinematics import TWO_PI
from dbc.codec import (
    Codec,
    EncoderEstimates,
    Node,
)
from dbc.runtime import realtime
from dbc.runtime.compiled import compiled
from dbc.runtime.errors import ConfigError
from dbc.secoc import load_key
from tools.deploy.check import Check, Status

#: NTP slews a clock by at most 500 ppm; a monotonic clock off its raw rate by more is broken.
CLOCK_RATE_MAX_PPM = 500.0
#: The most Set_Input_Vel_Auth carries (rev/s, dbc/wheelchair.dbc).
AUTH_VEL_MAX_REVPS = 3.2767


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


def check_compiled() -> Check:
    """Whether the controller's float kernels (controller/kernels.py: the fault bank, the pose
    EKF's steps, the limiter's step, the reference's spline) run compiled; a warning, with why,
    where they run from source (the same figures, slower)."""
    if compiled(kernels):
        return Check("compiled", Status.OK, "the controller's float kernels run compiled")
    why = controller.SOURCES_BECAUSE or (
        "this install has none: its build found no C compiler or no Python headers"
    )
    return Check(
        "compiled",
        Status.WARN,
        f"the controller's float kernels run from source ({why}): the same figures, a tick "
        "about 55 us slower on average, 0.5 ms in a tick with a pose fix (the fault bank)",
        "install gcc and python3.11-dev, then build and install the wheel again "
        "(docs/deploy.md, section 1)",
    )


def clocks() -> tuple[int, int]:
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
