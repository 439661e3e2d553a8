"""Where ``eval calibrate`` gets its board corners from when they are not detected in photos
here: a user's own detections (``--detections``: :mod:`eval.core.detections`), and the views
that repeat another pose's (:func:`repeated_views`) — a file or photo given twice is one pose,
not two.

Options: ``--detections`` (``DIR`` holds detections files, one camera's or ``left/`` and
``right/``), ``--image-size WxH`` (px; the detections say nothing of it, OpenCV's calibration
needs it) and ``--pixel-origin opencv|colmap|matlab`` (where the files put the centre of the
top-left pixel: 0, 0.5 or 1).
"""

from __future__ import annotations

import os

import numpy as np

from eval.cli import CLIError

#: The options that apply to detections only.
DETECTION_OPTIONS = ("image_size", "pixel_origin")


def add_detection_options(parser) -> None:
    """``--detections``, ``--image-size``, ``--pixel-origin`` (module docs)."""
    from eval.core.detections import PIXEL_ORIGINS

    parser.add_argument("--detections", action="store_true",
                        help="DIR holds your own detections instead of photos: a text file per "
                             "photo (one camera's in DIR, a pair's in DIR/left/ and DIR/right/, "
                             "paired by name), a line per board point: 'u v' in the board's "
                             "point order or 'id u v' (docs/calibration.md)")
    parser.add_argument("--image-size", metavar="WxH", default=None,
                        help="with --detections: the photos' size in pixels (e.g. 2592x1944)")
    parser.add_argument("--pixel-origin", choices=tuple(PIXEL_ORIGINS), default=None,
                        help="with --detections: the files' pixel convention — opencv (default: "
                             "the top-left pixel's centre is 0,0), colmap (0.5,0.5), matlab "
                             "(1,1)")


def check_detection_options(args) -> None:
    """CLIError for ``--image-size`` / ``--pixel-origin`` without ``--detections``, for
    ``--detections`` without ``--image-size`` or with ``--encoding`` (no photo is read)."""
    from synth.infra.cli import refuse_given

    if not args.detections:
        refuse_given(args, DETECTION_OPTIONS, "without --detections (photos say their size and "
                                              "are measured in OpenCV's pixels)")
        return
    refuse_given(args, ("encoding",), "to --detections: no photo is read")
    if args.image_size is None:
        raise CLIError(f"--detections: give --image-size WxH (the size of the photos the "
                       f"detections in {args.dir} come from)")
    image_size(args)


def image_size(args) -> tuple[int, int]:
    """``--image-size`` as (width, height) px."""
    try:
        width, height = (int(v) for v in str(args.image_size).lower().split("x"))
    except ValueError:
        raise CLIError(f"--image-size must be WxH in pixels (e.g. 2592x1944), got "
                       f"{args.image_size!r}") from None
    if width < 2 or height < 2:
        raise CLIError(f"--image-size {args.image_size}: at least 2x2 pixels")
    return width, height


def read_detection_views(args, board, views: int):
    """``(names, Detections, size)`` of ``--detections`` ``args.dir`` for ``views`` cameras
    (1: one camera's files; 2: ``left/`` and ``right/``). CLIError names the file and line of a
    bad detection, a point outside ``--image-size``, or a folder of the other layout."""
    from measure.calibration.air import Detections

    from eval.core.detections import (PIXEL_ORIGINS, DetectionError, detection_layout,
                                      read_detections)

    size = image_size(args)
    origin = PIXEL_ORIGINS[args.pixel_origin or "opencv"]
    try:
        layout = detection_layout(args.dir)
        if len(layout or ("one",)) != views:
            raise DetectionError(f"{args.dir}: detections of {len(layout or ('one',))} "
                                 f"camera(s), not {views}")
        names, _, per_view = read_detections(args.dir, board.n_corners, origin)
    except DetectionError as exc:
        raise CLIError(str(exc)) from None
    folders = [os.path.join(args.dir, v) for v in layout] or [args.dir]
    for name, photo in zip(names, per_view):
        for folder, (_, uv) in zip(folders, photo):
            outside = (uv < -0.5) | (uv > np.array(size) - 0.5)
            if outside.any():
                raise CLIError(f"{folder}/{name}: point ({uv[outside.any(axis=1)][0][0]:.1f}, "
                               f"{uv[outside.any(axis=1)][0][1]:.1f}) lies outside the "
                               f"{size[0]}x{size[1]} image (--image-size, --pixel-origin)")
    empty = (np.empty(0, int), np.empty((0, 2)))
    pad = [] if views == 2 else [empty]
    return names, Detections([[ids for ids, _ in photo] + [e[0] for e in pad]
                              for photo in per_view],
                             [[uv for _, uv in photo] + [e[1] for e in pad]
                              for photo in per_view]), size


def repeated_views(detections, views=(0, 1)) -> list[dict]:
    """The views that repeat another's: ``[{pose, view, of_pose, of_view}]`` for each pose's
    view whose corners (ids and pixels, to 1e-9 px) are those of an earlier pose's view of the
    same camera, or — a pair — whose right view is its own left view (the same photo as left
    and right). Identical photos give identical detections: a photo given twice is one pose."""
    out, seen = [], {}
    for k in range(detections.n_poses):
        for v in views:
            ids, uv = detections.ids[k][v], np.asarray(detections.pixels[k][v])
            if len(ids) == 0:
                continue
            key = (v, len(ids), round(float(np.sum(uv)), 6))
            for j in seen.get(key, []):
                if np.array_equal(ids, detections.ids[j][v]) and np.allclose(
                        uv, detections.pixels[j][v], rtol=0, atol=1e-9):
                    out.append({"pose": k, "view": v, "of_pose": j, "of_view": v})
                    break
            else:
                seen.setdefault(key, []).append(k)
        if len(views) == 2 and len(detections.ids[k][0]) and np.array_equal(
                detections.ids[k][0], detections.ids[k][1]) and np.allclose(
                detections.pixels[k][0], detections.pixels[k][1], rtol=0, atol=1e-9):
            out.append({"pose": k, "view": 1, "of_pose": k, "of_view": 0})
    return out


def repeat_lines(repeats, names, view_names=("left", "right")) -> list[str]:
    """One sentence per pose with a repeated view (:func:`repeated_views`): ``pair7 repeats
    pair3 (both photos)``, ``pair8's right photo repeats pair2's``, ``pair5's right photo is
    its left``; one camera: ``b repeats a``."""
    by_pose = {}
    for r in repeats:
        by_pose.setdefault(r["pose"], []).append(r)
    lines = []
    for pose, found in by_pose.items():
        name = names[pose]
        sources = {r["of_pose"] for r in found}
        if len(view_names) == 1:
            lines.append(f"{name} repeats {names[found[0]['of_pose']]}")
        elif any(r["of_pose"] == pose for r in found):
            lines.append(f"{name}'s right photo is its left (the same photo twice)")
        elif len(found) == len(view_names) and len(sources) == 1:
            lines.append(f"{name} repeats {names[found[0]['of_pose']]} (both photos)")
        else:
            lines += [f"{name}'s {view_names[r['view']]} photo repeats "
                      f"{names[r['of_pose']]}'s" for r in found]
    return lines


def without_repeats(detections, repeats):
    """``detections`` without every pose that has a repeated view (:func:`repeated_views`)."""
    from eval.calibrate.photos import without

    return without(detections, sorted({r["pose"] for r in repeats}))


__all__ = ["DETECTION_OPTIONS", "add_detection_options", "check_detection_options",
           "image_size", "read_detection_views", "repeat_lines", "repeated_views",
           "without_repeats"]


#: ``--max-poses``' default: more poses than this (the frames of a calibration video) are
#: thinned by pose diversity before the fit.
MAX_POSES = 150


def thin_by_pose(detections, board, size, max_poses: int = MAX_POSES):
    """``(detections, kept)``: at most ``max_poses`` poses, chosen to differ most (farthest-point
    sampling, from the pose with the most corners): each pose is described by where the
    homography of its detected corners puts the board's four outer corners in every view
    (pixels over the image's diagonal), so poses that repeat a position and tilt — a video's
    consecutive frames — go first. ``kept`` the poses kept (all when there are not more)."""
    import cv2

    found = sorted(set().union(*[detections.found(v) for v in range(len(detections.ids[0]))]))
    if len(found) <= max_poses:
        return detections, found
    corners = board.corners()[:, :2]
    outline = np.array([corners.min(axis=0), [corners[:, 0].max(), corners[:, 1].min()],
                        corners.max(axis=0), [corners[:, 0].min(), corners[:, 1].max()]])
    diagonal = float(np.hypot(*size))
    features = []
    for k in found:
        row = []
        for v in range(len(detections.ids[k])):
            ids = detections.ids[k][v]
            if len(ids) >= 4:
                H, _ = cv2.findHomography(corners[ids], detections.pixels[k][v], 0)
            else:
                H = None
            row.append(np.full(8, -1.0) if H is None else cv2.perspectiveTransform(
                outline.reshape(-1, 1, 2), H).ravel() / diagonal)
        features.append(np.concatenate(row))
    features = np.array(features)
    counts = np.array([sum(len(i) for i in detections.ids[k]) for k in found])
    chosen = [int(np.argmax(counts))]
    distance = np.linalg.norm(features - features[chosen[0]], axis=1)
    while len(chosen) < max_poses:
        nxt = int(np.argmax(distance))
        chosen.append(nxt)
        distance = np.minimum(distance, np.linalg.norm(features - features[nxt], axis=1))
    kept = sorted(found[i] for i in chosen)
    from eval.calibrate.photos import without

    return without(detections, sorted(set(found) - set(kept))), kept
