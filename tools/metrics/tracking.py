"""Run metrics from the bus log: tracking errors against ground truth, command activity.

Tracking errors use the bench's ground truth (``Bench_Truth_Pose``) against the
reference, never the controller's estimate.  The reference is recomputed from
the route with the planner; the route time of each truth sample comes from the
host heartbeats (``Route_Time`` at a known simulation time fixes the offset).
The error convention is the paper's (controller/types.py).

Command activity uses the setpoint frames actually sent (wheel rev/s turned back
into v and omega with the controller's nominal geometry).
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controller.kinematics import TWO_PI
from controller.types import Trajectory
from tools.logs.mcap_io import scan

TRACKING = 2  # HostState.TRACKING
HOST_HEARTBEAT_NS = 100_000_000  # Host_Heartbeat cycle time

#: The DBC messages a run's summary reads (this module, tools.metrics.diagnosis) and an
#: evaluation's figures (the truth twist): what a run without a log collects
#: (tools.logs.collect).  A test compares such a run's summary with a logged run's.
SUMMARY_MESSAGES = (
    "Host_Heartbeat",
    "Host_Diagnosis",
    "Bench_Truth_Pose",
    "Bench_Truth_Twist",
    "Bench_Fault_Event",
    *(
        f"{side}_{name}"
        for side in ("Left", "Right")
        for name in ("Set_Input_Vel_Auth", "Set_Input_Vel", "Get_Encoder_Estimates")
    ),
)


@dataclass
class BusSeries:
    """Decoded signals per DBC message name: {name: {"t": ns array, signal: array}}."""

    data: dict[str, dict[str, np.ndarray]]
    metadata: dict[str, dict[str, str]]
    attachments: dict[str, bytes]

    def get(self, name: str) -> dict[str, np.ndarray]:
        return self.data.get(name, {"t": np.zeros(0, dtype=np.int64)})


class BusCollector:
    """Collects decoded channels while a log is read: the callback of a log scan or merge.

    ``/can/<name>`` channels (all, or ``names``) are kept by DBC message name; topics in
    ``extra_topics`` (the controller's ``/controller/...`` channels, say) by their topic.
    """

    def __init__(
        self, names: Iterable[str] | None = None, extra_topics: Iterable[str] = ()
    ) -> None:
        self.wanted = None if names is None else {f"/can/{n}" for n in names}
        self.extra = frozenset(extra_topics)
        #: key -> signal -> values: lists while messages are added, or whole arrays
        #: (tools.logs.collect decodes a run's columns at once)
        self.columns: dict[str, dict[str, Any]] = defaultdict(lambda: defaultdict(list))
        self._keys: dict[str, str | None] = {}  # topic -> column key (None: not collected)

    def _key(self, topic: str) -> str | None:
        if topic in self.extra:
            return topic
        if not topic.startswith("/can/") or topic == "/can/raw":
            return None
        if self.wanted is not None and topic not in self.wanted:
            return None
        return topic[5:]

    def __call__(self, channel: Any, message: Any) -> None:
        topic = channel.topic
        try:
            key = self._keys[topic]
        except KeyError:
            key = self._keys[topic] = self._key(topic)
        if key is not None:
            self.add(key, message.log_time, json.loads(message.data))

    def add(self, key: str, t_ns: int, values: Mapping[str, Any]) -> None:
        """One decoded message of channel ``key`` (a DBC message name or a topic) at ``t_ns``;
        choice labels (``<signal>_label``) are left out."""
        col = self.columns[key]
        col["t"].append(t_ns)
        for k, v in values.items():
            if not k.endswith("_label"):
                col[k].append(v)

    def clear(self) -> None:
        self.columns.clear()

    def series(
        self, metadata: dict[str, dict[str, str]], attachments: dict[str, bytes]
    ) -> BusSeries:
        """The ``/can/`` channels collected so far, as arrays."""
        data = {
            n: {k: np.asarray(v) for k, v in c.items()}
            for n, c in self.columns.items()
            if n not in self.extra
        }
        return BusSeries(data, metadata, attachments)


def read_bus_log(path: str | Path, names: Iterable[str] | None = None) -> BusSeries:
    """Load decoded channels ``/can/<name>`` (all, or ``names``) of a recorder MCAP.

    A truncated log (killed recorder) is read as far as it is intact, with a warning.
    """

    collector = BusCollector(names)
    contents = scan(path, collector)
    return collector.series(contents.metadata, contents.attachments)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else math.nan


def tracking_window(bus: BusSeries) -> int | None:
    """Simulation time (ns) at which route time 0 was; None if the host never tracked."""
    hb = bus.get("Host_Heartbeat")
    if not hb["t"].size:
        return None
    idx = np.flatnonzero(hb["Host_State"] == TRACKING)
    if not idx.size:
        return None
    i = int(idx[0])
    return int(hb["t"][i]) - round(float(hb["Route_Time"][i]) * 1000.0) * 1_000_000


def last_tracking_ns(bus: BusSeries) -> int | None:
    """Time of the host's last heartbeat in TRACKING, plus one heartbeat period."""
    hb = bus.get("Host_Heartbeat")
    idx = np.flatnonzero(hb["Host_State"] == TRACKING) if hb["t"].size else np.zeros(0, dtype=int)
    if not idx.size:
        return None
    after = np.flatnonzero(hb["Host_State"][idx[-1] :] != TRACKING)
    if after.size:
        return int(hb["t"][idx[-1] + after[0]])
    # still tracking at its last heartbeat: the host ended (or went silent) there
    return int(hb["t"][idx[-1]]) + HOST_HEARTBEAT_NS


def tracking_errors(
    bus: BusSeries, trajectory: Trajectory, t0_ns: int, t1_ns: int | None = None
) -> dict[str, np.ndarray]:
    """Per truth sample in [t0, t1] (default: the whole route): route time, poses, paper errors."""
    tp = bus.get("Bench_Truth_Pose")
    t = tp["t"]
    if not t.size:
        return {}
    tau = (t.astype(np.int64) - t0_ns) * 1e-9
    keep = (tau >= 0.0) & (tau <= trajectory.duration_s + 1e-9)
    if t1_ns is not None:
        keep &= t.astype(np.int64) <= t1_ns
    tau = tau[keep]
    x, y, phi = tp["X"][keep], tp["Y"][keep], tp["Heading"][keep]
    ref = _sample_many(trajectory, tau)
    c, s = np.cos(ref["heading"]), np.sin(ref["heading"])
    dx, dy = x - ref["x"], y - ref["y"]
    xe = c * dx + s * dy
    ye = -s * dx + c * dy
    phie = np.angle(np.exp(1j * (phi - ref["heading"])))
    return {
        "tau": tau,
        "t_ns": t[keep],
        "x": x,
        "y": y,
        "phi": phi,
        "ref_x": ref["x"],
        "ref_y": ref["y"],
        "ref_heading": ref["heading"],
        "ref_v": ref["v"],
        "ref_omega": ref["omega"],
        "x_e": xe,
        "y_e": ye,
        "phi_e": phie,
    }


def _sample_many(trajectory: Trajectory, tau: np.ndarray) -> dict[str, np.ndarray]:
    many = getattr(trajectory, "sample_many", None)
    if many is not None:
        out = many(tau)
        return {
            "x": out["x_m"],
            "y": out["y_m"],
            "heading": out["heading_rad"],
            "v": out["v_mps"],
            "omega": out["omega_radps"],
        }
    samples = [trajectory.sample(float(t)) for t in tau]
    return {
        "x": np.array([r.x_m for r in samples]),
        "y": np.array([r.y_m for r in samples]),
        "heading": np.array([r.heading_rad for r in samples]),
        "v": np.array([r.v_mps for r in samples]),
        "omega": np.array([r.omega_radps for r in samples]),
    }


def setpoint_frames(bus: BusSeries, side: str) -> dict[str, np.ndarray]:
    """A wheel's setpoint frames: the authenticated ones if the host sent any, else the plain
    ODrive ``Set_Input_Vel`` (a host runs with one or the other)."""
    m = bus.get(f"{side}_Set_Input_Vel_Auth")
    return m if m["t"].size else bus.get(f"{side}_Set_Input_Vel")


def commands(
    bus: BusSeries, half_track_m: float, wheel_radius_m: float, t0_ns: int, t1_ns: int
) -> dict[str, np.ndarray]:
    """Commanded v, omega per control tick from the setpoint frames inside [t0, t1]."""
    sides = {side: setpoint_frames(bus, side) for side in ("Left", "Right")}
    left, right = sides["Left"], sides["Right"]
    if not left["t"].size or not right["t"].size:
        return {}
    # pair by tick time: both wheels are commanded in the same tick
    lt, rt = left["t"], right["t"]
    common, li, ri = np.intersect1d(lt, rt, return_indices=True)
    sel = (common >= t0_ns) & (common <= t1_ns)
    wl = left["Input_Vel"][li][sel] * TWO_PI
    wr = right["Input_Vel"][ri][sel] * TWO_PI
    v = 0.5 * wheel_radius_m * (wl + wr)
    w = wheel_radius_m * (wr - wl) / (2.0 * half_track_m)
    return {
        "t_ns": common[sel],
        "v": v,
        "omega": w,
        "wl_revps": wl / TWO_PI,
        "wr_revps": wr / TWO_PI,
    }


def wheel_tracking_rms(bus: BusSeries, t0_ns: int, t1_ns: int) -> dict[str, float]:
    """RMS of encoder speed minus setpoint per wheel (rev/s), setpoints held between frames."""
    out = {}
    for side in ("Left", "Right"):
        sp = setpoint_frames(bus, side)
        enc = bus.get(f"{side}_Get_Encoder_Estimates")
        if not sp["t"].size or not enc["t"].size:
            out[side.lower()] = math.nan
            continue
        sel = (enc["t"] >= t0_ns) & (enc["t"] <= t1_ns)
        te, ve = enc["t"][sel], enc["Vel_Estimate"][sel]
        idx = np.searchsorted(sp["t"], te, side="right") - 1
        ok = idx >= 0
        out[side.lower()] = _rms(ve[ok] - sp["Input_Vel"][idx[ok]])
    return out


def activity(cmd: dict[str, np.ndarray], dt_s: float) -> dict[str, float]:
    """Control effort, total variation and chattering of the commands."""
    if not cmd or cmd["v"].size < 3:
        return {
            "control_effort": math.nan,
            "tv_v": math.nan,
            "tv_omega": math.nan,
            "chattering_hz": math.nan,
        }
    v, w = cmd["v"], cmd["omega"]
    duration = max(len(v) * dt_s, dt_s)
    dw = np.diff(w)
    sign = np.sign(dw[np.abs(dw) > 1e-6])
    reversals = int(np.count_nonzero(np.diff(sign) != 0)) if sign.size > 1 else 0
    return {
        "control_effort": float(np.sum(v * v + w * w) * dt_s),
        "tv_v": float(np.sum(np.abs(np.diff(v)))),
        "tv_omega": float(np.sum(np.abs(dw))),
        "chattering_hz": reversals / duration,
    }


def summarize_bus(
    bus: BusSeries,
    trajectory: Trajectory,
    *,
    half_track_m: float,
    wheel_radius_m: float,
    period_s: float,
) -> dict[str, Any]:
    """Tracking and activity metrics of one run (see module doc)."""
    t0 = tracking_window(bus)
    out: dict[str, Any] = {"tracking_started": t0 is not None}
    nan = math.nan
    untracked = dict(
        rmse_xe_m=nan,
        rmse_ye_m=nan,
        rmse_phie_rad=nan,
        rmse_pos_m=nan,
        max_pos_err_m=nan,
        max_phie_rad=nan,
        samples=0,
    )
    if t0 is None:
        out.update(untracked)
        return out
    t1 = t0 + int(trajectory.duration_s * 1e9)
    last = last_tracking_ns(bus)
    if last is not None and last < t1:
        out["tracking_ended_early_s"] = (t1 - last) * 1e-9
        t1 = last
    e = tracking_errors(bus, trajectory, t0, t1)
    if not e or not e["x_e"].size:
        # no truth sample in the tracked window (e.g. a safe stop in the first tick): no figure
        out.update(untracked)
        return out
    pos = np.hypot(e["x_e"], e["y_e"])
    out.update(
        rmse_xe_m=_rms(e["x_e"]),
        rmse_ye_m=_rms(e["y_e"]),
        rmse_phie_rad=_rms(e["phi_e"]),
        rmse_pos_m=_rms(pos),
        max_pos_err_m=float(np.max(pos)),
        max_phie_rad=float(np.max(np.abs(e["phi_e"]))),
        final_pos_err_m=float(pos[-1]),
        samples=int(pos.size),
    )
    cmd = commands(bus, half_track_m, wheel_radius_m, t0, t1)
    out.update(activity(cmd, period_s))
    wt = wheel_tracking_rms(bus, t0, t1)
    out["wheel_speed_tracking_rms_revps"] = wt
    return out
