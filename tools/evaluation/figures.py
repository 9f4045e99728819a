"""The evaluation's figures (PNG, matplotlib's Agg backend), from ``results.json`` and the runs.

Each figure function reads the ground-truth time series a run left next to its MCAP log
(``series.npz``, written by :func:`tools.evaluation.campaign.run_task`) and returns the PNG's path, or
None when the campaign did not include the runs it needs.  :func:`make_all` makes every
figure it can:

==============================  ==========================================================
``fig09_trajectories.png``      every controller's path against the reference (paper Fig. 9)
``fig10_antifragile_twist.png`` ANTIFRAGILE: reference, commanded and real v, a, omega,
                                alpha (Fig. 10)
``fig11_antifragile_errors.png`` ANTIFRAGILE: x_e, y_e, phi_e over time (Fig. 11)
``fig12_baseline_faults.png``   BASELINE's path under each fault, and the errors (Fig. 12)
``fig13_cascaded_error.png``    every controller's Euclidean error, cascaded faults (Fig. 13)
``fig01_spectrum.png``          the measured fragility-robustness-antifragility spectrum
``exposure.png``                error on each of repeated exposures to the same fault
``montecarlo.png``              Monte-Carlo mean, 95 % interval and worst case per cell
==============================  ==========================================================
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.patches

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from tools.evaluation.results import spectrum_view

log = logging.getLogger(__name__)

#: One colour per controller, the paper's where it names them (Fig. 13).
COLORS = {
    "antifragile": "#d62728",
    "robust": "#2ca02c",
    "resilient": "#1f77b4",
    "adaptive": "#ff7f0e",
    "baseline": "#7f7f7f",
}
LABELS = {c: c.upper() for c in COLORS}
DPI = 110


def _color(c: str) -> str:
    return COLORS.get(c, "#9467bd")


def load_series(out_dir: Path, log: str | None) -> dict[str, np.ndarray] | None:
    """The time series of the run whose log is ``log`` (relative to ``out_dir``)."""
    if not log:
        return None
    path = out_dir / Path(log).parent / "series.npz"
    if not path.exists():
        return None
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    return data if "x" in data else None


#: The fault setting of the figures being made (:func:`make_all`), printed under each one.
_setting_label = ""


def _save(fig: Figure, path: Path) -> Path:
    if _setting_label:
        fig.text(0.01, -0.01, f"fault setting {_setting_label}", fontsize=7, va="top")
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return path


def _cell_log(results: Mapping[str, Any], controller: str, scenario: str) -> str | None:
    cell = results.get("table", {}).get(controller, {}).get(scenario) or {}
    log: str | None = cell.get("log")
    return log


def _route_time(s: Mapping[str, np.ndarray], key: str = "t_s") -> np.ndarray:
    return np.asarray(s[key]) - float(s["t0_s"][0])


# ------------------------------------------------------------------- Fig. 9


def fig_trajectories(results: Mapping[str, Any], out_dir: Path) -> Path | None:
    """Paper Fig. 9: the reference and every controller's real path, fault-free."""
    runs = {
        c: s
        for c in results["meta"]["controllers"]
        if (s := load_series(out_dir, _cell_log(results, c, "fault-free"))) is not None
    }
    if not runs:
        return None
    ref = next(iter(runs.values()))
    fig = plt.figure(figsize=(14, 10))
    gs = fig.add_gridspec(2, 3, height_ratios=[1.25, 1])
    ax = fig.add_subplot(gs[0, :])
    ax.plot(ref["ref_x"], ref["ref_y"], "k--", lw=1.2, label="reference")
    for i, (label, marker) in enumerate((("START", "o"), ("STOP", "s"))):
        p = (ref["ref_x"][-i], ref["ref_y"][-i])
        ax.plot(*p, "k" + marker)
        ax.annotate(label, p, xytext=(4, 4), textcoords="offset points")
    for c, s in runs.items():
        rms = float(np.sqrt(np.mean(s["pos_err"] ** 2)))
        label = (
            f"{LABELS.get(c, c)} (RMSE {100 * rms:.1f} cm, max {100 * s['pos_err'].max():.1f} cm)"
        )
        ax.plot(s["x"], s["y"], color=_color(c), lw=1.0, label=label)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("a) the paper route, every controller's real path (bench ground truth)")
    ax.legend(loc="upper left", fontsize=8)
    # zooms where it matters: the largest error of the best-tracking run, the tightest turn
    # of the reference, and the end
    best = min(runs.values(), key=lambda s: float(np.mean(s["pos_err"] ** 2)))
    heading = np.unwrap(np.arctan2(np.gradient(ref["ref_y"]), np.gradient(ref["ref_x"])))
    step = np.hypot(np.gradient(ref["ref_x"]), np.gradient(ref["ref_y"]))
    curv = np.abs(np.gradient(heading)) / np.maximum(step, 1e-3)
    spots = [
        ("largest error of the best run", int(np.argmax(best["pos_err"]))),
        ("tightest turn", int(np.argmax(curv))),
        ("STOP", ref["ref_x"].size - 1),
    ]
    half = 0.15
    for j, (title, k) in enumerate(spots):
        a = fig.add_subplot(gs[1, j])
        cx, cy = ref["ref_x"][k], ref["ref_y"][k]
        a.plot(ref["ref_x"], ref["ref_y"], "k--", lw=1.2)
        for c, s in runs.items():
            a.plot(s["x"], s["y"], color=_color(c), lw=1.2)
        a.set_xlim(cx - half, cx + half)
        a.set_ylim(cy - half, cy + half)
        a.set_aspect("equal")
        a.tick_params(labelsize=7)
        a.set_title(f"{'bcd'[j]}) zoom 30 cm × 30 cm: {title}", fontsize=9)
        ax.add_patch(
            matplotlib.patches.Rectangle(
                (cx - half, cy - half), 2 * half, 2 * half, fill=False, lw=0.8
            )
        )
        ax.annotate("bcd"[j], (cx + half, cy + half), fontsize=8)
    fig.suptitle("Trajectory tracking, fault-free (Fig. 9)")
    return _save(fig, out_dir / "fig09_trajectories.png")


# ------------------------------------------------------------------ Fig. 10/11


def fig_antifragile_twist(results: Mapping[str, Any], out_dir: Path) -> Path | None:
    """Paper Fig. 10: reference, commanded and real velocities and accelerations."""
    s = load_series(out_dir, _cell_log(results, "antifragile", "fault-free"))
    if s is None or s["ref_t_s"].size < 3 or s["twist_t_s"].size < 3:
        return None
    tr, tc, tw = (
        _route_time(s, "ref_t_s"),
        _route_time(s, "cmd_t_s"),
        _route_time(s, "twist_t_s"),
    )
    panels = [
        ("a) linear velocity (m/s)", s["ref_v"], s["cmd_v"], s["twist_v"], ("v_d", "v_c", "v_r")),
        (
            "b) linear acceleration (m/s²)",
            s["ref_a"],
            np.gradient(s["cmd_v"], tc),
            np.gradient(s["twist_v"], tw),
            ("av_d", "av_c", "av_r"),
        ),
        (
            "c) angular velocity (rad/s)",
            s["ref_omega"],
            s["cmd_omega"],
            s["twist_w"],
            ("ω_d", "ω_c", "ω_r"),
        ),
        (
            "d) angular acceleration (rad/s²)",
            s["ref_alpha"],
            np.gradient(s["cmd_omega"], tc),
            np.gradient(s["twist_w"], tw),
            ("aω_d", "aω_c", "aω_r"),
        ),
    ]
    fig, axes = plt.subplots(4, 1, figsize=(11, 10), sharex=True)
    for ax, (title, ref, cmd, real, names) in zip(axes, panels, strict=True):
        ax.plot(tc, cmd, color="#d62728", lw=0.8, label=f"{names[1]} commanded")
        ax.plot(tw, real, color="#1f77b4", lw=0.8, alpha=0.8, label=f"{names[2]} real")
        ax.plot(tr, ref, "k--", lw=1.0, label=f"{names[0]} reference")
        ax.set_ylabel(title, fontsize=8)
        ax.legend(loc="upper right", fontsize=7, ncol=3)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("route time (s)")
    fig.suptitle(
        "ANTIFRAGILE, fault-free (Fig. 10): commanded = setpoints sent, real = bench ground "
        "truth; accelerations by differences at 100 Hz"
    )
    return _save(fig, out_dir / "fig10_antifragile_twist.png")


def fig_antifragile_errors(results: Mapping[str, Any], out_dir: Path) -> Path | None:
    """Paper Fig. 11: ANTIFRAGILE's x_e, y_e, phi_e over time (ground truth), fault-free."""
    s = load_series(out_dir, _cell_log(results, "antifragile", "fault-free"))
    if s is None:
        return None
    t = s["tau_s"]
    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for ax, key, scale, unit in (
        (axes[0], "x_e", 100.0, "x_e (cm)"),
        (axes[1], "y_e", 100.0, "y_e (cm)"),
        (axes[2], "phi_e", 180.0 / math.pi, "φ_e (deg)"),
    ):
        v = s[key] * scale
        ax.plot(t, v, color="#d62728", lw=0.8)
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
        ax.set_title(
            f"max |{key}| = {np.max(np.abs(v)):.2f}, RMSE {np.sqrt(np.mean(v * v)):.2f}",
            fontsize=8,
            loc="right",
        )
    axes[-1].set_xlabel("route time (s)")
    fig.suptitle("ANTIFRAGILE, fault-free: tracking errors against ground truth (Fig. 11)")
    return _save(fig, out_dir / "fig11_antifragile_errors.png")


# ------------------------------------------------------------------- Fig. 12


FIG12_FAULTS = ("bump-left", "bump-right", "flat-left", "flat-right")
#: Fig. 12 draws the real path with its deviation from the reference magnified this much.
FIG12_MAGNIFY = 25.0


def fig_baseline_faults(results: Mapping[str, Any], out_dir: Path) -> Path | None:
    """Paper Fig. 12: BASELINE's path under each fault, and its RMSEs per fault."""
    runs = {
        f: s
        for f in FIG12_FAULTS
        if (s := load_series(out_dir, _cell_log(results, "baseline", f))) is not None
    }
    if not runs:
        return None
    fig = plt.figure(figsize=(14, 8))
    gs = fig.add_gridspec(2, 3)
    for i, (f, s) in enumerate(runs.items()):
        ax = fig.add_subplot(gs[i // 2, i % 2])
        # the deviation from the reference is centimetres on a 25 m route: magnified
        mx = s["ref_x"] + FIG12_MAGNIFY * (s["x"] - s["ref_x"])
        my = s["ref_y"] + FIG12_MAGNIFY * (s["y"] - s["ref_y"])
        ax.plot(s["ref_x"], s["ref_y"], "k--", lw=0.9, label="reference")
        cell = results["table"]["baseline"][f]
        onset = next(
            (w["onset_s"] for w in (cell.get("fault_diagnosis") or {}).get("faults", [])), None
        )
        k = int(np.searchsorted(s["t_s"], onset)) if onset is not None else mx.size
        ax.plot(mx[: k + 1], my[: k + 1], color=_color("baseline"), lw=1.0, label="BASELINE")
        ax.plot(mx[k:], my[k:], color="#d62728", lw=1.0, label="BASELINE, fault active")
        if k < mx.size:
            ax.plot(mx[k], my[k], "v", color="#d62728", ms=8, label="fault onset")
        ax.set_aspect("equal")
        ax.set_title(f"{'abcd'[i]}) {f}", fontsize=9)
        ax.tick_params(labelsize=7)
        if i == 0:
            ax.legend(fontsize=7)
    ax = fig.add_subplot(gs[:, 2])
    comps = (
        ("rmse_xe_m", "x_e (cm)", 100.0),
        ("rmse_ye_m", "y_e (cm)", 100.0),
        ("rmse_phie_rad", "φ_e (deg)", 180 / math.pi),
    )
    names = [*runs, "average"]
    width = 0.8 / len(names)
    for j, name in enumerate(names):
        vals = []
        for key, _, scale in comps:
            if name == "average":
                v = [results["table"]["baseline"][f].get(key) for f in runs]
                vals.append(scale * float(np.mean([x for x in v if x is not None])))
            else:
                x = results["table"]["baseline"][name].get(key)
                vals.append(scale * (x if x is not None else math.nan))
        ax.bar(np.arange(len(comps)) + j * width, vals, width, label=name)
    ax.set_xticks(np.arange(len(comps)) + 0.4 - width / 2, [c[1] for c in comps])
    ax.set_ylabel("RMSE")
    ax.set_title("e) BASELINE RMSE per fault and average")
    ax.legend(fontsize=7)
    fig.suptitle(
        "BASELINE (Kanayama, no adaptation) under each fault from t = 20 s (Fig. 12); "
        f"paths: deviation from the reference magnified {FIG12_MAGNIFY:g}x"
    )
    return _save(fig, out_dir / "fig12_baseline_faults.png")


# ------------------------------------------------------------------- Fig. 13


def _shade_windows(
    ax: Any, windows: list[dict[str, Any]] | None, labels: list[str] | None = None
) -> None:
    for i, w in enumerate(windows or []):
        end = w.get("end_s")
        ax.axvspan(
            w["onset_s"],
            end if end is not None else ax.get_xlim()[1],
            color=f"C{i % 10}",
            alpha=0.08,
        )
        if labels and i < len(labels):
            ax.text(
                w["onset_s"],
                1.0,
                f" {labels[i]}",
                transform=ax.get_xaxis_transform(),
                fontsize=7,
                va="top",
            )


def fig_cascaded(results: Mapping[str, Any], out_dir: Path) -> Path | None:
    """Paper Fig. 13: Euclidean error over (simulation) time of every controller, cascaded."""
    casc = results.get("cascaded") or {}
    runs = {
        c: s for c, cell in casc.items() if (s := load_series(out_dir, cell.get("log"))) is not None
    }
    if not runs:
        return None
    fig, ax = plt.subplots(figsize=(11, 5))
    for c, s in runs.items():
        ax.plot(s["t_s"], 100 * s["pos_err"], color=_color(c), lw=0.9, label=LABELS.get(c, c))
    ax.set_yscale("log")
    ax.set_ylim(bottom=0.03)
    ax.set_xlabel("simulation time (s)")
    ax.set_ylabel("Euclidean position error (cm, log)")
    first = next(iter(casc.values()))
    windows = first.get("windows") or []
    names = ["slip", "flat left", "bump right"]
    _shade_windows(ax, windows, names)
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3, which="both")
    ax.set_title(
        "Cascaded faults (Fig. 13): slip 10 s, flat tire 28 s, bump 46 s, fault-free from 62 s"
    )
    return _save(fig, out_dir / "fig13_cascaded_error.png")


# -------------------------------------------------------------------- spectrum


_CLASS_COLORS = {"fragile": "#d62728", "robust": "#7f7f7f", "antifragile": "#2ca02c"}


def fig_spectrum(results: Mapping[str, Any], out_dir: Path) -> Path | None:
    """The measured spectrum (the paper's hypothetical Fig. 1): responses and convexity."""
    spec = spectrum_view(results)
    if not spec or not spec.get("controllers"):
        return None
    ctrls = list(spec["controllers"])
    faults = list(next(iter(spec["controllers"].values())))
    tol = float(spec["tolerance"])
    fig = plt.figure(figsize=(3.4 * len(faults), 8.5))
    gs = fig.add_gridspec(2, len(faults), height_ratios=[1, 1.1])
    for j, fault in enumerate(faults):
        ax = fig.add_subplot(gs[0, j])
        for c in ctrls:
            cell = spec["controllers"][c][fault]
            resp = np.array(
                [[math.nan if v is None else v for v in row] for row in cell["response"]], float
            )
            x = np.asarray(cell["stress"] or spec["factors"], float)
            scale = 100.0 if cell.get("stress_unit") == "m" and cell["stress"] else 1.0
            ax.plot(
                x * scale,
                100 * resp[0],
                "o-",
                color=_color(c),
                lw=1.2,
                ms=3,
                label=LABELS.get(c, c),
            )
            if resp.shape[0] > 1:
                ax.fill_between(
                    x * scale,
                    100 * np.nanmin(resp, 0),
                    100 * np.nanmax(resp, 0),
                    color=_color(c),
                    alpha=0.15,
                )
        unit = "cm" if spec["controllers"][ctrls[0]][fault].get("stress_unit") == "m" else "ratio"
        what = {"flat": "radius lost", "bump": "eccentricity", "slip": "slip ratio"}
        ax.set_xlabel(f"{what.get(fault.split('-')[0], 'amplitude')} ({unit})", fontsize=8)
        ax.set_ylabel("position RMSE (cm)" if j == 0 else "")
        ax.set_title(fault, fontsize=9)
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.tick_params(labelsize=7)
        if j == 0:
            ax.legend(fontsize=7)
    ax = fig.add_subplot(gs[1, :])
    ax.axhspan(-tol, tol, color="#7f7f7f", alpha=0.15)
    ax.axhline(0.0, color="k", lw=0.6)
    width = 0.8 / max(1, len(ctrls))
    for i, c in enumerate(ctrls):
        for j, fault in enumerate(faults):
            cell = spec["controllers"][c][fault]
            k = cell.get("kappa")
            if k is None:
                continue
            xpos = j + (i - (len(ctrls) - 1) / 2) * width
            band = cell.get("band")
            if band:
                ax.errorbar(
                    xpos,
                    k,
                    yerr=[[k - band[0]], [band[1] - k]],
                    fmt="none",
                    ecolor=_color(c),
                    capsize=3,
                )
            ax.plot(
                xpos,
                k,
                "o",
                color=_color(c),
                ms=7,
                mec=_CLASS_COLORS.get(cell["class"], "k"),
                mew=2,
                label=LABELS.get(c, c) if j == 0 else None,
            )
            ax.annotate(
                cell["class"][0].upper(),
                (xpos, k),
                xytext=(3, 3),
                textcoords="offset points",
                fontsize=7,
            )
    ax.set_xticks(range(len(faults)), faults)
    ax.set_ylabel("convexity κ = H / E(paper amplitude)")
    ax.text(
        1.0,
        0.98,
        "fragile (convex error)",
        transform=ax.transAxes,
        ha="right",
        va="top",
        color=_CLASS_COLORS["fragile"],
        fontsize=8,
    )
    ax.text(
        1.0,
        0.02,
        "antifragile (concave error)",
        transform=ax.transAxes,
        ha="right",
        va="bottom",
        color=_CLASS_COLORS["antifragile"],
        fontsize=8,
    )
    ax.text(
        0.0,
        0.5,
        f" robust band |κ| ≤ {tol:g}",
        transform=ax.get_yaxis_transform(),
        fontsize=8,
        va="center",
    )
    ax.legend(fontsize=7, ncol=len(ctrls), loc="upper center", bbox_to_anchor=(0.5, -0.08))
    ax.grid(alpha=0.3)
    fig.suptitle(
        "Fragility-robustness-antifragility spectrum, measured (the paper's Fig. 1 from data)\n"
        "top: error against fault amplitude (band: replicates); bottom: convexity, 95 % band"
    )
    return _save(fig, out_dir / "fig01_spectrum.png")


# -------------------------------------------------------------------- exposure


def fig_exposure(results: Mapping[str, Any], out_dir: Path) -> Path | None:
    """Error on each exposure to the same fault: repeated run against first-time exposure."""
    exp = results.get("exposure")
    if not exp:
        return None
    ctrls = list(exp)
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(11, 8))
    for c in ctrls:
        s = load_series(out_dir, exp[c].get("log"))
        if s is not None:
            ax.plot(s["t_s"], 100 * s["pos_err"], color=_color(c), lw=0.8, label=LABELS.get(c, c))
    rows0 = exp[ctrls[0]]["exposures"]
    _shade_windows(ax, rows0, [f"exposure {r['exposure']}" for r in rows0])
    ax.set_yscale("log")
    ax.set_xlabel("simulation time (s)")
    ax.set_ylabel("position error (cm, log)")
    ax.legend(fontsize=7, ncol=len(ctrls))
    ax.grid(alpha=0.3, which="both")
    ax.set_title("repeated right flat tire (0.30 -> 0.26 m): 12-24 s, 36-48 s, 60-72 s")
    n = max(len(exp[c]["exposures"]) for c in ctrls)
    width = 0.8 / len(ctrls)
    for i, c in enumerate(ctrls):
        rows = exp[c]["exposures"]
        x = np.arange(len(rows)) + i * width
        rep = [100 * (r["rmse_pos_m"] or math.nan) for r in rows]
        first = [100 * (r["rmse_pos_m_first_time"] or math.nan) for r in rows]
        bx.bar(x, rep, width * 0.9, color=_color(c), label=f"{LABELS.get(c, c)} repeated")
        bx.plot(x, first, "k_", ms=14, mew=2)
    bx.plot([], [], "k_", ms=14, mew=2, label="same window, first-time exposure")
    bx.set_xticks(np.arange(n) + 0.4 - width / 2, [f"exposure {k + 1}" for k in range(n)])
    bx.set_ylabel("position RMSE in the window (cm)")
    bx.set_yscale("log")
    bx.legend(fontsize=7, ncol=3)
    bx.set_title("gain from exposure = first-time RMSE - repeated RMSE (bar below the dash)")
    fig.tight_layout()
    return _save(fig, out_dir / "exposure.png")


# ------------------------------------------------------------------ Monte-Carlo


def fig_montecarlo(results: Mapping[str, Any], out_dir: Path) -> Path | None:
    """Per cell: nominal run, Monte-Carlo mean with 95 % interval, and worst case."""
    mc = results.get("monte_carlo")
    if not mc:
        return None
    table = mc["table"]
    ctrls = list(table)
    scen = results["meta"]["scenarios"]
    fig, ax = plt.subplots(figsize=(2.2 * len(scen) + 2, 5))
    width = 0.8 / len(ctrls)
    for i, c in enumerate(ctrls):
        for j, s in enumerate(scen):
            st = table[c].get(s, {}).get("rmse_pos_m") or {}
            x = j + (i - (len(ctrls) - 1) / 2) * width
            if st.get("mean") is None:
                continue
            m = 100 * st["mean"]
            if st.get("ci95"):
                lo, hi = (100 * v for v in st["ci95"])
                ax.errorbar(
                    x,
                    m,
                    yerr=[[m - lo], [hi - m]],
                    fmt="o",
                    color=_color(c),
                    capsize=3,
                    ms=4,
                    label=LABELS.get(c, c) if j == 0 else None,
                )
            ax.plot(x, 100 * st["worst"], "x", color=_color(c))
            nominal = results["table"].get(c, {}).get(s, {}).get("rmse_pos_m")
            if nominal is not None:
                ax.plot(x, 100 * nominal, "s", mfc="none", color=_color(c), ms=5)
    ax.plot([], [], "x", color="k", label="worst case")
    ax.plot([], [], "s", mfc="none", color="k", label="nominal run")
    ax.set_xticks(range(len(scen)), scen)
    ax.set_yscale("log")
    ax.set_ylabel("position RMSE (cm, log)")
    ax.set_title(f"Monte-Carlo, {mc['replicates']} replicates per cell: mean and 95 % interval")
    ax.legend(fontsize=7, ncol=3)
    ax.grid(alpha=0.3, which="both")
    return _save(fig, out_dir / "montecarlo.png")


FIGURES = (
    fig_trajectories,
    fig_antifragile_twist,
    fig_antifragile_errors,
    fig_baseline_faults,
    fig_cascaded,
    fig_spectrum,
    fig_exposure,
    fig_montecarlo,
)


def make_all(results: Mapping[str, Any], out_dir: Path) -> list[str]:
    """Every figure the campaign has data for; returns the file names written."""
    global _setting_label
    _setting_label = results.get("meta", {}).get("setting_label", "")
    made = []
    for fn in FIGURES:
        try:
            path = fn(results, out_dir)
        except Exception:  # a figure must never cost the campaign its results
            log.exception(
                "figure %s failed; results.json and the report are still written", fn.__name__
            )
            plt.close("all")
            continue
        if path is not None:
            made.append(path.name)
    return made
