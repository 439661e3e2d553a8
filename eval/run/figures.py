"""Figures of ``python -m eval run``: the views with detections and matches (the error maps and
histograms are :mod:`eval.core.figures`).

matplotlib with the Agg canvas only (no display). Coordinates: pixels (OpenCV convention) for
the views, millimetres in the reference frame for the maps.
"""

from __future__ import annotations

import numpy as np

from eval.core.figures import new_figure, save_figure

#: Margins of the views' figure (figure fractions): set before the views are sized to the axes.
VIEWS_MARGINS = dict(left=0.045, right=0.99, bottom=0.08, top=0.95)


def _display(image: np.ndarray) -> np.ndarray:
    """Linear radiance to a display image (sRGB-like gamma, 99.9th percentile as white)."""
    white = np.percentile(image, 99.9) or float(image.max()) or 1.0
    return np.clip(image / white, 0, 1) ** (1 / 2.2)


def _side_by_side(ax, left, right) -> None:
    """Both views side by side on ``ax`` in pixel coordinates (OpenCV: pixel centres on
    integers), area-averaged (``cv2.INTER_AREA``) down to the size the axes give them in the
    saved figure and drawn as 8-bit RGB: matplotlib then neither normalizes nor resamples
    millions of float pixels itself (0.6 s of the figure's 1 s of CPU)."""
    import cv2

    pair = np.hstack([np.asarray(left, np.float32), np.asarray(right, np.float32)])
    h, w = pair.shape
    box = ax.get_position()
    fig = ax.figure
    scale = min(1.0, box.width * fig.get_figwidth() * fig.dpi / w,
                box.height * fig.get_figheight() * fig.dpi / h)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    if size != (w, h):
        pair = cv2.resize(pair, size, interpolation=cv2.INTER_AREA)
    gray = (_display(pair) * 255 + 0.5).astype(np.uint8)
    ax.imshow(np.repeat(gray[..., None], 3, axis=2), interpolation="nearest",
              extent=(-0.5, w - 0.5, h - 0.5, -0.5))


def views_figure(path, left, right, result) -> None:
    """Both views side by side; accepted detections, rejected blobs and the matched pairs of
    ``result`` (:class:`eval.run.pipeline.RunResult`)."""
    detections, matches, correct = result.detections, result.matches, result.correct
    width = left.shape[1]
    from matplotlib.collections import LineCollection

    fig = new_figure(16, 7.2, layout=None)
    fig.subplots_adjust(**VIEWS_MARGINS)
    ax = fig.add_subplot()
    _side_by_side(ax, left, right)
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
            segments = np.stack([left_c[sel], right_c[sel] + [width, 0]], axis=1)
            ax.add_collection(LineCollection(segments, colors=colour, linewidths=0.25,
                                             alpha=0.6))
            ax.plot([], [], color=colour, label=f"{label} ({int(sel.sum())})")
    ax.set_title("left | right: detections and matches", y=1.0)
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    ax.legend(loc="lower center", ncol=4, fontsize=8)
    save_figure(fig, path)


def views_pair(path, left, right) -> None:
    """Both views side by side (a surface scene: nothing detected to mark)."""
    fig = new_figure(16, 7.2, layout=None)
    fig.subplots_adjust(**VIEWS_MARGINS)
    ax = fig.add_subplot()
    _side_by_side(ax, left, right)
    ax.set_title("left | right", y=1.0)
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    save_figure(fig, path)
