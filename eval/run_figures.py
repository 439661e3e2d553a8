"""Figures of ``python -m eval run``: the views with detections and matches, error maps, histograms.

matplotlib with the Agg canvas only (no display). Coordinates: pixels (OpenCV convention) for
the views, millimetres in the reference frame for the maps.
"""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .results import method_label


def _save(fig: Figure, path: str) -> None:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=110)


def _display(image: np.ndarray) -> np.ndarray:
    """Linear radiance to a display image (sRGB-like gamma, 99.9th percentile as white)."""
    white = np.percentile(image, 99.9) or float(image.max()) or 1.0
    return np.clip(image / white, 0, 1) ** (1 / 2.2)


def views_figure(path, left, right, arrays) -> None:
    """Both views side by side; accepted detections, rejected blobs and the matched pairs."""
    detections, matches, correct = arrays["detections"], arrays["matches"], arrays["correct"]
    width = left.shape[1]
    fig = Figure(figsize=(16, 7.2))
    ax = fig.add_subplot()
    ax.imshow(np.hstack([_display(left), _display(right)]), cmap="gray", interpolation="nearest")
    for offset, name in ((0, "left"), (width, "right")):
        d = detections[name]
        c = np.asarray(d.centers)
        if len(c):
            ax.scatter(c[:, 0] + offset, c[:, 1], s=14, facecolors="none", edgecolors="lime",
                       linewidths=0.6, label=f"accepted ({name})" if offset == 0 else None)
        rejected = np.asarray(getattr(d, "rejected_centers", np.zeros((0, 2))))
        if len(rejected):
            ax.scatter(rejected[:, 0] + offset, rejected[:, 1], s=22, marker="x", c="red",
                       linewidths=0.8, label="rejected blob" if offset == 0 else None)
    left_c = np.asarray(detections["left"].centers)[matches.left]
    right_c = np.asarray(detections["right"].centers)[matches.right]
    for ok, colour, label in ((True, "deepskyblue", "matched pair"), (False, "red", "wrong match")):
        sel = correct == ok
        if sel.any():
            xs = np.vstack([left_c[sel, 0], right_c[sel, 0] + width])
            ys = np.vstack([left_c[sel, 1], right_c[sel, 1]])
            ax.plot(xs, ys, color=colour, linewidth=0.25, alpha=0.6)
            ax.plot([], [], color=colour, label=f"{label} ({int(sel.sum())})")
    ax.set_title("left | right: detections and matches")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    ax.legend(loc="lower center", ncol=4, fontsize=8)
    fig.tight_layout()
    _save(fig, path)


def views_pair(path, left, right) -> None:
    """Both views side by side (a surface scene: nothing detected to mark)."""
    fig = Figure(figsize=(16, 7.2))
    ax = fig.add_subplot()
    ax.imshow(np.hstack([_display(left), _display(right)]), cmap="gray", interpolation="nearest")
    ax.set_title("left | right")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    fig.tight_layout()
    _save(fig, path)


def error_maps_figure(path, per_method) -> None:
    """Per method: dX, dY, dZ, dP (mm) over the true target positions (X, Y in mm)."""
    methods = [m for m in per_method if len(per_method[m]["truth"])]
    fig = Figure(figsize=(16, 3.8 * max(len(methods), 1)))
    for row, method in enumerate(methods):
        truth, errors = per_method[method]["truth"], per_method[method]["errors"]
        columns = [("dX", errors[:, 0]), ("dY", errors[:, 1]), ("dZ", errors[:, 2]),
                   ("dP", np.linalg.norm(errors, axis=1))]
        for col, (name, values) in enumerate(columns):
            ax = fig.add_subplot(len(methods), 4, row * 4 + col + 1)
            if name == "dP":
                norm = dict(vmin=0, vmax=float(values.max()) or 1.0, cmap="viridis")
            else:
                limit = float(np.max(np.abs(values))) or 1.0
                norm = dict(vmin=-limit, vmax=limit, cmap="coolwarm")
            if len(values) >= 10:
                try:
                    area = ax.tricontourf(truth[:, 0], truth[:, 1], values, levels=15, **norm)
                except (ValueError, RuntimeError):
                    area = ax.scatter(truth[:, 0], truth[:, 1], c=values, s=12, **norm)
                ax.scatter(truth[:, 0], truth[:, 1], s=1, c="k")
            else:
                area = ax.scatter(truth[:, 0], truth[:, 1], c=values, s=20, **norm)
            fig.colorbar(area, ax=ax, label=f"{name} [mm]")
            ax.set_aspect("equal")
            ax.invert_yaxis()
            ax.set_title(f"{method_label(method)}: {name}", fontsize=9)
            ax.set_xlabel("X [mm]")
            ax.set_ylabel("Y [mm] (down)")
    fig.tight_layout()
    _save(fig, path)


def histograms_figure(path, per_method) -> None:
    """Normalized histograms of dX, dY, dZ per method (mm)."""
    methods = [m for m in per_method if len(per_method[m]["errors"])]
    fig = Figure(figsize=(15, 3.4 * max(len(methods), 1)))
    for row, method in enumerate(methods):
        errors = per_method[method]["errors"]
        for col, axis_name in enumerate("XYZ"):
            ax = fig.add_subplot(len(methods), 3, row * 3 + col + 1)
            values = errors[:, col]
            ax.hist(values, bins=40, density=True, color="C0" if method == "optical_path" else "C1")
            ax.axvline(values.mean(), color="k", linewidth=1,
                       label=f"mean {values.mean():+.3f} mm, σ {values.std():.3f} mm")
            ax.set_title(f"{method_label(method)}: d{axis_name}", fontsize=9)
            ax.set_xlabel(f"d{axis_name} [mm]")
            ax.set_ylabel("density [1/mm]")
            ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, path)
