"""Figures of ``python -m eval run``: the views with detections and matches (the error maps and
histograms are :mod:`eval.core.figures`).

matplotlib with the Agg canvas only (no display). Coordinates: pixels (OpenCV convention) for
the views, millimetres in the reference frame for the maps.
"""

from __future__ import annotations

import numpy as np

from eval.core.figures import new_figure, save_figure

def _display(image: np.ndarray) -> np.ndarray:
    """Linear radiance to a display image (sRGB-like gamma, 99.9th percentile as white)."""
    white = np.percentile(image, 99.9) or float(image.max()) or 1.0
    return np.clip(image / white, 0, 1) ** (1 / 2.2)


def views_figure(path, left, right, result) -> None:
    """Both views side by side; accepted detections, rejected blobs and the matched pairs of
    ``result`` (:class:`eval.run.pipeline.RunResult`)."""
    detections, matches, correct = result.detections, result.matches, result.correct
    width = left.shape[1]
    fig = new_figure(16, 7.2, layout=None)
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
    save_figure(fig, path)


def views_pair(path, left, right) -> None:
    """Both views side by side (a surface scene: nothing detected to mark)."""
    fig = new_figure(16, 7.2, layout=None)
    ax = fig.add_subplot()
    ax.imshow(np.hstack([_display(left), _display(right)]), cmap="gray", interpolation="nearest")
    ax.set_title("left | right")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    fig.tight_layout()
    save_figure(fig, path)
