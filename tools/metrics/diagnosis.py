"""``fault_diagnosis`` of summary.json: what was injected and what the filter bank said, from the bus log.

* **injected**: the ``Bench_Fault_Event`` frames (ACTIVE at onset, CLEARED at the end; a fault
  never cleared lasts to the end of the log).  Each fault gets a scenario-style name
  (``flat-left``, ``bump-right``, ``slip``, ``torque-loss-left`` ...);
* **identified**: from the controller's ``Host_Diagnosis`` frames (every 100 ms): for each fault
  the bank has a hypothesis for, the hypothesis on top with probability >= ``confirm_p`` at the
  end of the fault's window (``none`` if the nominal one, or no hypothesis reaches ``confirm_p``);
* **detection_delay_s**: from the onset until the correct hypothesis *stays* on top with
  probability >= ``confirm_p`` to the end of the fault's window; ``None`` if it never does;
* **false_alarm_fraction**: the share of fault-free time (outside every fault window, and
  outside the ``recovery_s`` after a fault cleared) during which a fault hypothesis is on top.

For a run with several faults the top-level ``injected`` and ``identified`` join the names with
``+``, ``detection_delay_s`` is the largest delay (``None`` if any fault was missed), and
``faults`` lists each fault.  Pure functions of the decoded log (:class:`tools.metrics.tracking.BusSeries`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controller.diagnosis import HYPOTHESIS_NAMES
from dbc.codec import FaultSide, FaultState, FaultType, Hypothesis
from firmware_sim.faultspec import KINDS
from tools.metrics.tracking import BusSeries, read_bus_log

_KIND_OF_TYPE = {k.fault_type: k for k in KINDS.values()}
_SIDE_NAMES = {FaultSide.LEFT: "left", FaultSide.RIGHT: "right", FaultSide.BOTH: "both"}
_NOMINAL = int(Hypothesis.NOMINAL)
_TYPES = frozenset(int(v) for v in FaultType)
_SIDES = frozenset(int(v) for v in FaultSide)


@dataclass(frozen=True)
class FaultWindow:
    fault_id: int
    name: str
    diagnosable: bool
    onset_ns: int
    end_ns: int | None  # None: until the end of the log


def fault_name(fault_type: int, side: int) -> tuple[str, bool]:
    """Scenario-style name of a fault and whether the filter bank has a hypothesis for it."""
    info = _KIND_OF_TYPE.get(FaultType(fault_type)) if fault_type in _TYPES else None
    if info is None:
        return f"type-{fault_type}", False
    base = info.diagnosable or info.name
    side_name = _SIDE_NAMES.get(FaultSide(side)) if side in _SIDES else None
    if base == "slip":
        return "slip", side_name == "both"
    if side_name is None:
        return base, False
    name = f"{base}-{side_name}"
    return name, info.diagnosable is not None and name in HYPOTHESIS_NAMES.values()


def fault_windows(bus: BusSeries) -> list[FaultWindow]:
    """Every injected fault with its onset and end, from the Bench_Fault_Event frames."""
    ev = bus.get("Bench_Fault_Event")
    t = ev["t"]
    if not t.size:
        return []
    open_: dict[int, tuple[int, int, int]] = {}
    out: list[FaultWindow] = []
    for i in np.argsort(t, kind="stable"):
        fid = int(ev["Fault_Id"][i])
        state = int(ev["Fault_State"][i])
        if state == FaultState.ACTIVE:
            open_[fid] = (int(t[i]), int(ev["Fault_Type"][i]), int(ev["Side"][i]))
        elif state == FaultState.CLEARED and fid in open_:
            t0, ft, side = open_.pop(fid)
            name, diag = fault_name(ft, side)
            out.append(FaultWindow(fid, name, diag, t0, int(t[i])))
    for fid, (t0, ft, side) in open_.items():
        name, diag = fault_name(ft, side)
        out.append(FaultWindow(fid, name, diag, t0, None))
    return sorted(out, key=lambda w: (w.onset_ns, w.fault_id))


def fault_diagnosis(run_log: str | Path) -> dict[str, Any]:
    """``fault_diagnosis`` of the run logged in ``run_log`` (a recorder's or finalized MCAP)."""
    return diagnosis_summary(read_bus_log(run_log, ["Bench_Fault_Event", "Host_Diagnosis"]))


def diagnosis_summary(
    bus: BusSeries, *, confirm_p: float = 0.9, recovery_s: float = 5.0
) -> dict[str, Any]:
    """The ``fault_diagnosis`` block of summary.json (see the module docstring)."""
    windows = fault_windows(bus)
    diag = bus.get("Host_Diagnosis")
    t = diag["t"].astype(np.int64)
    hyp = np.asarray(diag.get("Hypothesis", np.zeros(0)), dtype=int)
    prob = np.asarray(diag.get("Probability", np.zeros(0)), dtype=float)
    names = {int(h): n for h, n in HYPOTHESIS_NAMES.items()}
    result: dict[str, Any] = {
        "injected": "+".join(w.name for w in windows) or "none",
        "identified": None,
        "detection_delay_s": None,
        "false_alarm_fraction": None,
        "samples": int(t.size),
        "faults": [],
    }
    if not t.size:
        return result
    end_of_log = int(t[-1]) + 1
    confirmed = prob >= confirm_p
    per_fault: list[dict[str, Any]] = []
    for w in windows:
        end = w.end_ns if w.end_ns is not None else end_of_log
        inside = (t >= w.onset_ns) & (t < end)
        item: dict[str, Any] = {
            "fault_id": w.fault_id,
            "name": w.name,
            "onset_s": w.onset_ns / 1e9,
            "end_s": None if w.end_ns is None else w.end_ns / 1e9,
            "diagnosable": w.diagnosable,
            "identified": None,
            "detection_delay_s": None,
        }
        idx = np.flatnonzero(inside)
        if idx.size:
            last = int(idx[-1])
            top = names.get(int(hyp[last]), "none") if confirmed[last] else "none"
            item["identified"] = top
            if w.diagnosable:
                ok = (hyp[idx] == _hyp_index(w.name)) & confirmed[idx]
                if ok[-1]:
                    # first sample of the final run of confirmed samples
                    bad = np.flatnonzero(~ok)
                    first = int(idx[bad[-1] + 1]) if bad.size else int(idx[0])
                    item["detection_delay_s"] = max(0.0, (int(t[first]) - w.onset_ns) / 1e9)
        per_fault.append(item)
    result["faults"] = per_fault
    # fault-free time: outside every window and its recovery period
    free = np.ones(t.size, dtype=bool)
    rec_ns = round(recovery_s * 1e9)
    for w in windows:
        end = w.end_ns if w.end_ns is not None else end_of_log
        free &= ~((t >= w.onset_ns) & (t < end + rec_ns))
    if free.any():
        result["false_alarm_fraction"] = float(np.mean(hyp[free] != _NOMINAL))
        result["fault_free_s"] = float(free.sum()) * _period_s(t)
    else:
        result["fault_free_s"] = 0.0
    diagnosable = [f for f in per_fault if f["diagnosable"]]
    if not windows:
        result["identified"] = _top_name(hyp[free], names) if free.any() else "none"
    else:
        result["identified"] = "+".join(str(f["identified"]) for f in per_fault)
    if diagnosable:
        delays = [f["detection_delay_s"] for f in diagnosable]
        result["detection_delay_s"] = None if any(d is None for d in delays) else max(delays)
    return result


def _hyp_index(name: str) -> int:
    for h, n in HYPOTHESIS_NAMES.items():
        if n == name:
            return int(h)
    return -1


def _top_name(hyp: np.ndarray, names: dict[int, str]) -> str:
    """The hypothesis most often on top (``none`` = nominal)."""
    if not hyp.size:
        return "none"
    values, counts = np.unique(hyp, return_counts=True)
    return names.get(int(values[int(np.argmax(counts))]), "none")


def _period_s(t: np.ndarray) -> float:
    if t.size < 2:
        return 0.0
    d = np.diff(t)
    return float(np.median(d)) / 1e9 if d.size else math.nan
