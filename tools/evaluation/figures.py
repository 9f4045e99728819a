"""The evaluation's figures (PNG, matplotlib's Agg backend), from ``results.json`` and the runs.

Each figure function reads the ground-truth time series a run left next to its MCAP log
(``series.npz``, written by :func:`tools.evaluation.task.run_task`) and returns the PNG's path, or
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
import matplotlib.cm
import matplotlib.collections
import matplotlib.colors
import matplotlib.lines
import matplotlib.patches
import matplotlib.transforms

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


#: Fig. 9's zoom windows: this many metres either side of the spot.
FIG9_ZOOM_HALF_M = 0.10


def _zoom_spots(runs: Mapping[str, Mapping[str, np.ndarray]]) -> list[tuple[str, int]]:
    """Fig. 9's zoom spots (reference sample indices): the largest error of the best-tracking
    run, the tightest turn of the reference, and the end."""
    ref = next(iter(runs.values()))
    best = min(runs.values(), key=lambda s: float(np.mean(s["pos_err"] ** 2)))
    heading = np.unwrap(np.arctan2(np.gradient(ref["ref_y"]), np.gradient(ref["ref_x"])))
    step = np.hypot(np.gradient(ref["ref_x"]), np.gradient(ref["ref_y"]))
    curv = np.abs(np.gradient(heading)) / np.maximum(step, 1e-3)
    return [
        ("largest error of the best run", int(np.argmax(best["pos_err"]))),
        ("tightest turn", int(np.argmax(curv))),
        ("stop", ref["ref_x"].size - 1),
    ]


def fig_trajectories(results: Mapping[str, Any], out_dir: Path) -> Path | None:
    """Paper Fig. 9 as small multiples: one row per controller, fault-free.

    Left: the whole route, the controller's real path coloured by its position error (one
    colour scale for all rows).  Right: three zooms of 20 cm, the same spots in every row, with
    the reference, the real path and, at the spot's time, the reference point and the chair's
    point joined by the error vector.  Nothing is written on the data: names and figures are
    in the row labels and titles.
    """
    runs = {
        c: s
        for c in results["meta"]["controllers"]
        if (s := load_series(out_dir, _cell_log(results, c, "fault-free"))) is not None
    }
    if not runs:
        return None
    ref = next(iter(runs.values()))
    rx, ry = ref["ref_x"], ref["ref_y"]
    spots = _zoom_spots(runs)
    half = FIG9_ZOOM_HALF_M
    err_cm = {c: 100 * np.asarray(s["pos_err"], float) for c, s in runs.items()}
    top = max(float(np.max(e)) for e in err_cm.values())
    floor_cm = 0.1
    norm = matplotlib.colors.LogNorm(vmin=floor_cm, vmax=max(top, 1.0))
    cmap = plt.get_cmap("viridis")
    n = len(runs)
    fig = plt.figure(figsize=(17, 2.9 * n + 1.2))
    gs = fig.add_gridspec(n, 5, width_ratios=[6.2, 2.6, 2.6, 2.6, 0.15], wspace=0.35, hspace=0.45)
    overview = []
    for i, (c, s) in enumerate(runs.items()):
        ax = fig.add_subplot(gs[i, 0])
        overview.append(ax)
        ax.plot(rx, ry, color="0.6", lw=0.8, ls="--")
        pts = np.column_stack([s["x"], s["y"]])
        segs = np.stack([pts[:-1], pts[1:]], axis=1)
        lc = matplotlib.collections.LineCollection(list(segs), cmap=cmap, norm=norm, lw=1.6)
        lc.set_array(np.maximum(err_cm[c][1:], floor_cm))
        ax.add_collection(lc)
        ax.plot(rx[0], ry[0], "o", color="k", ms=5, mfc="white")
        ax.plot(rx[-1], ry[-1], "s", color="k", ms=5)
        for j, (_title, k) in enumerate(spots):
            ax.add_patch(
                matplotlib.patches.Rectangle(
                    (rx[k] - 3 * half, ry[k] - 3 * half), 6 * half, 6 * half, fill=False, lw=0.9
                )
            )
            if i == 0:
                ax.annotate(
                    "bcd"[j],
                    (rx[k] + 3 * half, ry[k] + 3 * half),
                    xytext=(3, 3),
                    textcoords="offset points",
                    fontsize=8,
                    fontweight="bold",
                )
        ax.set_aspect("equal")
        ax.autoscale_view()
        ax.tick_params(labelsize=7)
        ax.set_ylabel("y (m)", fontsize=8)
        rms = float(np.sqrt(np.mean(err_cm[c] ** 2)))
        ax.set_title(
            f"{LABELS.get(c, c)}: RMSE {rms:.1f} cm, max {float(np.max(err_cm[c])):.1f} cm",
            fontsize=10,
            loc="left",
            color=_color(c),
            fontweight="bold",
        )
        if i == n - 1:
            ax.set_xlabel("x (m)", fontsize=8)
        for j, (title, k) in enumerate(spots):
            a = fig.add_subplot(gs[i, 1 + j])
            cx, cy = rx[k], ry[k]
            a.plot(100 * (rx - cx), 100 * (ry - cy), "k--", lw=1.1)
            a.plot(100 * (s["x"] - cx), 100 * (s["y"] - cy), color=_color(c), lw=1.6)
            kk = min(k, s["x"].size - 1)
            ex, ey = 100 * (s["x"][kk] - cx), 100 * (s["y"][kk] - cy)
            a.plot([0.0, ex], [0.0, ey], color="k", lw=0.8)
            a.plot(0.0, 0.0, "o", color="k", ms=4)
            a.plot(ex, ey, "o", color=_color(c), ms=5, mec="k", mew=0.6)
            a.set_xlim(-100 * half, 100 * half)
            a.set_ylim(-100 * half, 100 * half)
            a.set_aspect("equal")
            a.tick_params(labelsize=7)
            a.grid(alpha=0.3)
            a.set_xlabel(f"x − {cx:.2f} m (cm)", fontsize=7)
            a.set_ylabel(f"y − {cy:.2f} m (cm)", fontsize=7)
            off = "" if max(abs(ex), abs(ey)) <= 100 * half else " (chair outside)"
            head = f"{'bcd'[j]}) {title}\n" if i == 0 else ""
            a.set_title(
                f"{head}error at t = {_route_time(s)[kk]:.1f} s: {math.hypot(ex, ey):.1f} cm{off}",
                fontsize=8,
            )
    cax = fig.add_subplot(gs[:, 4])
    fig.colorbar(
        matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap), cax=cax, label="position error (cm)"
    )
    fig.suptitle("Trajectory tracking, fault-free (Fig. 9): one row per controller", y=0.995)
    fig.text(
        0.1,
        0.985 - 0.02 * 5 / n,
        "a) the paper route, the real path (bench ground truth) coloured by its position error, "
        "dashed: the reference, ○ start, ■ stop, boxes: where b-d zoom (drawn 3× larger).\n"
        f"b-d) {200 * half:.0f} cm × {200 * half:.0f} cm around the same reference point in "
        "every row: dashed the reference, solid the real path; at that point's time the "
        "reference point (black) and the chair (colour), joined by the error.",
        fontsize=9,
        va="top",
    )
    fig.subplots_adjust(top=1.0 - 0.085 * 5 / n)
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
    fig = plt.figure(figsize=(11, 13))
    gs = fig.add_gridspec(8, 1, height_ratios=[1, 0.42] * 4, hspace=0.12)
    axes: list[Any] = []
    for i, (title, ref, cmd, real, _names) in enumerate(panels):
        ax = fig.add_subplot(gs[2 * i], sharex=axes[0] if axes else None)
        dx = fig.add_subplot(gs[2 * i + 1], sharex=ax)
        axes += [ax, dx]
        # the reference underneath, wide and pale, so that the commanded line stays visible
        # where the two agree; the commanded line on top of the real one
        ax.plot(tr, ref, color="0.72", lw=3.2, solid_capstyle="butt", zorder=1)
        ax.plot(tw, real, color="#1f77b4", lw=0.8, alpha=0.85, zorder=2)
        ax.plot(tc, cmd, color="#d62728", lw=0.7, zorder=3)
        ax.set_ylabel(title, fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelbottom=False)
        # below: what the eye cannot separate above, each line minus the reference
        dx.axhline(0.0, color="0.72", lw=2.0)
        dx.plot(tc, cmd - np.interp(tc, tr, ref), color="#d62728", lw=0.9)
        dx.plot(tw, real - np.interp(tw, tr, ref), color="#1f77b4", lw=0.6, alpha=0.85)
        dx.set_ylabel("− reference", fontsize=7)
        dx.tick_params(labelsize=7, labelbottom=i == len(panels) - 1)
        dx.grid(alpha=0.3)
    axes[-1].set_xlabel("route time (s)")
    handles = [
        matplotlib.lines.Line2D([], [], color="0.72", lw=3.2),
        matplotlib.lines.Line2D([], [], color="#d62728", lw=1.2),
        matplotlib.lines.Line2D([], [], color="#1f77b4", lw=1.2),
    ]
    fig.legend(
        handles,
        [
            "reference (v_d, av_d, ω_d, aω_d)",
            "commanded: setpoints sent (v_c ...)",
            "real: bench ground truth (v_r ...)",
        ],
        loc="upper center",
        bbox_to_anchor=(0.5, 0.962),
        ncol=3,
        fontsize=9,
        frameon=False,
    )
    fig.suptitle(
        "ANTIFRAGILE, fault-free (Fig. 10); accelerations by differences at 100 Hz", y=0.99
    )
    fig.subplots_adjust(top=0.925)
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
            )
    ax.set_xticks(range(len(faults)), faults)
    ax.set_xlim(-0.5, len(faults) - 0.5)
    ax.set_ylabel("convexity κ = H / E(paper amplitude)")
    # the classes named in the right margin, beside the band and the half-planes they name,
    # where no marker can fall
    lo, hi = ax.get_ylim()
    lo, hi = min(lo, -2 * tol), max(hi, 2 * tol)
    # each half-plane at least a quarter of the other, so that its two-line label clears
    # the band's (all markers on one side squeezed the other label onto it)
    lo, hi = min(lo, -0.3 * hi), max(hi, -0.3 * lo)
    ax.set_ylim(lo, hi)
    margin = matplotlib.transforms.blended_transform_factory(ax.transAxes, ax.transData)
    for y, va, text, cls in (
        ((tol + hi) / 2, "center", "fragile\n(convex error)", "fragile"),
        (0.0, "center", f"robust band\n|κ| ≤ {tol:g}", "robust"),
        ((lo - tol) / 2, "center", "antifragile\n(concave error)", "antifragile"),
    ):
        ax.text(
            1.01,
            y,
            text,
            transform=margin,
            ha="left",
            va=va,
            color=_CLASS_COLORS[cls] if cls != "robust" else "k",
            fontsize=8,
        )
    ax.grid(alpha=0.3)
    handles = [
        matplotlib.lines.Line2D([], [], color=_color(c), marker="o", lw=1.2, ms=5) for c in ctrls
    ]
    names = [LABELS.get(c, c) for c in ctrls]
    for cls, colour in _CLASS_COLORS.items():
        handles.append(
            matplotlib.lines.Line2D(
                [], [], ls="none", marker="o", ms=7, mfc="white", mec=colour, mew=2
            )
        )
        names.append(f"ring: {cls}")
    ax.legend(
        handles,
        names,
        fontsize=7,
        ncol=len(handles),
        loc="upper center",
        bbox_to_anchor=(0.5, -0.08),
        frameon=False,
    )
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
