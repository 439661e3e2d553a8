"""Figures 4–10 of Li et al. 2024 from :func:`eval.paper.run_experiments` (matplotlib, Agg).

Maps are filled tricontours over the target plane (X, Y in mm, reference frame; Y points down
as in the images), the targets marked as dots. Histograms are normalized (density) with a
Gaussian fitted by ``scipy.stats.norm.fit``. Every PNG is written atomically.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.colors import TwoSlopeNorm
from matplotlib.ticker import MaxNLocator
from matplotlib.tri import Triangulation
from scipy.stats import norm

from eval.core.figures import new_figure, save_figure
from eval.core.results import method_label

AXIS_NAMES = {"dX": "dX", "dY": "dY", "dZ": "dZ", "dP": "dP"}
FIGURE_FILES = {
    "figure4": "figure4_gap.png", "figure5": "figure5_su_1m.png", "figure6": "figure6_su_2m.png",
    "figure7": "figure7_noise_maps.png", "figure8": "figure8_noise_hist.png",
    "figure9": "figure9_index_maps.png", "figure10": "figure10_index_hist.png",
    "figure11": "figure11_index_profile.png",
}


def _components(errors: np.ndarray) -> dict[str, np.ndarray]:
    return {"dX": errors[..., 0], "dY": errors[..., 1], "dZ": errors[..., 2],
            "dP": np.linalg.norm(errors, axis=-1)}


def _plane_map(fig, ax, targets, values, title, label, signed=True, lines=(), n_levels=21,
               cmap=None, highlight=None, highlight_label=None):
    """Filled tricontour of ``values`` over the targets' (X, Y) with a colorbar in mm."""
    x, y = targets[:, 0], targets[:, 1]
    ok = np.isfinite(values)
    tri = Triangulation(x[ok], y[ok])
    v = values[ok]
    norm_ = None
    if signed:
        # diverging colours centred on zero; the range follows the data (one-signed data such
        # as Su's dZ does not waste half of the colour bar)
        limit = float(np.max(np.abs(v))) or 1e-12
        lo, hi = min(float(v.min()), -0.02 * limit), max(float(v.max()), 0.02 * limit)
        levels = MaxNLocator(n_levels, symmetric=False).tick_values(lo, hi)
        levels = levels[(levels > lo) | (np.arange(levels.size) == 0)]
        levels = np.unique(np.r_[levels, 0.0])
        norm_ = TwoSlopeNorm(vcenter=0.0, vmin=levels[0], vmax=levels[-1])
        cmap = cmap or "RdBu_r"
    else:
        top = float(np.max(v)) or 1e-12
        levels = MaxNLocator(n_levels).tick_values(0.0, top)
        cmap = cmap or "viridis"
    filled = ax.tricontourf(tri, v, levels=levels, cmap=cmap, norm=norm_, extend="neither")
    bar = fig.colorbar(filled, ax=ax, shrink=0.9)
    bar.set_label(label)
    ax.plot(x, y, ".", color="k", markersize=1.6, alpha=0.6, label="targets")
    drawn = [lv for lv in lines if v.min() < lv < v.max()]
    if drawn:
        contour = ax.tricontour(tri, v, levels=sorted(drawn), colors="k", linewidths=1.2)
        ax.clabel(contour, fmt=lambda lv: f"{lv:+g} mm" if signed else f"{lv:g} mm",
                  fontsize=8)
    if highlight is not None and np.any(highlight):
        ax.plot(x[highlight], y[highlight], "o", mfc="none", mec="red", markersize=6,
                label=highlight_label)
        ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
    ax.set_aspect("equal")
    ax.invert_yaxis()  # OpenCV frame: y points down, as in the images
    ax.set_xlabel("X [mm]")
    ax.set_ylabel("Y [mm] (down)")
    ax.set_title(title, fontsize=10)


def figure4_gap(results) -> Figure:
    gap = results["gap"]
    stats = gap["stats"]
    fig = new_figure(7.2, 6.2)
    ax = fig.add_subplot()
    intersect = gap["gap"] <= stats["threshold_mm"]
    _plane_map(fig, ax, gap["targets"], gap["gap"],
               f"Figure 4 — gap between rays O_L A1 and O_R B1, Z = {gap['z_mm']:g} mm\n"
               f"{100 * stats['share_above_threshold']:.1f} % of {stats['n']} targets with gap "
               f"> {stats['threshold_mm']:g} mm (black line: 0.6 mm)",
               "common-perpendicular length [mm]", signed=False, lines=(0.6,), n_levels=26,
               highlight=intersect,
               highlight_label=f"gap <= {stats['threshold_mm']:g} mm (rays intersect)")
    return fig


def figure_su_ideal(results, z: float, number: int) -> Figure:
    entry = results["ideal"][z]
    comps = _components(entry["errors"]["su"])
    fig = new_figure(11.5, 10.0)
    axes = fig.subplots(2, 2)
    for ax, name in zip(axes.ravel(), ("dX", "dY", "dZ", "dP")):
        signed = name != "dP"
        st = entry["stats"]["su"].component(name)
        _plane_map(fig, ax, entry["targets"], comps[name],
                   f"{name} (max |{name}| = {st.max_abs_mm:.4g} mm)", f"{name} [mm]",
                   signed=signed, lines=(-1.0, 1.0) if signed else (1.0,))
    fig.suptitle(f"Figure {number} — Su's method, ideal conditions, Z = {z:g} mm "
                 "(measured − true; black lines: ±1 mm)")
    return fig


def figure_maps(errors_by_method: dict, targets, trial: int, title: str) -> Figure:
    methods = list(errors_by_method)
    fig = new_figure(15.0, 4.6 * len(methods))
    axes = np.atleast_2d(fig.subplots(len(methods), 3))
    for row, method in enumerate(methods):
        comps = _components(errors_by_method[method][trial])
        for col, name in enumerate(("dX", "dY", "dZ")):
            values = comps[name]
            _plane_map(fig, axes[row, col], targets, values,
                       f"{method_label(method)}\n{name}, max |{name}| = "
                       f"{np.nanmax(np.abs(values)):.3g} mm", f"{name} [mm]", signed=True,
                       lines=(-1.0, 1.0))
    fig.suptitle(title)
    return fig


def _hist_panel(ax, values, label, color, reference=None):
    values = values[np.isfinite(values)]
    mu, sigma = norm.fit(values)
    lo, hi = np.percentile(values, [0.05, 99.95])
    if reference is not None:
        lo = min(lo, reference[0] - 4 * reference[1])
        hi = max(hi, reference[0] + 4 * reference[1])
    ax.hist(values, bins=80, range=(lo, hi), density=True, color=color, alpha=0.55,
            label=f"{label} (n = {values.size})")
    grid = np.linspace(lo, hi, 400)
    ax.plot(grid, norm.pdf(grid, mu, sigma), color="k", lw=1.6,
            label=f"Gaussian fit: μ = {mu:+.3f} mm, σ = {sigma:.3f} mm")
    if reference is not None:
        ax.plot(grid, norm.pdf(grid, *reference), color="0.4", lw=1.3, ls="--",
                label=f"no index deviation: μ = {reference[0]:+.3f} mm, σ = {reference[1]:.3f} mm")
    ax.axvline(0.0, color="0.6", lw=0.8)
    ax.set_ylabel("probability density [1/mm]")
    ax.legend(fontsize=7.5, loc="upper left")
    return mu, sigma


def figure_hist(errors_by_method: dict, title: str, reference: dict | None = None) -> Figure:
    methods = list(errors_by_method)
    fig = new_figure(15.0, 4.2 * len(methods))
    axes = np.atleast_2d(fig.subplots(len(methods), 3))
    colors = {"optical_path": "tab:blue", "su": "tab:orange", "regular_in_air": "tab:green"}
    for row, method in enumerate(methods):
        comps = _components(errors_by_method[method])
        for col, name in enumerate(("dX", "dY", "dZ")):
            ref = None
            if reference is not None:
                ref = norm.fit(_components(reference[method])[name].ravel())
            ax = axes[row, col]
            _hist_panel(ax, comps[name].ravel(), method_label(method), colors[method], ref)
            ax.set_xlabel(f"{name} [mm]")
            ax.set_title(f"{method_label(method)}: {name}", fontsize=10)
    fig.suptitle(title)
    return fig


def figure_index_profile(in_situ: dict) -> Figure:
    """Reprojection RMS against the assumed water index (every point at its optimum), with the
    in-situ estimates, the truth and the assumed value marked."""
    fig = new_figure(7.5, 4.5)
    ax = fig.subplots()
    profile = in_situ["profile"]
    ax.plot(profile["n"], profile["rms_px"], "o-", ms=3, label="reprojection RMS (trial 0)")
    ax.axvline(in_situ["n_true"], color="k", lw=1.5, label=f"truth {in_situ['n_true']:.7g}")
    estimate = in_situ["estimates"][0]
    ax.axvline(estimate, color="C3", ls="--",
               label=f"estimate {estimate:.7g} ± {in_situ['sigmas'][0]:.1e}")
    ax.axvspan(in_situ["n_true"] + in_situ["bias"] - in_situ["spread"],
               in_situ["n_true"] + in_situ["bias"] + in_situ["spread"], color="C3", alpha=0.12,
               label=f"±1 spread of {in_situ['trials']} trials")
    ax.set_xlabel("assumed n_water")
    ax.set_ylabel("reprojection RMS (px)")
    ax.set_title(f"Figure 11 — the water index from the measurement itself (σ = "
                 f"{in_situ['sigma_px']:g} px, assumed {in_situ['n_assumed']:g})", fontsize=9)
    ax.ticklabel_format(axis="x", useOffset=False)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def write_figures(results: dict, out) -> dict[str, Path]:
    """Draw figures 4–10 into ``out`` (PNG, atomic); return ``{figureN: path}``."""
    out = Path(out)
    noise = results["noise"]
    index = results["index"]
    side = index["chosen_side"]
    side_entry = index["sides"][side]
    trials = noise["trials"]
    sigma = noise["sigma_px"]
    dev = f"n3 true {side_entry['n_water_true']:.7g}, assumed {side_entry['n_water_assumed']:.7g}"
    z = noise["z_mm"]
    figures = {
        "figure4": figure4_gap(results),
        "figure5": figure_su_ideal(results, 1000.0, 5),
        "figure6": figure_su_ideal(results, 2000.0, 6),
        "figure7": figure_maps(
            noise["errors"], noise["targets"], 0,
            f"Figure 7 — pixel noise σ = {sigma:g} px (variance {noise['variance_px2']:g} px²), "
            f"Z = {z:g} mm: errors of ONE Monte-Carlo draw (trial 0 of {trials}); "
            "black lines: ±1 mm"),
        "figure8": figure_hist(
            {m: noise["errors"][m] for m in ("optical_path", "su")},
            f"Figure 8 — pixel noise σ = {sigma:g} px, Z = {z:g} mm: normalized histograms over "
            f"496 targets × {trials} trials with fitted Gaussians"),
        "figure9": figure_maps(
            index["errors"][side], noise["targets"], 0,
            f"Figure 9 — pixel noise σ = {sigma:g} px and {100 * index['relative']:g} % water-index "
            f"deviation ({side} side: {dev}), Z = {z:g} mm: one draw (trial 0, same noise as "
            "Figure 7)"),
        "figure10": figure_hist(
            index["errors"][side],
            f"Figure 10 — pixel noise and {100 * index['relative']:g} % water-index deviation "
            f"({side} side: {dev}): histograms over 496 × {trials}, dashed = Figure 8's fit",
            reference={m: noise["errors"][m] for m in ("optical_path", "su")}),
        "figure11": figure_index_profile(results["in_situ"]),
    }
    paths = {}
    for key, fig in figures.items():
        paths[key] = save_figure(fig, out / FIGURE_FILES[key])
    return paths
