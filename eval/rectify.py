"""``python -m eval rectify --calib FILE --distance Z_MM LEFT RIGHT --out DIR``: a stereo pair
warped to a virtual pinhole pair, for tools that know no port.

The warp (:func:`measure.stereo.rectify.rectify`) is exact for points on the plane at
``--distance`` mm along the rig's depth axis (the port normal; for domes the left optical axis)
and row-aligned like ``cv2.stereoRectify``'s pairs, so that OpenCV's ``StereoSGBM``, COLMAP or a
SLAM system can run on it unchanged. Off that plane it is not exact: ``errors.json`` and
``error_map.png`` say by how much, in pixels (each view's rectified pixel minus the virtual
pinhole's projection) and in millimetres (the virtual pair's triangulation of the rectified
pixels minus the point), over the field at each of ``--error-distances``.

Writes to ``--out``: ``left_rectified.png``, ``right_rectified.png`` (the photos' own bit depth
and channels), ``maps.npz`` (``left_map_x``, ``left_map_y``, ``right_map_x``, ``right_map_y``:
float32 ``cv2.remap`` maps, −1 where nothing is seen), ``calib_rectified.yaml`` (the virtual
pinhole pair: no port, no distortion; ``eval measure`` and OpenCV read it), ``errors.json``,
``error_map.png``.
"""

from __future__ import annotations

import json
import os
import sys
import time

import numpy as np

from eval.cli import CLIError, positive_float
from synth.infra.cli import add_json_option, add_out_option, add_progress_option
from synth.infra.images import imread

COMMAND = "eval rectify"
#: The distances of the error map, as multiples of ``--distance``, when none are given.
DEFAULT_ERROR_FACTORS = (0.5, 0.75, 1.5, 2.0)
#: The error map's grid step over the rectified left image (px).
ERROR_GRID_STEP_PX = 16


def add_parser(subparsers):
    p = subparsers.add_parser(
        "rectify", help="warp a stereo pair to virtual pinhole cameras (exact at one distance)",
        description="Warp LEFT and RIGHT (photos of a rig calibrated with its port) to a "
                    "row-aligned virtual pinhole pair, exact for points at --distance mm; "
                    "writes the images, the cv2.remap maps, the virtual cameras' calibration "
                    "and a map of the error the warp leaves at other distances.")
    p.add_argument("left", help="the left photo")
    p.add_argument("right", help="the right photo")
    p.add_argument("--calib", required=True, metavar="FILE",
                   help="the rig's calibration with its port (calib.yaml, calibmar's stereo "
                        "YAML or the COLMAP fork's cameras.txt)")
    p.add_argument("--cameras", metavar="A,B", default=None,
                   help="two cameras of a rig of N cameras (their names in --calib, e.g. "
                        "cam0,cam2, or 0-based indices): LEFT is A's photo, RIGHT is B's; "
                        "default: the pair of a two-camera calibration")
    p.add_argument("--distance", required=True, type=positive_float, metavar="Z_MM",
                   help="the distance (mm, along the port normal from the left camera) at "
                        "which the warp is exact")
    p.add_argument("--error-distances", metavar="Z1,Z2,…", default=None,
                   help="distances (mm) of the error map (default: 0.5, 0.75, 1.5 and 2 × "
                        "--distance)")
    add_out_option(p, COMMAND, default="out/rectify")
    add_json_option(p)
    add_progress_option(p)
    p.set_defaults(_main=main)
    return p


def parse_distances(text, distance: float) -> list:
    """``--error-distances`` as floats (mm), or the defaults around ``distance``."""
    if text is None:
        return [f * distance for f in DEFAULT_ERROR_FACTORS]
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise CLIError(f"--error-distances {text!r}: give distances in mm, e.g. 500,2000") from None
    if not values or any(not np.isfinite(v) or v <= 0 for v in values):
        raise CLIError(f"--error-distances {text!r}: give positive distances in mm")
    return values


def read_image(path):
    """The photo as stored (its bit depth and channels; EXIF orientation applied)."""
    import cv2

    if not os.path.isfile(path):
        raise CLIError(f"{path}: no such file")
    image = imread(path, cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if image is None:
        raise CLIError(f"{path}: not an image OpenCV can read")
    return image


def error_grid(rectification, distances):
    """Per distance the warp's errors on a grid of the rectified left image: ``(uv (N, 2),
    {distance: warp_errors})``."""
    from measure.stereo.rectify import plane_points, warp_errors

    virtual = rectification.virtual.left
    w, h = virtual.size
    u, v = np.meshgrid(np.arange(0, w, ERROR_GRID_STEP_PX, dtype=float),
                       np.arange(0, h, ERROR_GRID_STEP_PX, dtype=float))
    uv = np.column_stack([u.ravel(), v.ravel()])
    axis = rectification.rig.depth_axis
    return uv, {z: warp_errors(rectification, plane_points(virtual, uv, axis, z))
                for z in distances}


def error_summary(errors) -> dict:
    """The report's numbers of one distance's :func:`measure.stereo.rectify.warp_errors`."""
    def stats(values):
        values = values[np.isfinite(values)]
        if values.size == 0:
            return {"median": None, "p95": None, "max": None, "n": 0}
        return {"median": float(np.median(values)), "p95": float(np.percentile(values, 95)),
                "max": float(values.max()), "n": int(values.size)}

    return {"left_px": stats(errors[0]["error_px"]), "right_px": stats(errors[1]["error_px"]),
            "mm": stats(np.linalg.norm(errors["error_mm"], axis=1))}


def error_figure(path, rectification, uv, grids) -> None:
    """``error_map.png``: per distance, the left and right pixel errors and the 3D error over
    the rectified left image."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w, h = rectification.virtual.left.size
    shape = (len(np.unique(uv[:, 1])), len(np.unique(uv[:, 0])))
    fig, axes = plt.subplots(len(grids), 3, figsize=(12, 3.2 * len(grids)), squeeze=False)
    for row, (z, errors) in zip(axes, grids.items()):
        panels = ((errors[0]["error_px"], f"left, {z:g} mm: px"),
                  (errors[1]["error_px"], f"right, {z:g} mm: px"),
                  (np.linalg.norm(errors["error_mm"], axis=1), f"3D error, {z:g} mm: mm"))
        for ax, (values, title) in zip(row, panels):
            image = ax.imshow(values.reshape(shape), extent=(0, w, h, 0), cmap="viridis")
            ax.set_title(title, fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
            fig.colorbar(image, ax=ax, fraction=0.046)
    fig.suptitle(f"what the warp exact at {rectification.distance_mm:g} mm leaves elsewhere "
                 f"(over the rectified left image)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def rig_to_rectify(args):
    """``(rig, has_port, names)``: the pair of a two-camera ``--calib`` (``names`` None), or
    ``--cameras A,B`` of a rig of N cameras (:meth:`measure.stereo.rig.Rig.pair`:
    behind the port they share or each behind its own; ``names`` theirs). CLIError for a rig
    of N cameras without ``--cameras`` and for names it does not hold."""
    from synth.products.dataset import DatasetError
    from synth.products.rig_file import read_rig_file

    from eval.measure.inputs import read_calibration

    if args.cameras is None:
        try:
            rig, _, has_port, _ = read_calibration(args.calib)
        except CLIError:
            _refuse_rig_without_cameras(args.calib)
            raise
        return rig, has_port, None
    try:
        multi = read_rig_file(args.calib)
    except DatasetError as exc:
        raise CLIError(f"--calib {exc}") from None
    i, j = camera_pair(args.cameras, multi.names)
    rig = multi.pair(i, j)
    return rig, rig.port is not None and rig.port.refracts, (multi.names[i], multi.names[j])


def _refuse_rig_without_cameras(path) -> None:
    """CLIError saying to pick two cameras where ``path`` is a rig of more than two (the pair's
    reader refused it); nothing otherwise."""
    from synth.products.dataset import DatasetError
    from synth.products.rig_file import read_rig_file

    try:
        multi = read_rig_file(path)
    except (DatasetError, ValueError, OSError):
        return
    if len(multi.cameras) > 2:
        raise CLIError(f"--calib {path}: a rig of {len(multi.cameras)} cameras "
                       f"({', '.join(multi.names)}): give the pair to rectify, --cameras "
                       f"{multi.names[0]},{multi.names[1]}")


def camera_pair(text: str, names) -> tuple[int, int]:
    """The indices of ``--cameras A,B`` (names of ``names`` or 0-based indices)."""
    parts = [part.strip() for part in text.split(",")]
    if len(parts) != 2 or not all(parts):
        raise CLIError(f"--cameras {text}: give two cameras, e.g. --cameras "
                       f"{names[0]},{names[-1]}")
    indices = []
    for part in parts:
        if part in names:
            indices.append(names.index(part))
        elif part.isdigit() and int(part) < len(names):
            indices.append(int(part))
        else:
            raise CLIError(f"--cameras {text}: no camera {part!r} in the calibration (its "
                           f"cameras: {', '.join(names)})")
    if indices[0] == indices[1]:
        raise CLIError(f"--cameras {text}: two different cameras")
    return indices[0], indices[1]


def main(args) -> int:
    import cv2

    from measure.stereo.rectify import rectify
    from synth.infra.fileio import OutputDir, atomic_write_json, jsonable
    from synth.products.dataset import write_calib

    log = ((lambda text: None) if args.no_progress
           else (lambda text: print(text, file=sys.stderr, flush=True)))
    start = time.perf_counter()
    distances = parse_distances(args.error_distances, args.distance)
    output = OutputDir(args.out, COMMAND).claim()
    rig, has_port, names = rig_to_rectify(args)
    size = rig.left.size
    if not has_port:
        raise CLIError(f"--calib {args.calib}: a calibration without a port: its photos need "
                       f"no warp to a pinhole camera (cv2.stereoRectify does the rest)")
    images = [read_image(path) for path in (args.left, args.right)]
    for path, image, camera, name in zip((args.left, args.right), images,
                                         (rig.left, rig.right), names or (None, None)):
        if (image.shape[1], image.shape[0]) != tuple(camera.size):
            whose = f" camera {name}" if name else ""
            raise CLIError(f"{path}: {image.shape[1]}x{image.shape[0]} px, but --calib "
                           f"{args.calib}{whose} is for {camera.size[0]}x{camera.size[1]} px "
                           f"images")
    glass = rig.port.glass_depth(rig.left)
    if args.distance <= glass:  # refused before any work or progress line
        raise CLIError(f"--distance {args.distance:g}: distance must lie in the water, beyond "
                       f"the glass ({glass:.6g} mm)")
    log(f"maps exact at {args.distance:g} mm for {size[0]}x{size[1]} px …")
    try:
        rectification = rectify(rig, args.distance)
    except ValueError as exc:
        raise CLIError(f"--distance {args.distance:g}: {exc}") from None
    log(f"the warp's error at {', '.join(f'{z:g}' for z in distances)} mm …")
    uv, grids = error_grid(rectification, distances)
    report = {"calib": args.calib, **({"cameras": list(names)} if names else {}),
              "left": args.left, "right": args.right,
              "distance_mm": args.distance, "size": list(size),
              "virtual": {"left_K": rectification.virtual.left.K.tolist(),
                          "right_K": rectification.virtual.right.K.tolist(),
                          "baseline_mm": float(np.linalg.norm(rectification.virtual.right.t
                                                              - rectification.virtual.left.t))},
              "errors": {f"{z:g}": error_summary(e) for z, e in grids.items()},
              "error_grid_step_px": ERROR_GRID_STEP_PX}
    with output.staged() as tmp:
        for name, view, image in (("left", 0, images[0]), ("right", 1, images[1])):
            if not cv2.imwrite(os.path.join(tmp, f"{name}_rectified.png"),
                               rectification.warp(view, image)):
                raise CLIError(f"{name}_rectified.png: OpenCV cannot write this image")
        np.savez_compressed(os.path.join(tmp, "maps.npz"),
                            **{f"{name}_{axis}": rectification.maps[view][k]
                               for view, name in enumerate(("left", "right"))
                               for k, axis in enumerate(("map_x", "map_y"))})
        write_calib(os.path.join(tmp, "calib_rectified.yaml"), rectification.virtual,
                    has_port=False)
        error_figure(os.path.join(tmp, "error_map.png"), rectification, uv, grids)
        report["timings_s"] = {"total": time.perf_counter() - start}
        report = jsonable(report)
        atomic_write_json(os.path.join(tmp, "errors.json"), report)
    stream = sys.stderr if args.json else sys.stdout
    for z, e in report["errors"].items():
        print(f"at {z} mm: left median {e['left_px']['median']:.3g} px (max "
              f"{e['left_px']['max']:.3g}), right median {e['right_px']['median']:.3g} px (max "
              f"{e['right_px']['max']:.3g}), 3D median {e['mm']['median']:.3g} mm (max "
              f"{e['mm']['max']:.3g})", file=stream)
    print(f"wrote {output.path}", file=stream)
    if args.json:
        print(json.dumps(report, indent=2))
    return 0
