"""The figures a person reads: every controller told apart, labelled zooms, nothing on the data."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.figure import Figure

from tools.evaluation import figures

CONTROLLERS = ("robust", "adaptive", "resilient", "antifragile", "baseline")


def _series(k: int, n: int = 600) -> dict[str, np.ndarray]:
    """A run on a circle of 3 m: each controller with its own small offset."""
    t = np.linspace(0.0, 30.0, n)
    th = t / 30.0 * 2 * math.pi
    rx, ry = 3 * np.cos(th), 3 * np.sin(th)
    off = 0.004 * (k + 1) * (1 + 0.3 * np.sin(5 * th))
    x, y = rx + off * np.cos(th), ry + off * np.sin(th)
    v = np.full(n, 0.63)
    return {
        "t_s": t + 2.0,
        "t0_s": np.array([2.0]),
        "tau_s": t,
        "x": x,
        "y": y,
        "ref_x": rx,
        "ref_y": ry,
        "pos_err": np.hypot(x - rx, y - ry),
        "ref_t_s": t + 2.0,
        "cmd_t_s": t + 2.0,
        "twist_t_s": t + 2.0,
        "ref_v": v,
        "cmd_v": v + 0.001,
        "twist_v": v - 0.001,
        "ref_a": np.zeros(n),
        "ref_omega": v / 3,
        "cmd_omega": v / 3 + 0.002,
        "twist_w": v / 3 - 0.002,
        "ref_alpha": np.zeros(n),
        "x_e": x - rx,
        "y_e": y - ry,
        "phi_e": np.zeros(n),
    }


def _spectrum_cell(kappa: float, cls: str) -> dict[str, Any]:
    resp = [0.01 * (1 + f) ** (2 if cls == "fragile" else 1) for f in (0, 0.5, 1, 1.5, 2)]
    return {
        "kappa": kappa,
        "class": cls,
        "band": [kappa - 0.02, kappa + 0.02],
        "response": [resp],
        "stress": [0.0, 0.02, 0.04, 0.06, 0.08],
        "stress_unit": "m",
    }


@pytest.fixture
def campaign(tmp_path: Path) -> dict[str, Any]:
    return make_campaign(tmp_path)


def make_campaign(tmp_path: Path) -> dict[str, Any]:
    """results.json of five controllers fault-free, with their series, and a spectrum."""
    table: dict[str, Any] = {}
    for k, c in enumerate(CONTROLLERS):
        log = f"runs/fault-free/nominal/{c}/run.mcap"
        (tmp_path / log).parent.mkdir(parents=True)
        np.savez(tmp_path / Path(log).parent / "series.npz", **_series(k))
        table[c] = {"fault-free": {"log": log}}
    # the spectrum's worst case for the labels: a marker at the very top right, and one
    # in the robust band at the far left
    kappas = {"robust": 0.45, "adaptive": 0.0, "resilient": 0.01, "antifragile": 0.2}
    kappas["baseline"] = 0.14
    spectrum = {
        c: {
            f: _spectrum_cell(kappas[c], "fragile" if kappas[c] > 0.1 else "robust")
            for f in ("flat-right", "bump-right", "slip")
        }
        for c in CONTROLLERS
    }
    return {
        "meta": {
            "controllers": list(CONTROLLERS),
            "spectrum": {"factors": [0, 0.5, 1, 1.5, 2], "tolerance": 0.1, "replicates": 1},
        },
        "table": table,
        "spectrum": spectrum,
    }


@pytest.fixture
def drawn(monkeypatch: pytest.MonkeyPatch) -> dict[str, Figure]:
    """The figures as drawn, kept open (``_save`` still writes the PNG)."""
    kept: dict[str, Figure] = {}

    def save(fig: Figure, path: Path) -> Path:
        fig.canvas.draw()
        fig.savefig(path, dpi=40)
        kept[path.name] = fig
        return path

    monkeypatch.setattr(figures, "_save", save)
    yield kept
    plt.close("all")


def _data_axes(fig: Figure) -> list[Any]:
    return [a for a in fig.axes if a.lines or a.collections]


def _inside(ax: Any, artist: Any) -> bool:
    """Whether ``artist``'s drawn box overlaps the axes' data area."""
    renderer = ax.figure.canvas.get_renderer()
    return bool(artist.get_window_extent(renderer).overlaps(ax.get_window_extent(renderer)))


def test_fig9_has_one_row_per_controller_each_with_its_own_line(
    campaign: dict[str, Any], tmp_path: Path, drawn: dict[str, Figure]
) -> None:
    assert figures.fig_trajectories(campaign, tmp_path) is not None
    fig = drawn["fig09_trajectories.png"]
    titles = [a.get_title(loc="left") for a in fig.axes]
    for c in CONTROLLERS:
        assert sum(t.startswith(f"{c.upper()}:") for t in titles) == 1, titles
    # one overview and three zooms per controller, and the colour bar
    assert len(fig.axes) == 4 * len(CONTROLLERS) + 1
    zooms = [a for a in fig.axes if "error at t =" in a.get_title()]
    assert len(zooms) == 3 * len(CONTROLLERS)
    for row, c in enumerate(CONTROLLERS):
        colours = {line.get_color() for a in zooms[3 * row : 3 * row + 3] for line in a.lines}
        assert figures.COLORS[c] in colours
        others = {figures.COLORS[o] for o in CONTROLLERS if o != c}
        assert not colours & others, f"row {c} draws another controller"


def test_fig9_zoom_panels_are_labelled_and_titled(
    campaign: dict[str, Any], tmp_path: Path, drawn: dict[str, Figure]
) -> None:
    figures.fig_trajectories(campaign, tmp_path)
    zooms = [a for a in drawn["fig09_trajectories.png"].axes if "error at t =" in a.get_title()]
    for a in zooms:
        assert "(cm)" in a.get_xlabel() and "(cm)" in a.get_ylabel()
    firsts = [a.get_title() for a in zooms[:3]]
    assert [t[:2] for t in firsts] == ["b)", "c)", "d)"]


@pytest.mark.parametrize(
    ("fn", "name"),
    [
        (figures.fig_trajectories, "fig09_trajectories.png"),
        (figures.fig_antifragile_twist, "fig10_antifragile_twist.png"),
        (figures.fig_spectrum, "fig01_spectrum.png"),
    ],
)
def test_no_legend_sits_on_the_data(
    fn: Any, name: str, campaign: dict[str, Any], tmp_path: Path, drawn: dict[str, Figure]
) -> None:
    fn(campaign, tmp_path)
    fig = drawn[name]
    for ax in _data_axes(fig):
        leg = ax.get_legend()
        assert leg is None or not _inside(ax, leg), f"{name}: a legend on {ax.get_title()!r}"
    for leg in fig.legends:
        assert not any(_inside(ax, leg) for ax in _data_axes(fig)), f"{name}: figure legend"


def test_fig10_draws_the_commanded_line_over_the_reference(
    campaign: dict[str, Any], tmp_path: Path, drawn: dict[str, Figure]
) -> None:
    figures.fig_antifragile_twist(campaign, tmp_path)
    fig = drawn["fig10_antifragile_twist.png"]
    panels = [a for a in fig.axes if a.get_ylabel().startswith(("a)", "b)", "c)", "d)"))]
    assert len(panels) == 4
    for ax in panels:
        ref = max(ax.lines, key=lambda ln: ln.get_linewidth())  # the wide pale reference
        cmd = next(ln for ln in ax.lines if ln.get_color() == "#d62728")
        assert cmd.get_zorder() > ref.get_zorder()
        assert cmd.get_linewidth() < ref.get_linewidth()  # it shows inside the reference


def test_fig1_names_the_classes_in_the_margin_of_the_convexity_panel(
    campaign: dict[str, Any], tmp_path: Path, drawn: dict[str, Figure]
) -> None:
    figures.fig_spectrum(campaign, tmp_path)
    fig = drawn["fig01_spectrum.png"]
    kappa = next(a for a in fig.axes if a.get_ylabel().startswith("convexity"))
    texts = {t.get_text().replace("\n", " "): t for t in kappa.texts}
    band = next(t for s, t in texts.items() if s.startswith("robust band"))
    assert "|κ| ≤ 0.1" in band.get_text()
    fragile = next(t for s, t in texts.items() if s.startswith("fragile"))
    renderer = fig.canvas.get_renderer()
    data_area = kappa.get_window_extent(renderer)
    for t in (band, fragile):
        box = t.get_window_extent(renderer)
        assert box.x0 >= data_area.x1, f"{t.get_text()!r} is on the data"
    # the band's label is beside the band
    y0, y1 = kappa.transData.transform([(0, -0.1), (0, 0.1)])[:, 1]
    mid = (band.get_window_extent(renderer).y0 + band.get_window_extent(renderer).y1) / 2
    assert y0 <= mid <= y1
    others = [a for a in fig.axes if a is not kappa]
    assert not any("robust band" in t.get_text() for a in others for t in a.texts)
