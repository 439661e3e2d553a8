"""Figures and coloured clouds of a dense surface score (see :mod:`eval.core.surface_metrics`).

matplotlib with the Agg canvas only (no display). Every file is written whole or not at all:
PNGs through :func:`synth.infra.fileio.atomic_write_bytes`, PLYs by Open3D to a temporary file beside
the target, then renamed. Units mm; images in pixels (OpenCV convention, ``(u, v)`` = column, row).
"""

from __future__ import annotations

import os
import tempfile

import numpy as np
from matplotlib import colormaps


from eval.core.cloud_metrics import write_colored_ply
from eval.core.figures import new_figure, save_figure
from eval.core.results import method_label

#: Grey for pixels with no value (NaN) in the error map.
NO_VALUE_GREY = "0.6"
#: Lower end (mm) of the histogram's logarithmic axis: below the float32 resolution of the
#: distances at ~1 m (1e-4 mm, see :mod:`eval.core.surface_metrics`); smaller values are counted here.
HISTOGRAM_FLOOR_MM = 1e-4


def symmetric_limit(values, percentile: float = 99.0) -> float:
    """The ``percentile`` of |values| over the finite ones (mm); 1.0 when there is none or it is 0."""
    finite = np.abs(np.asarray(values, dtype=np.float64))
    finite = finite[np.isfinite(finite)]
    limit = float(np.percentile(finite, percentile)) if finite.size else 0.0
    return limit if limit > 0 else 1.0


def write_error_map(path, depth_error: np.ndarray, title: str) -> str:
    """The ``(H, W)`` depth error (mm; + = measured too deep) as an image over the left image
    grid: diverging colormap with symmetric limits at the 99th percentile of |error| (larger
    values saturate), NaN (no measurement or no truth) in grey. Returns the path."""
    depth_error = np.asarray(depth_error, dtype=np.float64)
    if depth_error.ndim != 2:
        raise ValueError("depth_error must be an (H, W) array")
    limit = symmetric_limit(depth_error)
    finite = depth_error[np.isfinite(depth_error)]
    summary = (f"RMS {np.sqrt(np.mean(finite ** 2)):.4f} mm, {finite.size} px"
               if finite.size else "no pixel with both values")
    return _pixel_map(path, depth_error, "RdBu_r", (-limit, limit), "depth error [mm]", "both",
                      f"{title}\n{summary}; grey: no value")


def _pixel_map(path, values, cmap_name: str, limits, label: str, extend: str, title: str) -> str:
    """``values`` ``(H, W)`` over the left image grid with ``cmap_name`` between ``limits``,
    NaN in grey, a colour bar ``label`` (``extend``: the saturated ends), ``title``; saved."""
    height, width = values.shape
    fig = new_figure(7.5, 1.2 + 6.0 * height / max(width, 1))
    ax = fig.add_subplot()
    cmap = colormaps[cmap_name].with_extremes(bad=NO_VALUE_GREY)
    image = ax.imshow(np.ma.masked_invalid(values), cmap=cmap, vmin=limits[0], vmax=limits[1],
                      interpolation="nearest")
    fig.colorbar(image, ax=ax, label=label, extend=extend)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    return save_figure(fig, path)


def write_sigma_map(path, sigma: np.ndarray, title: str) -> str:
    """The ``(H, W)`` σ of each point (mm) over the left image grid: sequential colormap from 0
    to the 99th percentile (larger values saturate), NaN (no measurement) in grey; the title
    gives the median and the largest. Returns the path."""
    sigma = np.asarray(sigma, dtype=np.float64)
    if sigma.ndim != 2:
        raise ValueError("sigma must be an (H, W) array")
    finite = sigma[np.isfinite(sigma)]
    limit = float(np.percentile(finite, 99)) if finite.size else 1.0
    summary = (f"median {np.median(finite):.4f} mm, max {finite.max():.4f} mm, {finite.size} px"
               if finite.size else "no pixel with a value")
    return _pixel_map(path, sigma, "viridis", (0.0, limit if limit > 0 else 1.0), "σ [mm]", "max",
                      f"{title}\n{summary}; grey: no value")


def write_distance_histogram(path, distances_by_method: dict, thresholds=(0.5, 1.0, 5.0)) -> str:
    """Histograms of point-to-mesh distances (mm), one step line per method (name → ``(N,)``
    array), on a logarithmic axis from :data:`HISTOGRAM_FLOOR_MM` (smaller values counted in the
    first bin) to the largest distance; y = share of that method's points per bin; the
    thresholds as dashed lines. Returns the path."""
    series = {m: np.asarray(d, dtype=np.float64).ravel() for m, d in distances_by_method.items()}
    series = {m: d[np.isfinite(d)] for m, d in series.items()}
    largest = max([float(d.max()) for d in series.values() if d.size] + list(thresholds) + [1.0])
    bins = np.geomspace(HISTOGRAM_FLOOR_MM, largest * 1.05, 61)
    fig = new_figure(7.5, 4.2)
    ax = fig.add_subplot()
    for index, (method, values) in enumerate(series.items()):
        if values.size == 0:
            ax.plot([], [], color=f"C{index}", label=f"{method_label(method)} (no points)")
            continue
        ax.hist(np.clip(values, bins[0], bins[-1]), bins=bins, histtype="step", linewidth=1.3,
                weights=np.full(values.size, 1.0 / values.size), color=f"C{index}",
                label=f"{method_label(method)} (n {values.size}, "
                      f"RMS {np.sqrt(np.mean(values ** 2)):.3g} mm)")
    for tau in thresholds:
        ax.axvline(tau, color="k", linestyle="--", linewidth=0.8)
        ax.text(tau, 0.98, f"τ = {tau:g} mm", transform=ax.get_xaxis_transform(), fontsize=7,
                rotation=90, va="top", ha="right")
    ax.set_xscale("log")
    ax.set_xlabel("point-to-mesh distance [mm]")
    ax.set_ylabel("share of points per bin")
    ax.set_title("distance of the measured points to the true surface", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", framealpha=0.9)
    return save_figure(fig, path)


def write_colored_cloud(path, points: np.ndarray, distances: np.ndarray, vmax: float,
                        colormap: str = "viridis") -> dict:
    """Binary PLY of ``(N, 3)`` points (mm, reference frame; rows with a non-finite point or
    distance left out) coloured by ``distances`` (mm) on ``colormap`` over [0, ``vmax``],
    clipped (:func:`eval.core.cloud_metrics.write_colored_ply`, to a temporary ``.ply`` beside
    ``path`` — Open3D picks the format from the extension — renamed into place). Returns
    ``{"file", "points", "colormap", "vmin_mm", "vmax_mm"}``."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    distances = np.asarray(distances, dtype=np.float64).reshape(-1)
    if len(points) != len(distances):
        raise ValueError("points and distances must have the same length")
    keep = np.isfinite(points).all(axis=1) & np.isfinite(distances)
    points, distances = points[keep], distances[keep]
    entry = {"file": os.path.basename(os.fspath(path)), "points": int(len(points)),
             "colormap": colormap, "vmin_mm": 0.0, "vmax_mm": float(vmax)}
    directory, name = os.path.split(os.path.abspath(os.fspath(path)))
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{name}.", suffix=".tmp.ply")
    os.close(fd)
    try:
        write_colored_ply(tmp, points, distances, vmax, colormap)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; outputs are meant to be read
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return entry
