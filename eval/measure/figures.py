"""``views.png`` of ``eval measure``: both photos side by side with what was found in them.

Targets: accepted detections (green circles), rejected blobs (red crosses), the matched pairs
(blue lines from left to right), detections left unmatched (orange). Dense: the matched left
pixels of the first method shaded over the left photo. The photos (linear, as read) are shown
with an sRGB-like gamma, their 99.9th percentile as white. matplotlib, Agg canvas only.
Coordinates: pixels, OpenCV convention.
"""

from __future__ import annotations

import numpy as np

from eval.core.figures import new_figure, save_figure


def _display(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image, dtype=np.float32)
    white = float(np.percentile(image, 99.9)) or float(image.max()) or 1.0
    return np.clip(image / white, 0, 1) ** (1 / 2.2)


def views_figure(path, result, method: str | None = None) -> None:
    """Both views of one pair (:class:`eval.measure.pipeline.PairResult`) with its detections
    and matches, or (dense) the pixels ``method`` matched."""
    left, right = result.left, result.right
    width = left.shape[1]
    fig = new_figure(16, 7.2, layout=None)
    ax = fig.add_subplot()
    ax.imshow(np.hstack([_display(left), _display(right)]), cmap="gray", interpolation="nearest",
              vmin=0, vmax=1)
    if result.detections is not None:
        for offset, view in ((0, "left"), (width, "right")):
            d = result.detections[view]
            c = np.asarray(d.centers).reshape(-1, 2)
            if len(c):
                ax.scatter(c[:, 0] + offset, c[:, 1], s=14, facecolors="none",
                           edgecolors="lime", linewidths=0.6,
                           label="detected" if offset == 0 else None)
            rejected = np.asarray(d.rejected_centers).reshape(-1, 2)
            if len(rejected):
                ax.scatter(rejected[:, 0] + offset, rejected[:, 1], s=22, marker="x", c="red",
                           linewidths=0.8, label="rejected blob" if offset == 0 else None)
            if result.matches is not None:
                alone = c[getattr(result.matches, f"unmatched_{view}")]
                if len(alone):
                    ax.scatter(alone[:, 0] + offset, alone[:, 1], s=40, facecolors="none",
                               edgecolors="orange", linewidths=0.9,
                               label="unmatched" if offset == 0 else None)
        if len(result.uv_left):
            xs = np.vstack([result.uv_left[:, 0], result.uv_right[:, 0] + width])
            ys = np.vstack([result.uv_left[:, 1], result.uv_right[:, 1]])
            ax.plot(xs, ys, color="deepskyblue", linewidth=0.25, alpha=0.6)
            ax.plot([], [], color="deepskyblue", label=f"matched pair ({len(result.uv_left)})")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="lower center", ncol=4, fontsize=8)
        title = f"{result.name}: left | right, detections and matches"
    else:
        uv = result.uv_left.get(method, np.zeros((0, 2))) if method else np.zeros((0, 2))
        mask = np.zeros(left.shape, dtype=float)
        mask[uv[:, 1].astype(int), uv[:, 0].astype(int)] = 1.0
        overlay = np.zeros((*left.shape, 4))
        overlay[..., 2] = 1.0
        overlay[..., 3] = 0.35 * mask
        ax.imshow(np.hstack([overlay, np.zeros_like(overlay)]), interpolation="nearest")
        title = (f"{result.name}: left | right, pixels matched by {method} (blue: "
                 f"{len(uv)})")
    if result.problem:
        title += " — nothing measured"
    ax.set_title(title)
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    fig.tight_layout()
    save_figure(fig, path)


__all__ = ["views_figure"]
