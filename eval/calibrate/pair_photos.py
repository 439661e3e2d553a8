"""``eval calibrate PHOTOS`` of a pair's own photos (``DIR/left/``, ``DIR/right/``, paired by
name) or, ``--detections``, of its detection files: no truth beside them, so the report says
what can be trusted from the photos themselves (:mod:`eval.calibrate.photos`,
:mod:`eval.calibrate.photos_report`).

The stages of :func:`calibrate_pair_photos`: the options checked (``--air`` or ``--intrinsics``,
the board, the design) before any photo is read; the corners found (photos read and detected,
or detection files read) and the poses kept (a pose given twice is one; many poses thinned by
their diversity); the fit without outliers — in air OpenCV's, under water the housing's
refractive bundle adjustment, again from each camera's own port when the design start fails;
then the report, the files, the figures and the printed summary. Lengths mm, pixels px, times s.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass

from eval.calibrate.design import design_pair, design_port, pair_glass
from eval.calibrate.intrinsics import intrinsics_for_photos, underwater_note
from eval.calibrate.options import LENS_UNDERWATER, require_air_or_intrinsics, require_board
from eval.calibrate.outputs import failed, print_written, write_calibrations
from eval.calibrate.port_lengths import lengths_for
from eval.cli import CLIError
from eval.core.photos import encoding_note
from synth.infra.cli import EXIT_CHECK_FAILED, board_from_args, given, refuse_given


@dataclass
class _Corners:
    """A pair's board corners, per pose (``names``) and view: all of them
    (``detections_all``), and those the fit is given (``detections``: repeats left out, the
    poses thinned to ``thinned``); ``size`` the image size (px)."""
    names: list
    size: tuple
    detections_all: object
    detections: object
    found: dict
    not_found: list
    repeats: list
    thinned: list
    timings: dict


@dataclass
class _PairFit:
    """The fit without outliers: ``result`` (in air the OpenCV calibration, under water the
    housing, then also ``housing``), the detections it used and its outliers; under water the
    in-air covariance, the start rig and each camera fitted alone (when the design start
    failed); in air the covariance of the in-air fit."""
    result: object
    used_detections: object
    outliers: dict
    housing: object = None
    air_covariance: object = None
    start_rig: object = None
    alone: object = None

    @property
    def rms_per(self) -> dict:
        """The RMS (px) per ``(pose, view)`` of the fit."""
        return self.result.rms_px_per

    @property
    def poses(self) -> dict:
        """The board pose of each pose: in air the left camera's where it has one."""
        if self.housing is None:
            return {k: self.result.board_poses.get((k, 0), pose)
                    for (k, _), pose in self.result.board_poses.items()}
        return dict(zip(self.housing.pose_ids, self.housing.poses))


def calibrate_pair_photos(args, output, log, free, start) -> int:
    """``eval calibrate`` of a pair's photo folder or detections (module docs); ``free`` the
    housing's parameters to estimate (:func:`eval.calibrate.design.parse_free`)."""
    from eval.calibrate import photos_report
    from eval.calibrate import report as report_lib

    where = f"{args.dir} ({'detections' if args.detections else 'photos'})"
    board, pair = _checked_options(args, where)
    air_rig = air_covariance = None
    if not args.air:
        air_rig, air_covariance = intrinsics_for_photos(args.intrinsics, log)
    corners = _corners(args, board, log, where, air_rig)
    t = time.perf_counter()
    fit = _fitter(corners.detections, board, where)
    if args.air:
        fitted = _fit_in_air(args, fit, board, corners.size, log)
        corners.timings["calibrate"] = time.perf_counter() - t
    else:
        fitted = _fit_housing(args, fit, board, corners.detections, free, air_rig,
                              air_covariance, pair, log)
        corners.timings["bundle_adjustment"] = time.perf_counter() - t
        if not fitted.housing.identifiable:
            return _no_housing(args, fitted, board, corners.detections, free, where)
    report = _report(args, board, corners, fitted)
    _add_estimates(report, args, board, fitted, free, corners.names, log)
    _add_warnings_and_failures(report, args, board, corners, fitted, pair)
    report["timings_s"] = corners.timings
    log("write the calibration, report and figures …")
    used = sorted({k for k, _ in fitted.rms_per})
    with output.staged() as tmp:
        write_calibrations(tmp, fitted.result.rig, fitted.housing, report,
                           None if args.air else fitted.start_rig, fitted.air_covariance)
        report_lib.residual_figure(tmp, fitted.used_detections, fitted.result.residuals,
                                   corners.size)
        photos_report.coverage_figure(tmp, corners.detections, set(used), corners.size, report)
        report = report_lib.write_report(tmp, report, photos_report.markdown, start)
    code = print_written(output, photos_report.summary_lines(report), args,
                         fitted.housing is not None)
    return failed(args.dir, report["failures"], output.path) or code


def _checked_options(args, where):
    """``(board, pair)``: the options checked before any photo is read — ``--air`` or
    ``--intrinsics`` and what each refuses, the board, and the design (``pair``: two housings,
    a port per camera, ``--port-distance``)."""
    require_air_or_intrinsics(args, where, "the in-air calibration")
    if not args.air:
        refuse_given(args, ("lens",), LENS_UNDERWATER)
    require_board(args, where)
    board = board_from_args(args)
    pair = given(args, "port_distance")  # two housings: a port per camera
    if pair and not args.air:
        pair_glass(args)  # a bad design is refused before any work
        lengths_for(args.port_distance, 2)
    elif not args.air:
        design_port(args, (0.0, 0.0, 1.0))  # a bad --design-port is refused before any work
    return board, pair


def _corners(args, board, log, where, air_rig) -> _Corners:
    """The pair's corners (:func:`_read_corners`), checked against the in-air calibration's
    image size, without repeated poses and thinned to ``--max-poses`` (a note on stderr when
    poses were left out)."""
    from eval.calibrate import photos as trust
    from eval.calibrate.sources import MAX_POSES, repeated_views, thin_by_pose, without_repeats

    names, _, size, detections, timings = _read_corners(args, board, log, where, air_rig)
    found = {v: detections.found(i) for i, v in enumerate(trust.VIEWS)}
    not_found = [names[k] for k in range(len(names))
                 if k not in found["left"] and k not in found["right"]]
    repeats = repeated_views(detections)
    detections_all, detections = detections, without_repeats(detections, repeats)
    before = len(set(detections.found(0)) | set(detections.found(1)))
    detections, thinned = thin_by_pose(detections, board, size, args.max_poses or MAX_POSES)
    if len(thinned) < before:
        print(f"note: the board in {before} pairs: the {len(thinned)} most different poses kept "
              f"(--max-poses {args.max_poses or MAX_POSES})", file=sys.stderr)
    return _Corners(names, size, detections_all, detections, found, not_found, repeats, thinned,
                    timings)


def _check_intrinsics_size(args, air_rig, size) -> None:
    """CLIError where the in-air calibration ``air_rig`` (None: ``--air``) is of another image
    size than the photos or detections (``size``, px): said before any board is detected."""
    if air_rig is not None and tuple(air_rig.left.size) != tuple(size):
        raise CLIError(f"--intrinsics {args.intrinsics}: image size "
                       f"{air_rig.left.size[0]}x{air_rig.left.size[1]} px, but the "
                       f"{'detections are' if args.detections else 'photos are'} "
                       f"{size[0]}x{size[1]} px")


def _read_corners(args, board, log, where, air_rig):
    """``(names, images or None, size, detections, timings)`` of a pair's photos (read and
    detected) or, ``--detections``, of its detection files; CLIError where the board is in no
    photo, the photos show another board (photos only: the checks need the images) or are of
    another size than the in-air calibration ``air_rig`` (checked before the detection)."""
    from measure.calibration.air import detect_boards

    from eval.calibrate import photos as trust
    from eval.calibrate.sources import read_detection_views
    from eval.core.photos import photo_folder, read_pairs

    t = time.perf_counter()
    if args.detections:
        names, detections, size = read_detection_views(args, board, 2)
        _check_intrinsics_size(args, air_rig, size)
        return names, None, size, detections, {"read": time.perf_counter() - t}
    pairs = photo_folder(args.dir)
    log(f"read {len(pairs.names)} photo pairs from {args.dir} …")
    note = encoding_note(pairs.left[0], args.encoding) if pairs.left else None
    if note:
        print(note, file=sys.stderr, flush=True)
    images, size = read_pairs(pairs, args.encoding)
    _check_intrinsics_size(args, air_rig, size)
    timings = {"read": time.perf_counter() - t}
    log(f"detect the board in {len(images)} photo pairs …")
    t = time.perf_counter()
    detections = detect_boards(board, images)
    timings["detect"] = time.perf_counter() - t
    found = {v: detections.found(i) for i, v in enumerate(trust.VIEWS)}
    if not found["left"] and not found["right"]:
        squares = "x".join(map(str, board.squares))
        raise CLIError(f"{where}: the {board.kind} {squares} was found in none of the "
                       f"{len(images)} photo pairs{trust.board_hint(board, images)}")
    larger = trust.larger_board(board, images, found["left"])
    if larger:
        raise CLIError(f"{where}: {larger}")
    charuco = trust.charuco_check(board, [images[k][0] for k in found["left"]])
    if charuco:
        raise CLIError(f"{where}: {charuco}")
    return list(pairs.names), images, size, detections, timings


def _fitter(detections, board, where):
    """The fit without outliers of ``detections`` (:func:`eval.calibrate.photos.
    fit_without_outliers`) for a calibration ``calibrate(detections)``: ``(result, used
    detections, outliers)``; a CalibrationError (too few poses) names the photo folder."""
    from measure.calibration.air import CalibrationError

    from eval.calibrate import photos as trust

    def fit(calibrate):
        try:
            return trust.fit_without_outliers(
                calibrate, lambda r: r.rms_px_per, detections, lambda r: r.residuals, board,
                lambda r: getattr(r, "identifiable", True))
        except CalibrationError as exc:
            raise CLIError(f"{where}: {exc}") from None

    return fit


def _fit_in_air(args, fit, board, size, log) -> _PairFit:
    """OpenCV's calibration of both cameras and the stereo pose (``--lens``), outliers out."""
    from measure.calibration.air import DEFAULT_LENS_MODEL, calibrate_in_air

    from eval.calibrate.dots import views_of_air, with_eccentricity

    log("calibrate in air (OpenCV calibrateCamera, stereoCalibrate) …")
    result, used_detections, outliers = fit(
        with_eccentricity(lambda d: calibrate_in_air(board, d, size,
                                                     args.lens or DEFAULT_LENS_MODEL),
                          board, views_of_air))
    return _PairFit(result, used_detections, outliers, air_covariance=result.covariance)


def _fit_housing(args, fit, board, detections, free, air_rig, air_covariance, pair,
                 log) -> _PairFit:
    """The housing's refractive bundle adjustment from the design (a port per camera when
    ``pair``), outliers out; when it finds no housing and leaves a large RMS, again from each
    camera's own port, kept where it fits better."""
    from measure import StereoRig
    from measure.calibration.housing import FIT_RMS_LIMIT_PX, calibrate_housing

    from eval.calibrate.consistency import cameras_alone, start_from_cameras
    from eval.calibrate.dots import views_of_housing, with_eccentricity

    if pair:
        start_rig = design_pair(args, air_rig)
    else:
        start_rig = StereoRig(air_rig.left, air_rig.right,
                              design_port(args, air_rig.left.R[:, 2]))
    log(f"refractive bundle adjustment of {', '.join(free)} …")
    result, used_detections, outliers = fit(
        with_eccentricity(lambda d: calibrate_housing(start_rig, board, d, free,
                                                      air_covariance, args.air_uncertainty),
                          board, views_of_housing))
    housing, alone = result, None
    if not housing.identifiable and housing.rms_px > FIT_RMS_LIMIT_PX:
        log("the design start failed: again from each camera's own port …")
        alone = cameras_alone(start_rig, board, detections)  # the design far off
        better = start_from_cameras(start_rig, alone)
        if better is not None:
            again, again_used, again_outliers = fit(
                with_eccentricity(lambda d: calibrate_housing(
                    better, board, d, free, air_covariance, args.air_uncertainty),
                    board, views_of_housing))
            if again.identifiable or again.rms_px < housing.rms_px:
                start_rig, housing = better, again
                used_detections, outliers = again_used, again_outliers
    return _PairFit(housing, used_detections, outliers, housing, air_covariance, start_rig,
                    alone)


def _no_housing(args, fitted, board, detections, free, where) -> int:
    """A housing the photos do not determine: exit 1 with one ``failed:`` line when the in-air
    rig does not describe the photos or the solution is not unique, else CLIError; nothing
    written."""
    from eval.calibrate.consistency import rig_inconsistency, uniqueness

    housing, start_rig = fitted.housing, fitted.start_rig
    inconsistent = rig_inconsistency(housing, start_rig, board, detections, free, fitted.alone)
    if inconsistent is None and "extrinsics" in free:
        inconsistent = uniqueness(housing, start_rig, board, detections, free,
                                  fitted.air_covariance, args.air_uncertainty)["note"]
    if inconsistent:
        print(f"failed: {where}: {inconsistent}; nothing written", file=sys.stderr)
        return EXIT_CHECK_FAILED
    raise CLIError(f"{where}: {housing.reason}; nothing written (free fewer parameters "
                   f"with --free, or photograph more varied poses)")


def _report(args, board, corners, fitted) -> dict:
    """The report's account of the photos: the poses found, kept, left out and why, per pose
    its RMS (px) and geometry (distance mm, tilt degrees), the image's coverage."""
    from eval.calibrate import photos as trust
    from eval.calibrate.sources import MAX_POSES, repeat_lines

    names, result, rms_per, poses = corners.names, fitted.result, fitted.rms_per, fitted.poses
    used = sorted({k for k, _ in rms_per})
    geometry = trust.pose_geometry(board, {k: poses[k] for k in used if k in poses}, result.rig)
    return {"photos": os.path.abspath(args.dir),
            "source": "detections" if args.detections else "photos", "air": bool(args.air),
            "board": board.to_dict(), "image_size": list(corners.size), "poses": len(names),
            "repeats": repeat_lines(corners.repeats, names),
            "thinned": {"kept": len(corners.thinned),
                        "rule": f"at most {args.max_poses or MAX_POSES} "
                                f"poses, the most different kept (--max-poses)"},
            "found": {v: len(corners.found[v]) for v in trust.VIEWS}, "used": len(used),
            "not_found": corners.not_found,
            "left_out": [names[k] for k in fitted.outliers["left_out"]],
            "outlier_rule": trust.OUTLIER_RULE, "outliers": fitted.outliers,
            "per_pose": trust.per_pose_table(
                names, corners.detections_all, fitted.used_detections, rms_per,
                fitted.outliers, geometry,
                (result.stereo_poses, result.stereo_left_out) if args.air else None,
                {r["pose"] for r in corners.repeats}),
            "coverage": trust.coverage(fitted.used_detections, corners.size),
            "geometry": {"distance_mm": trust.stats_range(g["distance_mm"]
                                                          for g in geometry.values()),
                         "tilt_deg": trust.stats_range(g["tilt_deg"]
                                                       for g in geometry.values())}}


def _add_estimates(report, args, board, fitted, free, names, log) -> None:
    """The estimates with their σ: in air the cameras and the stereo pose, under water the
    housing (and, the stereo pose freed, whether other starts find another port); the worst
    corners of the fit."""
    from eval.calibrate import photos as trust
    from eval.calibrate import report as report_lib
    from eval.calibrate.consistency import uniqueness

    if args.air:
        report["in_air"] = trust.air_estimates(fitted.result,
                                               sorted({k for k, _ in fitted.rms_per}))
    else:
        housing = fitted.housing
        report["housing"] = trust.housing_estimates(housing, fitted.start_rig)
        report["sigma_note"] = report_lib.sigma_note(housing.uncertainty)
        if "extrinsics" in free:  # the rig's own pose freed: is the port determined at all?
            log("the same fit from other starting port distances …")
            report["housing"]["uniqueness"] = uniqueness(
                housing, fitted.start_rig, board, fitted.used_detections, free,
                fitted.air_covariance, args.air_uncertainty)
    report["worst_corners"] = trust.worst_corners(fitted.result.residuals, names)


def _add_warnings_and_failures(report, args, board, corners, fitted, pair) -> None:
    """What the report warns of (repeated photos, an underwater ``--intrinsics`` whose port is
    not used, an edge of the board no photo shows) and the failures that make the exit code 1
    (in air: the stereo fit; under water: a port that is not unique, or a gross misfit)."""
    from eval.calibrate import photos as trust
    from eval.calibrate.consistency import gross_misfit

    report["warnings"] = trust.warnings_for(report) + [
        f"{line}: left out (a photo given twice is one pose)" for line in report["repeats"]]
    if args.intrinsics and os.path.isfile(args.intrinsics):
        from synth.products.dataset import read_calib

        said = underwater_note(args.intrinsics, read_calib(args.intrinsics))
        if said:
            report["warnings"].append(said[len("note: "):])
    edge = trust.unseen_edge(board, corners.detections, (0, 1))
    if edge:
        report["warnings"].append(edge)
    report["failures"] = trust.air_failures(report) if args.air else []
    if not args.air and report["housing"].get("uniqueness", {}).get("note"):
        report["failures"].append(report["housing"]["uniqueness"]["note"])
    if not args.air:
        misfit = gross_misfit(fitted.housing, board, fitted.used_detections, corners.size,
                              bool(pair))
        if misfit:
            report["failures"].append(misfit)
