"""Calibrating a user's own photos: what the report says when there is no truth to compare with.

A photo folder (:mod:`eval.core.photos`: ``DIR/left/``, ``DIR/right/``, paired by name) holds
nothing but images, so every number reported here comes from the photos themselves:

* per pose and view the corners found and the reprojection RMS of the final fit (RMS of the 2D
  residual length, px: OpenCV's per-view errors in air, the bundle adjustment's underwater);
* poses where the board was not found, and **outlier poses**: a pose is left out of the final
  fit when one of its views' RMS in the first fit exceeds :func:`outlier_threshold` =
  max(3 × median, median + 5 × 1.4826 × MAD, median + 0.1 px) of all views' RMS (MAD the
  median absolute deviation; 1.4826 × MAD is σ for Gaussian scatter; the 0.1 px floor keeps a
  set of nearly equal, very small residuals from shedding poses); once no pose is, single
  corners whose residual exceeds 5 robust σ (:func:`outlier_corners`). The fit is run again
  after each round until nothing more drops out (:func:`fit_without_outliers`), and the report
  names every pose and corner left out;
* the σ and correlations of every estimate (in air OpenCV's ``calibrateCameraExtended``
  standard deviations; the stereo pose has none from OpenCV, so the per-pose scatter of the
  baseline over √n is given; underwater the housing's σ and correlation matrix);
* how well the corners cover each image (:func:`coverage`: the fraction of a 10 × 10 grid of
  cells holding a corner of a used pose, and ``coverage.png``), the board distances and tilts
  (from the estimated poses);
* warnings (:func:`warnings_for`) when there are fewer than :data:`RECOMMENDED_POSES` poses,
  the boards are tilted by less than :data:`MIN_TILT_DEG` (focal length and, underwater, the
  port trade against each other without perspective), the corners cover less than
  :data:`MIN_COVERAGE` of an image (the distortion is extrapolated), or two housing parameters
  correlate at :data:`HIGH_CORRELATION` or more.
"""

from __future__ import annotations


import numpy as np
from measure.calibration.air import (LENS_MODEL_GAIN, LENS_MODEL_ORDER, STEREO_FLOOR_DEG,
                                 STEREO_FLOOR_FRACTION, STEREO_OUTLIER_FACTOR)
from measure.calibration.outliers import (OUTLIER_FACTOR, OUTLIER_FLOOR_PX, OUTLIER_MADS,
                                          outlier_threshold)

from eval.calibrate.board_size import HINT_PHOTOS, board_hint, larger_board

#: Warn below these.
RECOMMENDED_POSES, MIN_TILT_DEG, MIN_COVERAGE = 8, 15.0, 0.5
#: Warn at or above this |correlation| between two housing parameters.
HIGH_CORRELATION = 0.95
#: Coverage grid: cells per image side.
COVERAGE_CELLS = 10
VIEWS = ("left", "right")
#: An in-air stereo fit has failed when its RMS exceeds :data:`STEREO_RMS_FACTOR` × the worse
#: camera's own RMS + :data:`STEREO_RMS_MARGIN_PX` (a correct one is a little above the
#: cameras': OpenCV's stereo sample 0.27 px against 0.23 and 0.29 px).
STEREO_RMS_FACTOR, STEREO_RMS_MARGIN_PX = 2.0, 0.2
STEREO_RULE = (f"a pose is left out of the stereo fit when its own stereo pose (from the two "
               f"cameras' board poses) lies farther from the median pose than "
               f"max({STEREO_OUTLIER_FACTOR:g} × the median distance, "
               f"{100 * STEREO_FLOOR_FRACTION:g} % of the baseline) or is turned from it by more "
               f"than max({STEREO_OUTLIER_FACTOR:g} × the median angle, {STEREO_FLOOR_DEG:g}°); "
               f"the run then exits 1 naming it")
LENS_RULE = (f"auto tries {', '.join(LENS_MODEL_ORDER)} in turn and keeps a richer model only "
             f"when it lowers the RMS by {100 * LENS_MODEL_GAIN:g} % or more")
#: Corners listed in the report by their residual.
WORST_CORNERS = 10
#: Single corners (:func:`outlier_corners`): left out beyond this many robust σ, at least
#: this many px; the rounds of :func:`fit_without_outliers` at most.
CORNER_SIGMAS, CORNER_FLOOR_PX, MAX_OUTLIER_ROUNDS = 8.0, 0.1, 6
#: A corner's neighbours for :func:`outlier_corners`: within this many squares on the board;
#: more than this fraction of the corners beyond the threshold says the model misfits (the
#: Minions rig with its stereo pose freed: 855 of 4056, 0.32 px and more), and none is dropped.
NEIGHBOUR_SQUARES, MAX_CORNER_FRACTION = 1.5, 0.02
OUTLIER_RULE = (f"a pose is left out when one of its views' RMS exceeds "
                f"max({OUTLIER_FACTOR:g} × median, median + {OUTLIER_MADS:g} × 1.4826 × MAD, "
                f"median + {OUTLIER_FLOOR_PX:g} px) of all views' RMS, and once no pose is, a "
                f"single corner whose residual exceeds max({CORNER_SIGMAS:g} robust σ of its photo, "
                f"{CORNER_FLOOR_PX:g} px), its residual taken less the median of its board "
                f"neighbours' (none when more than {100 * MAX_CORNER_FRACTION:g} % of the "
                f"corners are: then the model misfits); the fit is run again after each, until "
                f"nothing more drops out")


def outlier_poses(rms_per: dict) -> tuple[float, list[int]]:
    """``(threshold, poses)`` of ``{(pose, view): rms}``: the poses with a view above the
    threshold, sorted."""
    threshold = outlier_threshold(rms_per.values())
    return threshold, sorted({k for (k, _), r in rms_per.items() if r > threshold})


def without(detections, poses):
    """``detections`` with the board of ``poses`` removed (both views; pose numbers kept)."""
    from measure.calibration.air import Detections

    drop = set(poses)
    empty = (np.empty(0, int), np.empty((0, 2)))
    ids = [[empty[0]] * 2 if k in drop else list(v) for k, v in enumerate(detections.ids)]
    pixels = [[empty[1]] * 2 if k in drop else list(v) for k, v in enumerate(detections.pixels)]
    return Detections(ids, pixels)


def outlier_corners(residuals: dict, board=None) -> tuple[float, list]:
    """``(largest threshold, [(pose, view, id, residual px), …])`` of a fit's ``residuals``
    ``{view: (pose, id, du, dv) rows}``: the corners whose residual, less the median residual
    of its board neighbours in the same photo (within :data:`NEIGHBOUR_SQUARES` squares, with
    ``board``; a lens model that misfits the image's edges moves neighbours alike, a corner the
    detector put on another feature moves alone), is longer than max(:data:`CORNER_SIGMAS` ×
    σ, :data:`CORNER_FLOOR_PX`), σ the robust per-axis scatter of those in its photo (1.4826 ×
    the median of |du|, |dv|; photos differ: blur, light). Real corners' errors have heavier
    tails than a Gaussian's: at 5 σ, 8–22 ordinary corners (0.35–0.7 px) of each real set in
    docs/calibration.md went; at 8 σ none of them, while a corner on another feature is off
    by a pixel or more."""
    rows = [np.column_stack([np.full(len(r), view), np.asarray(r, np.float64)])
            for view, r in residuals.items() if len(r)]
    if not rows:
        return 0.0, []
    rows = np.vstack(rows)
    local = rows[:, 3:5] - _neighbour_medians(rows, board) if board is not None else rows[:, 3:5]
    photo = np.unique(rows[:, :2], axis=0, return_inverse=True)[1].ravel()
    sigma = 1.4826 * np.array([np.median(np.abs(local[photo == p]))
                               for p in range(photo.max() + 1)])
    threshold = np.maximum(CORNER_SIGMAS * sigma, CORNER_FLOOR_PX)[photo]
    length = np.hypot(local[:, 0], local[:, 1])
    bad = np.flatnonzero(length > threshold)
    if bad.size > MAX_CORNER_FRACTION * len(rows):  # the model misfits, not single corners
        return 0.0, []
    worst = bad[np.argsort(-length[bad])]
    return (float(threshold[bad].max()) if bad.size else 0.0,
            [(int(rows[i, 1]), int(rows[i, 0]), int(rows[i, 2]), float(length[i]))
             for i in worst])


def _neighbour_medians(rows, board) -> np.ndarray:
    """``(N, 2)`` per residual row ``(view, pose, id, du, dv)`` the median residual of the
    other corners of its photo within :data:`NEIGHBOUR_SQUARES` squares on the board (zero
    where it has none)."""
    from scipy.spatial import cKDTree

    xy = board.corners()[:, :2]
    out = np.zeros((len(rows), 2))
    for key in np.unique(rows[:, :2], axis=0):       # one photo (view, pose) at a time
        members = np.flatnonzero(np.all(rows[:, :2] == key, axis=1))
        points = xy[rows[members, 2].astype(int)]
        tree = cKDTree(points)
        for i, near in zip(members, tree.query_ball_point(points,
                                                          NEIGHBOUR_SQUARES * board.square_mm)):
            others = [members[n] for n in near if members[n] != i]
            if others:
                out[i] = np.median(rows[others, 3:5], axis=0)
    return out


def without_corners(detections, corners):
    """``detections`` without the single ``corners`` ``[(pose, view, id, …)]``; a view left
    with fewer than :data:`measure.calibration.board.MIN_CORNERS` corners loses them all."""
    from measure.calibration.air import Detections
    from measure.calibration.board import MIN_CORNERS

    drop = {}
    for pose, view, i, *_ in corners:
        drop.setdefault((pose, view), set()).add(i)
    ids = [list(v) for v in detections.ids]
    pixels = [list(v) for v in detections.pixels]
    for (pose, view), gone in drop.items():
        keep = ~np.isin(ids[pose][view], sorted(gone))
        if np.count_nonzero(keep) < MIN_CORNERS:
            keep[:] = False
        ids[pose][view] = ids[pose][view][keep]
        pixels[pose][view] = pixels[pose][view][keep]
    return Detections(ids, pixels)


def fit_without_outliers(fit, rms_of, detections, residuals_of=None, board=None,
                         usable=None):
    """``(result, detections used, outliers)``: ``fit(detections)`` repeated until nothing
    more drops out (at most :data:`MAX_OUTLIER_ROUNDS` refits): each round leaves out the
    poses :func:`outlier_poses` of ``rms_of(result)`` names, or — when none — the single
    corners :func:`outlier_corners` of ``residuals_of(result)`` names (``{view: (pose, id,
    du, dv) rows}``, each against its neighbours on ``board``; not done without it). No round
    when ``usable(result)`` is false (a fit that failed says nothing of single poses).
    ``outliers`` holds the first round's threshold, every pose left out, the first fit's
    per-view RMS, each round (its threshold, the poses and their RMS, or the corners) and the
    corners left out."""
    from measure.calibration.air import CalibrationError

    result = fit(detections)
    per = rms_of(result)
    threshold, _ = outlier_poses(per)
    info = {"threshold_px": threshold, "left_out": [],
            "first_fit_rms_px": {f"{k}:{VIEWS[v]}": r for (k, v), r in sorted(per.items())},
            "rounds": [], "corners_left_out": []}
    used = detections
    for _ in range(MAX_OUTLIER_ROUNDS if usable is None or usable(result) else 0):
        limit, bad = outlier_poses(rms_of(result))
        if bad:
            rms = rms_of(result)
            info["rounds"].append({"threshold_px": limit, "poses": bad, "rms_px": {
                f"{k}:{VIEWS[v]}": r for (k, v), r in sorted(rms.items()) if k in bad}})
            info["left_out"] = sorted(set(info["left_out"]) | set(bad))
            used = without(used, bad)
        else:
            corners = outlier_corners(residuals_of(result), board) if residuals_of else (0, [])
            if not corners[1]:
                break
            info["rounds"].append({"threshold_px": corners[0], "corners": len(corners[1])})
            info["corners_left_out"] += [{"pose": k, "view": VIEWS[v], "id": i,
                                          "residual_px": r} for k, v, i, r in corners[1]]
            used = without_corners(used, corners[1])
        try:
            result = fit(used)
        except CalibrationError as exc:
            raise CalibrationError(f"{exc} (after leaving out {len(info['left_out'])} outlier "
                                   f"pose(s) and {len(info['corners_left_out'])} corner(s))"
                                   ) from None
    return result, used, info


def corners_warning(outliers: dict) -> str | None:
    """The warning that names how many single corners were left out, or None."""
    corners = outliers.get("corners_left_out", [])
    if not corners:
        return None
    smallest = min(c["residual_px"] for c in corners)
    return (f"{len(corners)} single corner(s) left out of the final fit (each off its "
            f"neighbours by over {CORNER_SIGMAS:g} σ of its photo, {smallest:.3g} px or more; "
            f"the report's outliers list them)")


def outlier_status(outliers: dict, pose: int) -> str:
    """The report's status of a pose left out as an outlier: its worst view's RMS in the fit
    that left it out, and that round's threshold."""
    for rounds in outliers.get("rounds", []):
        if pose in rounds.get("poses", ()):
            worst = max(r for key, r in rounds["rms_px"].items() if key.startswith(f"{pose}:"))
            return (f"left out: outlier (fit RMS {worst:.3f} px > {rounds['threshold_px']:.3f} "
                    f"px)")
    first = [r for key, r in outliers["first_fit_rms_px"].items() if key.startswith(f"{pose}:")]
    return (f"left out: outlier (first fit RMS {max(first):.3f} px > "
            f"{outliers['threshold_px']:.3f} px)")


def coverage(detections, size, cells: int = COVERAGE_CELLS) -> dict:
    """Per view: ``fraction`` of ``cells × cells`` image cells holding a detected corner, and
    the ``cells`` grid (rows of 0/1)."""
    w, h = size
    out = {}
    for view, name in enumerate(VIEWS):
        grid = np.zeros((cells, cells), int)
        for k in range(detections.n_poses):
            uv = np.asarray(detections.pixels[k][view]).reshape(-1, 2)
            if len(uv):
                col = np.clip((uv[:, 0] + 0.5) * cells // w, 0, cells - 1).astype(int)
                row = np.clip((uv[:, 1] + 0.5) * cells // h, 0, cells - 1).astype(int)
                grid[row, col] = 1
        out[name] = {"fraction": float(grid.mean()), "cells": grid.tolist()}
    return out


def pose_geometry(board, poses: dict, rig) -> dict:
    """Per pose ``{distance_mm, tilt_deg}`` of ``{pose: (R, t)}`` (board to reference frame):
    the distance from the left camera's centre to the board's centre and the angle between the
    board's normal and the left camera's optical axis (0° = facing the camera)."""
    centre = board.corners().mean(axis=0)
    axis = rig.left.R[:, 2]
    out = {}
    for k, (R, t) in poses.items():
        R, t = np.asarray(R), np.asarray(t)
        c = R @ centre + t
        cos = abs(float(R[:, 2] @ axis))
        out[k] = {"distance_mm": float(np.linalg.norm(c - rig.left.t)),
                  "tilt_deg": float(np.degrees(np.arccos(min(cos, 1.0))))}
    return out


def stats_range(values) -> list | None:
    values = list(values)
    return [float(min(values)), float(max(values))] if values else None


def stereo_scatter(air, poses) -> dict:
    """The stereo pose seen pose by pose (:attr:`measure.calibration.AirCalibration.stereo_poses`:
    each pose's own stereo pose from the two cameras' board extrinsics): the baseline's scatter
    (std over the poses of the stereo fit) and that over √n — the σ OpenCV's
    ``stereoCalibrate`` does not give."""
    left_out = set(air.stereo_left_out)
    b = np.asarray([air.stereo_poses[k]["baseline_mm"] for k in poses
                    if k in air.stereo_poses and k not in left_out])
    if b.size < 2:
        return {"poses": int(b.size), "baseline_std_mm": None, "baseline_sigma_mm": None}
    std = float(np.std(b, ddof=1))
    return {"poses": int(b.size), "baseline_std_mm": std,
            "baseline_sigma_mm": std / np.sqrt(b.size)}


def air_estimates(air, poses) -> dict:
    """The in-air calibration's numbers with OpenCV's σ (no truth)."""
    out = {"rms_px": air.rms_px, "stereo_rms_px": air.stereo_rms_px,
           "poses_used": air.poses_used, "cameras": {}, "lens_models": air.lens_models,
           "covariance": air.covariance is not None}
    for name in VIEWS:
        out["cameras"][name] = camera_estimates(getattr(air.rig, name), air.sigmas[name])
    R, t = air.rig.right.R, air.rig.right.t
    from scipy.spatial.transform import Rotation

    scatter = stereo_scatter(air, poses)
    out["stereo"] = {"baseline_mm": float(np.linalg.norm(t - air.rig.left.t)),
                     "baseline_sigma_mm": scatter["baseline_sigma_mm"],
                     "baseline_std_over_poses_mm": scatter["baseline_std_mm"],
                     "baseline_poses": scatter["poses"],
                     "right_position_mm": t.tolist(),
                     "right_rotation_deg": float(np.degrees(Rotation.from_matrix(R).magnitude())),
                     "right_R": R.tolist()}
    return out


def camera_estimates(camera, sigmas: dict) -> dict:
    """``{name: {estimate, sigma}}`` of one camera's intrinsics: fx, fy, cx, cy and the
    distortion coefficients its lens model estimated (the names of ``sigmas``)."""
    from measure.calibration.air import FISHEYE_INTRINSIC_NAMES, INTRINSIC_NAMES

    values = {"fx": camera.K[0, 0], "fy": camera.K[1, 1], "cx": camera.K[0, 2],
              "cy": camera.K[1, 2]}
    dist = np.zeros(8) if camera.dist is None else np.pad(np.ravel(camera.dist),
                                                          (0, max(0, 8 - np.size(camera.dist))))
    names = FISHEYE_INTRINSIC_NAMES if camera.fisheye else INTRINSIC_NAMES
    values.update((n, d) for n, d in zip(names[4:], dist) if n in sigmas)
    return {key: {"estimate": float(v), "sigma": sigmas.get(key)} for key, v in values.items()}


def housing_estimates(housing, start_rig) -> dict:
    """The housing calibration's numbers with σ and the correlation matrix (no truth)."""
    out = {"free": list(dict.fromkeys(label.split("[")[0] for label in housing.labels)),
           "labels": list(housing.labels), "correlation": housing.correlation.tolist(),
           "rms_px": housing.rms_px, "rms_px_start": housing.rms_px_start,
           "observations": housing.n_observations, "evaluations": housing.nfev,
           "parameters": {}}
    for name in housing.estimates:
        sigma = housing.sigmas[name]
        if name == "extrinsics":
            out["parameters"][name] = {"R": housing.rig.right.R.tolist(),
                                       "t": housing.rig.right.t.tolist(),
                                       "sigma_rotation_deg": np.degrees(sigma[:3]).tolist(),
                                       "sigma_position_mm": list(sigma[3:]),
                                       "sigma_conditional": housing.sigmas_conditional.get(name)}
            continue
        for key, port, part, view in _ports(housing, name):
            s = np.atleast_1d(sigma)[part]
            conditional = np.atleast_1d(housing.sigmas_conditional.get(name, sigma))[part]
            if name == "normal":
                axis = housing.rig.cameras[view].R[:, 2]
                tilt = float(np.degrees(np.arccos(np.clip(port.normal @ axis, -1, 1))))
                p = {"estimate": port.normal.tolist(), "sigma_deg": np.degrees(s).tolist(),
                     "tilt_from_left_axis_deg" if view == 0 else "tilt_from_right_axis_deg": tilt}
                p["sigma_conditional"] = conditional.tolist()
            else:
                value, unit = {"distance": (port.distance, "mm"),
                               "thickness": (port.thicknesses[0] if port.thicknesses else None,
                                             "mm"),
                               "n_water": (port.n_water, "")}[name]
                p = {"estimate": value, "sigma": float(s[0]), "unit": unit,
                     "sigma_conditional": float(conditional[0])}
            out["parameters"][key] = p
    out["uncertainty"] = housing.uncertainty
    ports = [start_rig.view_port(v) for v in (0, 1)]
    shared = ports[0] is ports[1]
    out["start"] = {"distance": ports[0].distance if shared else [p.distance for p in ports],
                    "thickness": list(ports[0].thicknesses),
                    "indices": list(ports[0].indices)}
    return out


def _ports(housing, name):
    """``(key, port, slice of the σ, view)``: the shared port (view 0), or — two housings, the
    estimate ``{"left": …, "right": …}`` — each camera's own (``left_distance`` …)."""
    estimate = housing.estimates[name]
    if not isinstance(estimate, dict):
        yield name, housing.rig.view_port(0), slice(None), 0
        return
    width = np.size(housing.sigmas[name]) // len(estimate)
    for i, camera in enumerate(estimate):
        view = VIEWS.index(camera)
        yield f"{camera}_{name}", housing.rig.view_port(view), slice(i * width, (i + 1) * width), view


def warnings_for(report: dict) -> list[str]:
    """What a user should know before trusting the calibration (module docs)."""
    out = []
    used = [p for p in report["per_pose"] if p["status"] == "used"]
    if len(used) < RECOMMENDED_POSES:
        out.append(f"only {len(used)} pose(s) used; at least {RECOMMENDED_POSES} are "
                   f"recommended (fewer leave the distortion and the σ themselves uncertain)")
    tilt = report["geometry"]["tilt_deg"]
    if tilt is not None and tilt[1] < MIN_TILT_DEG:
        what = ("the focal lengths" if report["air"] else
                "the port distance and tilt (they trade against the focal length)")
        out.append(f"the boards are tilted by at most {tilt[1]:.1f}° (< {MIN_TILT_DEG:g}°): "
                   f"{what} are poorly determined without tilted boards; tilt some by 20–45°")
    for name in VIEWS:
        fraction = report["coverage"][name]["fraction"]
        if fraction < MIN_COVERAGE:
            out.append(f"the corners cover {100 * fraction:.0f} % of the {name} image "
                       f"({COVERAGE_CELLS}×{COVERAGE_CELLS} cells; < {100 * MIN_COVERAGE:.0f} %): "
                       f"the lens distortion is extrapolated outside them; photograph the board "
                       f"near the image's edges and corners too")
    if report.get("in_air"):
        hint = underwater_hint(report["in_air"]["cameras"],
                               {name: m["model"] for name, m in
                                report["in_air"].get("lens_models", {}).items()})
        if hint:
            out.append(hint)
    if report["left_out"]:
        out.append(f"{len(report['left_out'])} outlier pose(s) left out of the final fit: "
                   f"{', '.join(report['left_out'])} (see the outlier rule)")
    corners = corners_warning(report["outliers"])
    if corners:
        out.append(corners)
    housing = report.get("housing")
    if housing and len(housing["labels"]) > 1:
        c = np.abs(np.triu(np.asarray(housing["correlation"]), 1))
        i, j = np.unravel_index(np.argmax(c), c.shape)
        if c[i, j] >= HIGH_CORRELATION:
            out.append(f"{housing['labels'][i]} and {housing['labels'][j]} are correlated at "
                       f"{housing['correlation'][i][j]:+.3f}: these boards barely tell them apart")
    return out


def charuco_check(board, images) -> str | None:
    """For a ChArUco board: the problem (:meth:`measure.calibration.board.Board.
    charuco_problem`) that most of the first :data:`HINT_PHOTOS` of ``images`` (photos the
    board was detected in) agree on — a wrong --marker-mm or --squares — or None."""
    if board.kind != "charuco":
        return None
    problems = [board.charuco_problem(image) for image in images[:HINT_PHOTOS]]
    found = [p for p in problems if p]
    return found[0] if found and len(found) * 2 > len(problems) else None


def unseen_edge(board, detections, views) -> str | None:
    """A warning when a ChArUco board's last row or column of corners was never detected in
    any photo: the board may be smaller than --squares says (the corners then still lie where
    the larger board has them, so the fit is right, but its outline is not)."""
    if board.kind != "charuco":
        return None
    cols, rows = board.squares[0] - 1, board.squares[1] - 1
    ids = [np.asarray(detections.ids[k][v]) for k in range(detections.n_poses) for v in views]
    ids = np.concatenate([i for i in ids if i.size]) if any(i.size for i in ids) else np.empty(0)
    if not ids.size:
        return None
    r, c = ids // cols, ids % cols
    missing = [what for what, seen in (("last row", (r == rows - 1).any()),
                                       ("last column", (c == cols - 1).any())) if not seen]
    if not missing:
        return None
    smaller = (board.squares[0] - ("last column" in missing),
               board.squares[1] - ("last row" in missing))
    return (f"no corner of the board's {' and '.join(missing)} was found in any photo: is the "
            f"board {smaller[0]}x{smaller[1]} squares, not {board.squares[0]}x"
            f"{board.squares[1]}?")


def verdict_lines(report: dict) -> list:
    """report.md's verdict (the failures: exit code 1) and warnings of a calibration from
    photos, each a section only when it has entries."""
    lines = []
    if report.get("failures"):
        lines += ["## Verdict: failed (exit code 1)", ""] + [f"- {w}" for w in
                                                             report["failures"]] + [""]
    if report["warnings"]:
        lines += ["## Warnings", ""] + [f"- {w}" for w in report["warnings"]] + [""]
    return lines


def stereo_rms_failure(rms_px: dict, stereo_rms_px: float, what: str) -> list[str]:
    """The failure of an in-air stereo fit whose RMS is far above the cameras' own
    (:data:`STEREO_RMS_FACTOR`), as a one-item list; empty otherwise. ``what``: the images, in
    words."""
    worst = max(rms_px.values())
    if stereo_rms_px > STEREO_RMS_FACTOR * worst + STEREO_RMS_MARGIN_PX:
        diverged = stereo_rms_px > 1e4 * worst  # no pair of photos is that far from rigid
        return [f"the stereo RMS {stereo_rms_px:.3g} px is {stereo_rms_px / worst:.3g}× the "
                f"cameras' own ({worst:.3g} px): "
                + ("the stereo fit diverged — a lens model with more coefficients than these "
                   "poses determine (try a simpler --lens: k3 or standard)" if diverged else
                   f"the {what} do not fit one rigid pair of cameras")]
    return []


def air_failures(report: dict) -> list[str]:
    """Why an in-air photo calibration is known to be wrong (empty when it is not): poses whose
    own stereo pose disagrees with the others', a stereo RMS far above the cameras' own
    (:data:`STEREO_RMS_FACTOR`), an estimate whose σ exceeds it."""
    a = report["in_air"]
    out = []
    for p in report["per_pose"]:
        s = p.get("stereo") or {}
        if s.get("left_out"):
            out.append(f"pair {p['name']} disagrees with the others as a stereo pose (its right "
                       f"camera {s['deviation_mm']:.1f} mm and {s['deviation_deg']:.2f}° from "
                       f"the median pose; limits {s['threshold_mm']:.1f} mm, "
                       f"{s['threshold_deg']:.2f}°): left out of the stereo fit — are left/"
                       f"{p['name']} and right/{p['name']} one moment's photos, neither turned "
                       f"nor mirrored?")
    for cam, m in a["lens_models"].items():
        if m.get("problem"):
            out.append(f"the {cam} camera's {m['model']} lens model cannot be used: "
                       f"{m['problem']} (try --lens standard, or photograph the board near "
                       f"the image's edges and corners)")
    out += stereo_rms_failure(a["rms_px"], a["stereo_rms_px"], "two folders' photos")
    checks = [(f"{cam} {key}", v[key]["estimate"], v[key]["sigma"])
              for cam, v in a["cameras"].items() for key in ("fx", "fy")]
    s = a["stereo"]
    checks.append(("the baseline", s["baseline_mm"], s["baseline_sigma_mm"]))
    for what, value, sigma in checks:
        if sigma is not None and sigma > abs(value):
            out.append(f"the σ of {what} ({sigma:.3g}) exceeds its value ({value:.4g}): the "
                       f"photos do not determine it")
    return out


def worst_corners(residuals: dict, names, count: int = WORST_CORNERS) -> list[dict]:
    """The ``count`` corners farthest from the fit: ``{pose, view, id, residual_px}`` of
    ``residuals`` (per view ``(pose, id, du, dv)`` rows), largest first."""
    rows = [(float(np.hypot(du, dv)), int(k), view, int(i))
            for view, res in residuals.items() for k, i, du, dv in np.asarray(res).reshape(-1, 4)]
    rows.sort(key=lambda r: (-r[0], r[1], r[2], r[3]))
    return [{"pose": names[k], "view": VIEWS[v] if isinstance(v, int) else v, "id": i,
             "residual_px": r} for r, k, v, i in rows[:count]]


#: An in-air calibration whose every camera has k1 at least this (pincushion) looks like photos
#: taken through a flat port: rendered boards behind the paper's port calibrated with --air gave
#: k1 = +0.30 and fx 1.34 × the in-air one; in-air lenses show barrel distortion or next to none
#: (OpenCV's stereo sample −0.29, the GoPro frames −0.26).
PORT_LIKE_K1 = 0.1


def underwater_hint(cameras: dict, models: dict | None = None) -> str | None:
    """A warning when every camera's k1 (``{name: {"k1": {"estimate": …}}}``) is at least
    :data:`PORT_LIKE_K1`: underwater photos calibrated with ``--air`` (a calibration that absorbs
    the port). Not for the fisheye model (``models`` ``{name: lens model}``): its k1 is on the
    angle, and a plain pinhole lens has k1 = 1/3 there; nor for the rational model, whose k1
    is divided by a polynomial of its own (k4–k6): k1 alone says nothing of the distortion."""
    if models and {"fisheye", "rational"} & set(models.values()):
        return None
    k1 = {name: v["k1"]["estimate"] for name, v in cameras.items() if "k1" in v}
    if not k1 or min(k1.values()) < PORT_LIKE_K1:
        return None
    values = ", ".join(f"{name} {value:+.2f}" for name, value in k1.items())
    return (f"strong pincushion distortion (k1 {values}) is what a flat port does to a lens: if "
            f"these photos were taken under water, this calibration absorbs the port — calibrate "
            f"the housing with --intrinsics (the cameras' in-air calibration) instead of --air")


def per_pose_table(names, detections_all, detections_used, rms_per, outliers, geometry,
                   stereo=None, repeats=()) -> list:
    """One row per pose: name, corners per view, final RMS per view, status, distance, tilt;
    in air (``stereo`` = ``(stereo_poses, left_out)`` of the calibration) the pose's own
    stereo pose: baseline and distance from the median pose, and whether it was left out.
    ``repeats``: the poses left out because a view repeats another's."""
    rows = []
    for k, name in enumerate(names):
        corners = {v: int(len(detections_all.ids[k][i])) for i, v in enumerate(VIEWS)}
        if not any(corners.values()):
            status = "board not found"
        elif k in repeats:
            status = "left out: a view repeats another pose's (the report's repeats)"
        elif k in outliers["left_out"]:
            status = outlier_status(outliers, k)
        else:
            status = "used"
        rms = {v: rms_per.get((k, i)) if status == "used" else None
               for i, v in enumerate(VIEWS)}
        row = {"pose": k, "name": name, "corners": corners, "rms_px": rms, "status": status}
        if stereo is not None and k in stereo[0]:
            row["stereo"] = dict(stereo[0][k], left_out=k in stereo[1])
            if k in stereo[1]:
                row["status"] = "used alone; left out of the stereo fit (its stereo pose disagrees)"
        row.update(geometry.get(k, {"distance_mm": None, "tilt_deg": None}))
        rows.append(row)
    return rows


__all__ = ["COVERAGE_CELLS", "HIGH_CORRELATION", "MIN_COVERAGE", "MIN_TILT_DEG", "OUTLIER_RULE",
           "RECOMMENDED_POSES", "air_estimates", "board_hint", "corners_warning", "coverage",
           "fit_without_outliers", "housing_estimates", "larger_board",
           "outlier_corners", "outlier_poses", "outlier_status", "outlier_threshold",
           "per_pose_table", "pose_geometry", "stats_range", "stereo_scatter",
           "underwater_hint", "warnings_for", "without", "without_corners"]
