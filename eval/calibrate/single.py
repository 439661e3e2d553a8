"""``python -m eval calibrate DIR --air`` where ``DIR`` holds one camera's photos (no ``left/``
and ``right/``): OpenCV calibrates that camera alone.

The board on the command line as for a stereo folder; every photo in ``DIR`` (sorted by name) is
one pose. The lens model is chosen as for a pair (``--lens``, :func:`measure.calibration.
calibrate_camera`), outlier poses are left out by the same rule
(:func:`eval.calibrate.photos.outlier_poses`), and the report says what the photos alone can
say: per pose the corners and RMS, the worst corners, the coverage of the image, the σ of every
intrinsic (OpenCV's ``stdDeviationsIntrinsics``) and the photo-to-photo σ of fx, fy, cx, cy
(:func:`photo_spread`: the jackknife over the photos).

Writes to ``--out``: ``camera.yaml`` (OpenCV ``FileStorage``, the names of OpenCV's calibration
sample: ``image_width``, ``image_height``, ``camera_matrix``, ``distortion_coefficients``, with
``lens_model``, ``distortion_model`` (``brown_conrady`` or ``fisheye``: OpenCV's fisheye model,
k1…k4), ``rms_px``, the σ and — standard lens model — the ``covariance`` of the 8
intrinsics, :func:`camera_covariance`, and their photo-to-photo ``covariance_photos``
(:func:`photo_spread`), which the camera's housing calibration starts from:
:mod:`eval.calibrate.single_housing`), ``calibmar.yaml`` (calibmar's one-camera file, no port;
model OPENCV, FULL_OPENCV or OPENCV_FISHEYE), ``cameras.txt`` (one COLMAP camera),
``report.json``, ``report.md``, ``coverage.png`` and ``residuals.png``. A calibration the run
knows is wrong (a lens model whose distortion folds within the image, a σ of fx or fy larger
than the value) exits 1 with the files written.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from eval.calibrate import photos as trust
from eval.calibrate import photos_report
from eval.calibrate.board_size import LARGER_PHOTOS
from eval.calibrate import report as report_lib
from eval.calibrate.report import format_value as _f
from eval.cli import CLIError

#: The view number of the one camera in :class:`measure.calibration.Detections`.
VIEW = 0


def single_camera_folder(path) -> bool:
    """Whether ``path`` directly holds photos (one camera's folder)."""
    from eval.core.photos import PHOTO_EXTENSIONS

    return os.path.isdir(path) and any(
        os.path.splitext(name)[1].lower() in PHOTO_EXTENSIONS and not name.startswith(".")
        for name in os.listdir(path))


def read_and_detect(args, board, log, size=None, size_source=""):
    """One camera's photos ``args.dir`` read and the board detected in each (``--detections``:
    its detections files read): ``(names, images or None, size, detections, timings,
    aside)``, ``detections`` holding view 0 only, without the photos set aside (``aside``
    ``{pose: status}``: :func:`_set_aside`).
    ``size``: the image size the photos must have (``size_source`` names where it comes from);
    CLIError when they differ or the board is found in none of them."""
    from measure.calibration.air import Detections

    from eval.calibrate.sources import read_detection_views
    from eval.core.photos import encoding_note, photo_files, read_photo

    where = f"{args.dir} (one camera's photos)"
    if getattr(args, "detections", False):
        t = time.perf_counter()
        names, detections, found_size = read_detection_views(args, board, 1)
        if size is not None and tuple(size) != tuple(found_size):
            raise CLIError(f"{size_source}: image size {size[0]}x{size[1]} px, but --image-size "
                           f"says {found_size[0]}x{found_size[1]} px")
        detections, aside = _set_aside(detections, board, found_size, args, names)
        return names, None, found_size, detections, {"read": time.perf_counter() - t}, aside
    files = photo_files(args.dir)
    log(f"read {len(files)} photos from {args.dir} and detect the board …")
    note = encoding_note(files[0], args.encoding)
    if note:
        print(note, file=sys.stderr, flush=True)
    t = time.perf_counter()
    shapes, found_all, kept = _read_and_detect_each(files, board, args.encoding)
    timings = {"read_and_detect": time.perf_counter() - t}
    size = _one_size(files, shapes, size, size_source)
    empty = (np.empty(0, int), np.empty((0, 2)))
    detections = Detections([[ids, empty[0]] for ids, _ in found_all],
                            [[px, empty[1]] for _, px in found_all])
    names = [os.path.basename(f) for f in files]
    detections, aside = _set_aside(detections, board, size, args, names)
    found = detections.found(VIEW)
    if not found:
        squares = "x".join(map(str, board.squares))
        first = [read_photo(f, args.encoding) for f in files[:trust.HINT_PHOTOS]]
        raise CLIError(f"{where}: the {board.kind} {squares} was found in none of the "
                       f"{len(files)} photos{trust.board_hint(board, [(im, im) for im in first])}")
    larger = trust.larger_board(board, {k: (im, im) for k in found[:LARGER_PHOTOS]
                                        for im in [read_photo(files[k], args.encoding)]}, found)
    if larger:  # a part of the board, a different part in each photo: a nonsense fit
        raise CLIError(f"{where}: {larger}")
    charuco = trust.charuco_check(board, [kept[k] for k in found if k in kept])
    if charuco:
        raise CLIError(f"{where}: {charuco}")
    return names, None, size, detections, timings, aside


def note_set_aside(report: dict, aside: dict, names) -> None:
    """One camera's photos set aside before the fit (``aside`` ``{pose: why}``: repeats,
    thinned) into ``report``: named, warned of (but thinning), their status in the per-pose
    table, and counted among the photos the board was found in."""
    report["set_aside"] = {names[k]: why for k, why in sorted(aside.items())}
    report["warnings"] += [f"{names[k]}: {why}" for k, why in sorted(aside.items())
                           if "thinned" not in why]
    for row in report["per_pose"]:
        row["status"] = aside.get(row["pose"], row["status"])
    report["found"] += len(aside)  # found, then set aside


def _set_aside(detections, board, size, args, names):
    """``(detections, aside {pose: status})``: the photos that repeat an earlier one
    (:func:`eval.calibrate.sources.repeated_views`) and, of more than ``--max-poses``, the
    least different (:func:`eval.calibrate.sources.thin_by_pose`) left out, each with the
    status the report gives it; a ``note:`` line when poses were thinned."""
    from eval.calibrate.sources import (MAX_POSES, repeat_lines, repeated_views, thin_by_pose)

    repeats = repeated_views(detections, views=(0,))
    aside = {r["pose"]: f"left out: {line} (a photo given twice is one pose)"
             for r, line in zip(repeats, repeat_lines(repeats, names, ("",)))}
    detections = trust.without(detections, sorted(aside))
    limit = getattr(args, "max_poses", None) or MAX_POSES
    before = detections.found(VIEW)
    detections, kept = thin_by_pose(detections, board, size, limit)
    if len(kept) < len(before):
        print(f"note: the board in {len(before)} photos: the {len(kept)} most different poses "
              f"kept (--max-poses {limit})", file=sys.stderr)
        aside.update({k: f"left out: thinned (--max-poses {limit})"
                      for k in set(before) - set(kept)})
    return detections, aside


def _read_and_detect_each(files, board, encoding):
    """``(shapes, [(ids, pixels)], kept)``: each photo read and the board detected in it, on a
    thread per core (OpenCV's reading and detectors release the GIL), the photos themselves
    not kept (a hundred 12-megapixel photos are 5 GB as float32) but the first
    :data:`eval.calibrate.photos.HINT_PHOTOS` where the board was found (``kept``, by index:
    what :func:`eval.calibrate.photos.charuco_check` looks at)."""
    from concurrent.futures import ThreadPoolExecutor

    from eval.core.photos import read_photo

    def one(path):
        image = read_photo(path, encoding)
        ids, pixels = board.detect(image)
        return image.shape[:2], ids, pixels, image if board.kind == "charuco" else None

    with ThreadPoolExecutor(max(1, min(os.cpu_count() or 1, len(files)))) as pool:
        results = list(pool.map(one, files))
    kept = {k: r[3] for k, r in enumerate(results) if r[3] is not None and len(r[1])}
    kept = {k: kept[k] for k in sorted(kept)[:trust.HINT_PHOTOS]}
    return [r[0] for r in results], [(r[1], r[2]) for r in results], kept


def _one_size(files, shapes, size, size_source):
    """The photos' one size (width, height); CLIError when they differ or are not ``size``
    (``size_source`` says where that comes from)."""
    sizes = [(w, h) for h, w in shapes]
    odd = next((f for f, s in zip(files, sizes) if s != sizes[0]), None)
    if odd is not None:
        got = sizes[files.index(odd)]
        raise CLIError(f"{odd}: {got[0]}x{got[1]} px, but {files[0]} is {sizes[0][0]}x"
                       f"{sizes[0][1]} px (one camera's photos must all have one size)")
    if size is not None and tuple(size) != sizes[0]:
        raise CLIError(f"{size_source}: image size {size[0]}x{size[1]} px, but the photos are "
                       f"{sizes[0][0]}x{sizes[0][1]} px")
    return sizes[0]


def calibrate_single(args, output, log, start, board) -> tuple[dict, str]:
    """Calibrate the camera of the photo folder ``args.dir``; returns ``(report, summary)``
    after writing everything into ``output`` (module docs)."""
    from measure.calibration.air import DEFAULT_LENS_MODEL, CalibrationError, calibrate_fisheye
    from measure.calibration.air import fit_camera

    from eval.calibrate.dots import views_of_camera, with_eccentricity

    where = f"{args.dir} (one camera's photos)"
    names, images, size, detections, timings, aside = read_and_detect(args, board, log)
    lens = args.lens or DEFAULT_LENS_MODEL
    corners = board.corners().astype(np.float32)

    def fit(dets):
        own = fit_camera(corners, dets, VIEW, "camera", size, lens)
        out, model, tried = own.out, own.model, dict(own.tried)
        if lens == "auto":  # the fisheye model's RMS beside them, for the user to choose
            try:
                tried["fisheye"] = float(calibrate_fisheye(own.obj, own.img, size)[0])
            except CalibrationError:
                tried["fisheye"] = float("nan")
        return {"out": out, "model": model, "tried": tried, "problem": own.problem,
                "poses": own.poses, "residuals": own.residuals,
                "rms_px_per": {(k, VIEW): e for k, e in own.rms_px_per.items()},
                "covariance": camera_covariance(own.obj, out) if model == "standard" else None}

    t = time.perf_counter()
    log("calibrate the camera (OpenCV calibrateCamera) …")
    try:
        result, used_detections, outliers = trust.fit_without_outliers(
            with_eccentricity(fit, board, views_of_camera(size)), lambda r: r["rms_px_per"],
            detections, lambda r: {VIEW: r["residuals"]}, board)
    except CalibrationError as exc:
        raise CLIError(f"{where}: {exc}") from None
    timings["calibrate"] = time.perf_counter() - t
    camera, sigmas = _camera(result, size)
    t = time.perf_counter()
    spread, spread_covariance = photo_spread(used_detections, result, corners, size)
    timings["leave_one_out"] = time.perf_counter() - t
    report = _report(args, board, names, size, detections, used_detections, result, outliers,
                     camera, sigmas, result["problem"])
    note_set_aside(report, aside, names)
    for key, value in spread.items():
        report["camera"][key]["sigma_photos"] = value
    report["timings_s"] = timings
    log("write the calibration, report and figures …")
    with output.staged() as tmp:
        write_camera_files(tmp, camera, report["lens_model"]["model"], report["rms_px"],
                           {k: v["sigma"] for k, v in report["camera"].items()
                            if v["sigma"] is not None}, result["covariance"],
                           extra_covariances={"covariance_photos": spread_covariance})
        report_lib.residual_figure(tmp, used_detections, {VIEW: result["residuals"]}, size,
                                   views=("camera",))
        photos_report.coverage_figure(tmp, detections, set(result["poses"]), size,
                              {"coverage": {"camera": report["coverage"]}}, views=("camera",))
        report = report_lib.write_report(tmp, report, markdown, start)
    return report, summary_lines(report)


#: The distortion coefficients each Brown–Conrady lens model fits (indices into OpenCV's
#: ``k1 k2 p1 p2 k3 k4 k5 k6``).
FREE_DISTORTION = {"standard": (0, 1, 2, 3), "k3": (0, 1, 2, 3, 4), "rational": tuple(range(8)),
                   "radial": (0, 1)}


def photo_spread(detections, result, corners, size):
    """``({fx, fy, cx, cy: σ}, covariance)`` from the photos themselves: the jackknife over
    the photos used, ``(n − 1)/n Σ (θ_i − θ̄)(θ_i − θ̄)ᵀ`` of the intrinsics with photo i left
    out, σ in px. OpenCV's σ takes every corner's error as independent; on real photos a
    photo's corners share its errors (motion, a board not quite flat, a rolling shutter), and
    which photos are kept moves the intrinsics by more (docs/calibration.md: fx ± 0.19 % by
    OpenCV, 0.8 % by the photos, on the GoPro frames). Each θ_i is one Gauss–Newton step from
    the fit of all photos without photo i (:func:`_left_out_steps`; the Brown–Conrady models)
    — within 1–5 % of refitting without each photo on three real sets, and at no cost where
    the refits took 24 s for 28 photos; the fisheye model is refitted. ``covariance``: of the
    8 intrinsics fx fy cx cy k1 k2 p1 p2 named as :func:`camera_covariance`'s (standard lens
    model; else None), what a housing calibration can take as the in-air calibration's
    spread. Empty and None for fewer than 4 photos."""
    from measure.calibration.covariance import AIR_INTRINSICS
    from measure.stereo.rig_covariance import CovarianceError, RigCovariance

    poses = result["poses"]
    if len(poses) < 4:
        return {}, None
    obj = [corners[detections.ids[k][VIEW]] for k in poses]
    img = [detections.pixels[k][VIEW].astype(np.float32) for k in poses]
    if result["model"] in FREE_DISTORTION:
        values = _left_out_steps(obj, img, result["out"], result["model"])
    else:
        values = _left_out_refits(obj, img, size, result["model"])
    n = len(values)
    centred = values - values.mean(axis=0)
    covariance = (n - 1) / n * centred.T @ centred
    sigma = np.sqrt(np.diag(covariance))
    named = None
    if result["model"] == "standard":
        try:
            named = RigCovariance([f"left.{p}" for p in AIR_INTRINSICS], covariance)
        except CovarianceError:
            named = None
    return {key: float(v) for key, v in zip(("fx", "fy", "cx", "cy"), sigma)}, named


def _left_out_steps(obj, img, out, model) -> np.ndarray:
    """``(n, 4 + d)``: the intrinsics (fx fy cx cy and the model's free distortion
    coefficients) with each photo left out, by one Gauss–Newton step from the fit of all of
    them ``out`` (``cv2.calibrateCameraExtended``'s): with each photo's board pose profiled out
    (its 6 columns ``B`` eliminated from its rows ``A``), ``M_i = AᵀA − AᵀB (BᵀB)⁻¹ BᵀA`` and
    ``g_i = Aᵀr − AᵀB (BᵀB)⁻¹ Bᵀr``; at the optimum Σ g_i = 0, so without photo i
    ``θ_i = θ̂ + (Σ M − M_i)⁻¹ g_i`` (r = projected − detected, px; ``cv2.projectPoints``'s
    Jacobian)."""
    import cv2

    K, D = out[1], np.ravel(out[2])
    free = 10 + np.asarray(FREE_DISTORTION[model])
    theta = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], D[free - 10]]
    Ms, gs = [], []
    for o, i, rvec, tvec in zip(obj, img, out[3], out[4]):
        p, J = cv2.projectPoints(np.asarray(o, np.float64), rvec, tvec, K, D)
        r = (p.reshape(-1, 2) - np.asarray(i, np.float64).reshape(-1, 2)).ravel()
        B, A = J[:, :6], J[:, np.r_[6:10, free]]
        AB = A.T @ B
        S = np.linalg.inv(B.T @ B)
        Ms.append(A.T @ A - AB @ S @ AB.T)
        gs.append(A.T @ r - AB @ (S @ (B.T @ r)))
    total = np.sum(Ms, axis=0)
    return np.array([theta + np.linalg.solve(total - M, g) for M, g in zip(Ms, gs)])


def _left_out_refits(obj, img, size, model) -> np.ndarray:
    """``(n, 4 + d)``: the intrinsics of ``model`` refitted with each photo left out."""
    from measure.calibration.air import calibrate_camera

    values = []
    for drop in range(len(obj)):
        out = calibrate_camera([o for k, o in enumerate(obj) if k != drop],
                               [i for k, i in enumerate(img) if k != drop], size, model)[0]
        K, dist = out[1], np.ravel(out[2])
        values.append([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *dist[:4]])
    return np.asarray(values)


def _camera(result, size):
    """The :class:`measure.Camera` of a fit and its σ per intrinsic."""
    from measure.calibration.air import intrinsic_names, lens_camera

    out, model = result["out"], result["model"]
    camera = lens_camera(out, model, size)
    sigmas = dict(zip(intrinsic_names(model), (float(s) for s in out[5].ravel())))
    return camera, sigmas


def _report(args, board, names, size, detections, used, result, outliers, camera, sigmas,
            problem) -> dict:
    used_poses = result["poses"]
    rms = float(result["out"][0])
    rows = photo_rows(names, detections, outliers, result["rms_px_per"])
    coverage = trust.coverage(used, size)["left"]
    estimates = trust.camera_estimates(camera, sigmas)
    failures = []
    if problem:
        failures.append(f"the {result['model']} lens model cannot be used: {problem} (try --lens "
                        f"standard, or photograph the board near the image's edges and corners)")
    for key in ("fx", "fy"):
        e = estimates[key]
        if e["sigma"] is not None and e["sigma"] > abs(e["estimate"]):
            failures.append(f"the σ of {key} ({e['sigma']:.3g}) exceeds its value "
                            f"({e['estimate']:.4g}): the photos do not determine it")
    warnings = []
    if len(used_poses) < trust.RECOMMENDED_POSES:
        warnings.append(f"only {len(used_poses)} photo(s) used; at least "
                        f"{trust.RECOMMENDED_POSES} are recommended")
    if coverage["fraction"] < trust.MIN_COVERAGE:
        warnings.append(f"the corners cover {100 * coverage['fraction']:.0f} % of the image "
                        f"({trust.COVERAGE_CELLS}×{trust.COVERAGE_CELLS} cells): the lens "
                        f"distortion is extrapolated outside them")
    hint = trust.underwater_hint({"camera": estimates}, {"camera": result["model"]})
    if hint:
        warnings.append(hint)
    edge = trust.unseen_edge(board, detections, (VIEW,))
    if edge:
        warnings.append(edge)
    if outliers["left_out"]:
        warnings.append(f"{len(outliers['left_out'])} outlier photo(s) left out of the final "
                        f"fit: {', '.join(names[k] for k in outliers['left_out'])}")
    if trust.corners_warning(outliers):
        warnings.append(trust.corners_warning(outliers))
    return {"photos": os.path.abspath(args.dir), "source": "photos", "air": True,
            "cameras": 1, "board": board.to_dict(), "image_size": list(size),
            "poses": len(names), "found": len(detections.found(VIEW)), "used": len(used_poses),
            "outlier_rule": trust.OUTLIER_RULE, "outliers": outliers, "per_pose": rows,
            "coverage": coverage, "lens_model": {"model": result["model"],
                                                 "rms_px": result["tried"], "problem": problem},
            "rms_px": rms, "camera": estimates,
            "worst_corners": trust.worst_corners({"camera": result["residuals"]}, names),
            "warnings": warnings, "failures": failures}


def camera_covariance(obj, out):
    """The covariance of one camera's 8 intrinsics fx fy cx cy k1 k2 p1 p2 from its
    ``calibrateCameraExtended`` output ``out`` (the standard lens model, k3 fixed) and the board
    corners ``obj`` per pose: :func:`measure.calibration.covariance.camera_map` ``A`` (the
    linear map of the corners' noise to the intrinsics, board poses marginalized) times the
    residual variance ``Σr² / (2n − 8 − 6P)``: ``s² A Aᵀ``, named ``left.fx`` … (the camera is
    the reference camera, :data:`measure.calibration.covariance.AIR_NAMES`)."""
    from measure.calibration.covariance import AIR_INTRINSICS, camera_map
    from measure.stereo.rig_covariance import CovarianceError, RigCovariance

    n = sum(len(o) for o in obj)
    A, columns = camera_map([np.asarray(o, np.float64) for o in obj], out[3], out[4], out[1],
                            out[2])
    s2 = float(out[0]) ** 2 * n / max(2 * n - columns, 1)
    try:
        return RigCovariance([f"left.{p}" for p in AIR_INTRINSICS], s2 * A @ A.T)
    except CovarianceError:  # e.g. noise-free corners: no covariance to give
        return None


def write_camera_files(directory, camera, lens_model, rms_px, sigmas: dict, covariance=None,
                       port=None, extra=None, other_formats: bool = True,
                       extra_covariances=None) -> None:
    """``camera.yaml``, ``calibmar.yaml`` and ``cameras.txt`` of one camera (module docs):
    ``lens_model`` (or None), the fit's ``rms_px``, ``sigmas`` ``{intrinsic: σ}``.
    ``covariance``: a ``covariance`` node (``names``, ``matrix``, ``normal_axes`` where it has
    them) in ``camera.yaml``; ``extra_covariances`` ``{node: covariance}`` more of them (the
    photo-to-photo ``covariance_photos``). ``port``:
    the camera's housing (a rig port whose view 0 is the camera's), written as calib.yaml's
    ``port`` or a ``dome`` node in ``camera.yaml`` (mm, the camera's frame) and as FLATPORT or
    DOMEPORT in the other two; ``extra``: further maps (:func:`synth.products.dataset.
    write_calib`'s ``extra``, e.g. the housing's σ). ``other_formats`` False: ``camera.yaml``
    only (a port of several layers, which FLATPORT cannot hold)."""
    import cv2

    from measure.geometry.flatport_format import write_view_port

    from synth.formats.calib_formats import write_single_camera
    from synth.formats.calib_yaml import write_node

    # the output folder is staged whole: its files appear together or not at all
    fs = cv2.FileStorage(os.path.join(directory, "camera.yaml"), cv2.FILE_STORAGE_WRITE)
    try:
        fs.write("image_width", int(camera.size[0]))
        fs.write("image_height", int(camera.size[1]))
        fs.write("camera_matrix", camera.K)
        dist = np.zeros(5) if camera.dist is None else camera.dist
        fs.write("distortion_coefficients", np.asarray(dist, np.float64).reshape(1, -1))
        if lens_model:
            fs.write("lens_model", lens_model)
        # how distortion_coefficients are evaluated: brown_conrady (cv2.projectPoints) or
        # fisheye (cv2.fisheye, k1…k4)
        fs.write("distortion_model", camera.distortion_model)
        fs.write("rms_px", float(rms_px))
        if sigmas:
            fs.startWriteStruct("sigmas", cv2.FileNode_MAP)
            for key, value in sigmas.items():
                fs.write(key, float(value))
            fs.endWriteStruct()
        fs.write("units", "px (OpenCV pixels: the centre of the top-left pixel is 0, 0)")
        for node, value in {"covariance": covariance, **(extra_covariances or {})}.items():
            if value is not None:
                _write_covariance(fs, node, value)
        if port is not None:
            fs.write("port_units", "mm (the camera's frame)")
            write_view_port(fs, port.view(0))
        for name, value in (extra or {}).items():
            write_node(fs, name, value)
    finally:
        fs.release()
    if other_formats:
        write_single_camera(directory, camera, port)


def _write_covariance(fs, node: str, covariance) -> None:
    """A :class:`RigCovariance` as a FileStorage map ``node`` (``names``, ``matrix``,
    ``normal_axes`` where it has them)."""
    import cv2

    fs.startWriteStruct(node, cv2.FileNode_MAP)
    fs.startWriteStruct("names", cv2.FileNode_SEQ)
    for name in covariance.names:
        fs.write("", name)
    fs.endWriteStruct()
    fs.write("matrix", covariance.matrix)
    if covariance.normal_axes is not None:
        fs.write("normal_axes", covariance.normal_axes)
    fs.endWriteStruct()


def photo_rows(names, detections, outliers, rms_px_per, posed=None) -> list:
    """The report's ``per_pose`` of one camera's photos: each photo's corners, status (board not
    found, left out as an outlier, left out with no starting pose — where ``posed``, the
    photos the fit had a pose for, is given — or used) and RMS ``rms_px_per[(k, VIEW)]``."""
    rows = []
    for k, name in enumerate(names):
        n = int(len(detections.ids[k][VIEW]))
        if not n:
            status = "board not found"
        elif k in outliers["left_out"]:
            status = trust.outlier_status(outliers, k)
        elif posed is not None and k not in posed:
            status = "left out: no starting pose (solvePnP)"
        else:
            status = "used"
        rows.append({"pose": k, "name": name, "corners": n, "status": status,
                     "rms_px": rms_px_per.get((k, VIEW)) if status == "used" else None})
    return rows


def photo_lines(report: dict) -> list:
    """report.md's photos of one camera: the outlier rule, each photo's corners, RMS and status,
    the coverage of the image and the worst corners (also the one-camera housing's report)."""
    lines = ["## Photos", "", f"Outlier rule: {report['outlier_rule']} (threshold here "
             f"{report['outliers']['threshold_px']:.3f} px).", "",
             "| photo | corners | RMS (px) | status |", "|---|---|---|---|"]
    lines += [f"| {p['name']} | {p['corners']} | {_f(p['rms_px'])} | {p['status']} |"
              for p in report["per_pose"]]
    lines += ["", f"Corners cover {100 * report['coverage']['fraction']:.0f} % of the image "
              f"({trust.COVERAGE_CELLS}×{trust.COVERAGE_CELLS} cells; `coverage.png`).", "",
              "## Worst corners", "", "| photo | corner id | residual (px) |", "|---|---|---|"]
    lines += [f"| {c['pose']} | {c['id']} | {c['residual_px']:.3f} |"
              for c in report["worst_corners"]]
    return lines


def markdown(report: dict) -> str:
    b = report["board"]
    lines = [f"# Camera calibration report: `{report['photos']}`", "",
             f"{report['poses']} photos ({report['image_size'][0]}x{report['image_size'][1]} px) "
             f"of one camera, in air, a {b['kind']} of {b['squares'][0]}x{b['squares'][1]} "
             f"squares ({b['squares'][0] - 1}x{b['squares'][1] - 1} inner corners), "
             f"{b['square_mm']:g} mm; board found in {report['found']}, {report['used']} in the "
             f"final fit. No truth: every number below comes from the photos.", ""]
    lines += trust.verdict_lines(report)
    m = report["lens_model"]
    lines += ["## Camera (OpenCV)", "",
              f"Reprojection RMS {report['rms_px']:.4f} px; lens model {m['model']} ("
              + ", ".join(f"{k} {v:.4f} px" if v is not None else f"{k} no fit"
                          for k, v in m["rms_px"].items())
              + f"; {trust.LENS_RULE}"
              + ("; the fisheye model's RMS is listed for comparison: it is used with --lens "
                 "fisheye" if "fisheye" in m["rms_px"] and m["model"] != "fisheye" else "")
              + "). σ: OpenCV's `calibrateCameraExtended` standard "
              "deviations (the fisheye model's computed as it does, s² (JᵀJ)⁻¹); σ photos: "
              "the jackknife over the photos, each left out in turn (the spread which photos "
              "are kept gives).", "", "| parameter | value | σ | σ photos |", "|---|---|---|---|"]
    lines += [f"| {k} | {v['estimate']:.6g} | {_f(v['sigma'], 3)} | "
              f"{_f(v.get('sigma_photos'), 3) if 'sigma_photos' in v else ''} |"
              for k, v in report["camera"].items()]
    lines += ["", *photo_lines(report)]
    lines += ["", "## Files", "", "- `camera.yaml` (OpenCV FileStorage), `calibmar.yaml` "
              "(calibmar, no port), `cameras.txt` (COLMAP)",
              "- `coverage.png`, `residuals.png` (residual vectors per photo)", "",
              "## Timings (s)", "",
              " · ".join(f"{k} {v:.2f}" for k, v in report["timings_s"].items())]
    return "\n".join(lines) + "\n"


def summary_lines(report: dict) -> str:
    b, c = report["board"], report["camera"]
    not_found = [p["name"] for p in report["per_pose"] if p["status"] == "board not found"]
    lines = [f"{report['photos']}: one camera; board found in {report['found']}/"
             f"{report['poses']} photos; {report['used']} used"
             + (f", not found in {', '.join(not_found)}" if not_found else ""),
             f"board: {b['kind']} of {b['squares'][0]}x{b['squares'][1]} squares "
             f"({b['squares'][0] - 1}x{b['squares'][1] - 1} inner corners, OpenCV's pattern "
             f"size), {b['square_mm']:g} mm",
             f"lens model: {report['lens_model']['model']} (--lens; the report lists the RMS of "
             f"each model tried)",
             f"camera: fx {c['fx']['estimate']:.3f} ± {_f(c['fx']['sigma'], 2)}, fy "
             f"{c['fy']['estimate']:.3f} ± {_f(c['fy']['sigma'], 2)}, cx "
             f"{c['cx']['estimate']:.3f} ± {_f(c['cx']['sigma'], 2)}, cy "
             f"{c['cy']['estimate']:.3f} ± {_f(c['cy']['sigma'], 2)} px; RMS "
             f"{report['rms_px']:.4f} px",
             *([f"photo-to-photo σ (each photo left out in turn): fx ± "
                f"{c['fx']['sigma_photos']:.2g}, fy ± {c['fy']['sigma_photos']:.2g}, cx ± "
                f"{c['cx']['sigma_photos']:.2g}, cy ± {c['cy']['sigma_photos']:.2g} px"]
               if "sigma_photos" in c["fx"] else []),
             f"corners cover {100 * report['coverage']['fraction']:.0f} % of the image"]
    lines += [f"warning: {w}" for w in report["warnings"]]
    return "\n".join(lines)


__all__ = ["calibrate_single", "markdown", "photo_spread", "single_camera_folder", "summary_lines",
           "write_camera_files"]
