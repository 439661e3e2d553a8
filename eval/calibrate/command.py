"""``python -m eval calibrate DIR``: calibrate from board images, and say what it cost.

``DIR`` is a folder of ``python -m synth boards`` (compared with its truth) or a folder of a
user's own photos (``DIR/left/``, ``DIR/right/``, paired by name; the board on the command line,
``--air`` or ``--intrinsics``; the report says what can be trusted without truth:
:mod:`eval.calibrate.photos`), or ONE camera's photos (a folder holding them: in air
:mod:`eval.calibrate.single`, underwater with its ``camera.yaml`` the housing of that camera,
:mod:`eval.calibrate.single_housing`). In air (``--air`` boards): OpenCV calibrates
both cameras and the stereo pose (:func:`measure.calibration.air.calibrate_in_air`). Underwater:
the housing is estimated by refractive bundle adjustment with the in-air intrinsics fixed
(:func:`measure.calibration.housing.calibrate_housing`); ``--intrinsics`` gives them, as an in-air boards
folder (calibrated here first) or a ``calib.yaml``. Behind two housings (each camera its own
flat port: boards whose truth says so, or photos with ``--port-distance``) each camera's port is
estimated, starting ``--port-distance LEFT,RIGHT`` mm from its camera (:mod:`eval.calibrate.design`;
N cameras ``D0,D1,…``, :mod:`eval.calibrate.cameras`).

Writes to ``--out``: ``calib.yaml`` (the dataset format, with an ``uncertainty`` map),
``calib_in_air_only.yaml`` (underwater: the in-air calibration with the design port — what a
team that skips the housing calibration measures with), ``flatport.txt`` (the port as the
refractive COLMAP fork and calibmar write it), ``report.json``, ``report.md`` (every estimate
beside the truth with its error in σ) and figures ``residuals.png`` (reprojection residual
vectors per pose and view) and ``poses.png`` (the board poses in 3D).

This module routes a folder to its calibration; the parser is :mod:`eval.calibrate.options`, a
pair's boards :mod:`eval.calibrate.pair_boards`, ``--intrinsics``
:mod:`eval.calibrate.intrinsics`, and the files and lines at the end
:mod:`eval.calibrate.outputs`.
"""

from __future__ import annotations

import os
import sys
import time

from eval.calibrate.design import (DOME_DESIGN_OPTIONS, FLAT_DESIGN_OPTIONS, design_domes,
                                   design_pair, design_port, pair_glass, parse_free)
from eval.calibrate.intrinsics import intrinsics_for_photos, is_photo_folder, underwater_note
from eval.calibrate.options import (COMMAND, HOUSING_OPTIONS, LENS_UNDERWATER,
                                    add_calibrate_parser, require_board)
from eval.calibrate.outputs import (COLMAP_NOTE, failed, print_n_water_note, print_written,
                                    write_calibrations)
from eval.calibrate.pair_boards import calibrate_pair_boards
from eval.calibrate.port_lengths import lengths_for
from eval.calibrate.single import single_camera_folder
from eval.cli import CLIError
from eval.core.photos import encoding_note
from synth.infra.cli import EXIT_CHECK_FAILED, board_from_args, given, refuse_given


def add_parser(subparsers):
    """The ``calibrate`` subcommand's parser (:mod:`eval.calibrate.options`: its options by
    group)."""
    add_calibrate_parser(subparsers)


def main(args) -> int:
    """``eval calibrate DIR`` (module docs): the folder's kind says which calibration runs —
    ``--model absorbed``, detections, photos of N cameras, of a pair or of one camera, or a
    ``synth boards`` folder."""
    from synth.infra.fileio import OutputDir

    log = (lambda text: None) if args.no_progress else (
        lambda text: print(text, file=sys.stderr, flush=True))
    output = OutputDir(args.out, COMMAND).claim()
    start = time.perf_counter()
    _check_folder_and_model(args)
    if args.model == "absorbed":
        return _calibrate_absorbed(args, output, log, start)
    if args.detections:
        return _calibrate_detections(args, output, log, start, args.free)
    if not os.path.exists(os.path.join(args.dir, "manifest.json")):
        cameras = _camera_folders(args.dir)
        if cameras:
            return _calibrate_camera_photos(args, output, log, start, cameras)
    if is_photo_folder(args.dir) or (
            any(os.path.isdir(os.path.join(args.dir, sub)) for sub in ("left", "right"))
            and not os.path.exists(os.path.join(args.dir, "manifest.json"))):
        refuse_given(args, DOME_DESIGN_OPTIONS, f"to photos ({args.dir}): the housing "
                                                "calibration of photos models a flat port")
        return _calibrate_photos(args, output, log, parse_free(args.free), start)
    if not os.path.isfile(os.path.join(args.dir, "manifest.json")) and single_camera_folder(
            args.dir):
        return _calibrate_single(args, output, log, start)
    if not os.path.isfile(os.path.join(args.dir, "manifest.json")) and os.path.isdir(args.dir):
        raise CLIError(f"{args.dir}: not a boards folder (no manifest.json) nor a photo folder "
                       f"(no left/ and right/ folders, no photos)")
    return _calibrate_boards(args, output, log, start)


def _check_folder_and_model(args) -> None:
    """CLIError when ``DIR`` is no folder, a detection option is given without
    ``--detections`` (or wrongly), or ``--stereo-intrinsics`` without ``--model absorbed``."""
    from eval.calibrate.sources import check_detection_options

    if not os.path.isdir(args.dir):
        what = "a file, not a folder" if os.path.exists(args.dir) else "no such folder"
        raise CLIError(f"{args.dir}: {what} (give a photo folder, DIR/left/ and DIR/right/, or a "
                       f"synth boards folder)")
    check_detection_options(args)
    if args.model != "absorbed":
        refuse_given(args, ("stereo_intrinsics",), "without --model absorbed (the port model's "
                                                   "stereo fit holds the in-air intrinsics)")


def _calibrate_absorbed(args, output, log, start) -> int:
    """``--model absorbed`` (:mod:`eval.calibrate.absorbed`): the underwater photos calibrate
    the cameras themselves, so ``--air``, ``--intrinsics`` and the port's options are
    refused."""
    from eval.calibrate.absorbed import calibrate_absorbed_main

    if args.air or args.intrinsics:
        raise CLIError(f"--model absorbed: {'--air' if args.air else '--intrinsics'} does not "
                       f"apply: the underwater photos themselves calibrate the cameras")
    refuse_given(args, HOUSING_OPTIONS + DOME_DESIGN_OPTIONS,
                 "with --model absorbed: it has no port")
    return calibrate_absorbed_main(args, output, log, start)


def _camera_folders(path) -> list:
    """The camera folders (``cam0/``, ``cam1/``, …) of a photo folder of N cameras; empty for
    any other folder."""
    from eval.core.photos import PhotoError, camera_folder_names

    try:
        return camera_folder_names(path)
    except PhotoError as exc:
        raise CLIError(str(exc)) from None


def _calibrate_boards(args, output, log, start) -> int:
    """A ``synth boards`` folder: of N > 2 cameras (:mod:`eval.calibrate.cameras`) or of a pair
    (:mod:`eval.calibrate.pair_boards`)."""
    from synth.products.boards import read_boards

    boards = read_boards(args.dir)
    if "multirig" in boards.calib:  # a folder of N > 2 cameras
        from eval.calibrate.cameras import boards_source, calibrate_cameras_main

        if boards.air:
            refuse_given(args, HOUSING_OPTIONS, f"to in-air boards ({args.dir}): they calibrate "
                                                f"the cameras, no housing")
        source = boards_source(boards)
        design = None if boards.air else _n_camera_design(args, source.own_ports,
                                                            len(source.names))
        return calibrate_cameras_main(args, output, log, start, source, design)
    return calibrate_pair_boards(args, output, log, start, boards)


def _n_camera_design(args, own_ports: bool = False, cameras: int = 3):
    """The starting glass of N cameras under water: one shared port (:mod:`eval.calibrate.design`), or
    — ``--port-distance`` given, or boards whose truth has a port per camera (``own_ports``) —
    the glass and water each camera's own port has (:func:`pair_glass`: the shared distance
    options refused)."""
    if own_ports or given(args, "port_distance"):
        return pair_glass(args, cameras)
    return design_port(args, (0.0, 0.0, 1.0))


def _calibrate_camera_photos(args, output, log, start, cameras) -> int:
    """``eval calibrate`` of a user's photo folder of N > 2 cameras (``cam0/``, ``cam1/``, …:
    :mod:`eval.calibrate.cameras`)."""
    from eval.calibrate.cameras import calibrate_cameras_main, photos_source

    where = f"{args.dir} (photos of {len(cameras)} cameras)"
    if len(cameras) == 2:
        raise CLIError(f"{args.dir}: two camera folders (cam0/, cam1/); a stereo pair's photos "
                       f"are left/ and right/ (the two-camera calibration)")
    if args.air:
        refuse_given(args, HOUSING_OPTIONS, "to in-air photos (--air): they calibrate the "
                                            "cameras, no housing")
        if args.intrinsics:
            raise CLIError("--intrinsics does not apply with --air: in-air photos calibrate the "
                           "intrinsics themselves")
    elif not args.intrinsics:
        raise CLIError(f"{where}: say --air (photos taken in air) or --intrinsics calib.yaml "
                       f"(photos taken underwater, with the in-air calibration of these cameras)")
    require_board(args, where)
    board = board_from_args(args)
    if board.symmetric:
        raise CLIError(f"{where}: a {board.squares[0]}x{board.squares[1]} chessboard looks the "
                       f"same turned by 180°; a rig of N cameras does not settle its turn yet "
                       f"(one camera and a pair do): use a board with one odd and one even "
                       f"number of squares")
    design = None if args.air else _n_camera_design(args, cameras=len(cameras))
    if design is not None and given(args, "port_distance"):
        lengths_for(args.port_distance, len(cameras))  # refused before any photo is read
    note = None
    first = os.path.join(args.dir, cameras[0])
    photos = sorted(f for f in os.listdir(first) if not f.startswith("."))
    if photos:
        note = encoding_note(os.path.join(first, photos[0]), args.encoding)
    log(f"read the photos of {', '.join(cameras)} from {args.dir} …")
    source = photos_source(args.dir, cameras, board, bool(args.air), args.encoding)
    if note:  # once the photos are read: a refused folder prints its error line only
        print(note, file=sys.stderr, flush=True)
    return calibrate_cameras_main(args, output, log, start, source, design)


def _calibrate_photos(args, output, log, free, start) -> int:
    """``eval calibrate`` of a user's photo folder (module docs, :mod:`eval.calibrate.photos`)."""
    from measure import StereoRig
    from measure.calibration.air import (DEFAULT_LENS_MODEL, CalibrationError, calibrate_in_air)
    from measure.calibration.housing import calibrate_housing

    from eval.calibrate import photos as trust
    from eval.calibrate import photos_report
    from eval.calibrate import report as report_lib
    from measure.calibration.housing import FIT_RMS_LIMIT_PX

    from eval.calibrate.consistency import (cameras_alone, gross_misfit, rig_inconsistency,
                                            start_from_cameras, uniqueness)
    from eval.calibrate.dots import views_of_air, views_of_housing, with_eccentricity
    from eval.calibrate.sources import (MAX_POSES, repeat_lines, repeated_views, thin_by_pose,
                                        without_repeats)

    where = f"{args.dir} ({'detections' if args.detections else 'photos'})"
    source = "detections" if args.detections else "photos"
    if args.air:
        refuse_given(args, HOUSING_OPTIONS, "to in-air photos (--air): they calibrate the "
                                            "cameras, no housing")
        if args.intrinsics:
            raise CLIError("--intrinsics does not apply with --air: in-air photos calibrate the "
                           "intrinsics themselves")
    elif not args.intrinsics:
        raise CLIError(f"{where}: say --air (photos taken in air) or --intrinsics calib.yaml "
                       f"(photos taken underwater, with the in-air calibration)")
    else:
        refuse_given(args, ("lens",), LENS_UNDERWATER)
    require_board(args, where)
    board = board_from_args(args)
    pair = given(args, "port_distance")  # two housings: a port per camera
    if pair and not args.air:
        pair_glass(args)  # a bad design is refused before any work
        lengths_for(args.port_distance, 2)
    elif not args.air:
        design_port(args, (0.0, 0.0, 1.0))  # a bad --design-port is refused before any work
    air_rig = air_covariance = None
    if not args.air:
        air_rig, air_covariance = intrinsics_for_photos(args.intrinsics, log)
    names, images, size, detections, timings = _pair_corners(args, board, log, where)
    if air_rig is not None and tuple(air_rig.left.size) != tuple(size):
        raise CLIError(f"--intrinsics {args.intrinsics}: image size "
                       f"{air_rig.left.size[0]}x{air_rig.left.size[1]} px, but the "
                       f"{'detections are' if args.detections else 'photos are'} "
                       f"{size[0]}x{size[1]} px")
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
    t = time.perf_counter()

    def fit(calibrate):  # a CalibrationError (too few poses) names the photo folder
        try:
            return trust.fit_without_outliers(
                calibrate, lambda r: r.rms_px_per, detections, lambda r: r.residuals, board,
                lambda r: getattr(r, "identifiable", True))
        except CalibrationError as exc:
            raise CLIError(f"{where}: {exc}") from None

    if args.air:
        log("calibrate in air (OpenCV calibrateCamera, stereoCalibrate) …")
        result, used_detections, outliers = fit(
            with_eccentricity(lambda d: calibrate_in_air(board, d, size,
                                                         args.lens or DEFAULT_LENS_MODEL),
                              board, views_of_air))
        rig, housing, rms_per = result.rig, None, result.rms_px_per
        air_covariance = result.covariance
        poses = {k: result.board_poses.get((k, 0), pose)  # the left camera's where it has one
                 for (k, _), pose in result.board_poses.items()}
        timings["calibrate"] = time.perf_counter() - t
    else:
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
                    result, used_detections, outliers = again, again_used, again_outliers
        timings["bundle_adjustment"] = time.perf_counter() - t
        if not housing.identifiable:
            inconsistent = rig_inconsistency(housing, start_rig, board, detections, free, alone)
            if inconsistent is None and "extrinsics" in free:
                inconsistent = uniqueness(housing, start_rig, board, detections, free,
                                          air_covariance, args.air_uncertainty)["note"]
            if inconsistent:
                print(f"failed: {where}: {inconsistent}; nothing written", file=sys.stderr)
                return EXIT_CHECK_FAILED
            raise CLIError(f"{where}: {housing.reason}; nothing written (free fewer parameters "
                           f"with --free, or photograph more varied poses)")
        rig, rms_per = housing.rig, housing.rms_px_per
        poses = dict(zip(housing.pose_ids, housing.poses))
    used = sorted({k for k, _ in rms_per})
    geometry = trust.pose_geometry(board, {k: poses[k] for k in used if k in poses}, rig)
    report = {"photos": os.path.abspath(args.dir), "source": source, "air": bool(args.air),
              "board": board.to_dict(), "image_size": list(size), "poses": len(names),
              "repeats": repeat_lines(repeats, names),
              "thinned": {"kept": len(thinned), "rule": f"at most {args.max_poses or MAX_POSES} "
                          f"poses, the most different kept (--max-poses)"},
              "found": {v: len(found[v]) for v in trust.VIEWS}, "used": len(used),
              "not_found": not_found,
              "left_out": [names[k] for k in outliers["left_out"]],
              "outlier_rule": trust.OUTLIER_RULE, "outliers": outliers,
              "per_pose": trust.per_pose_table(
                  names, detections_all, used_detections, rms_per, outliers, geometry,
                  (result.stereo_poses, result.stereo_left_out) if args.air else None,
                  {r["pose"] for r in repeats}),
              "coverage": trust.coverage(used_detections, size),
              "geometry": {"distance_mm": trust.stats_range(g["distance_mm"]
                                                            for g in geometry.values()),
                           "tilt_deg": trust.stats_range(g["tilt_deg"] for g in geometry.values())}}
    if args.air:
        report["in_air"] = trust.air_estimates(result, used)
        residuals = result.residuals
    else:
        report["housing"] = trust.housing_estimates(housing, start_rig)
        report["sigma_note"] = report_lib.sigma_note(housing.uncertainty)
        residuals = housing.residuals
        if "extrinsics" in free:  # the rig's own pose freed: is the port determined at all?
            log("the same fit from other starting port distances …")
            report["housing"]["uniqueness"] = uniqueness(
                housing, start_rig, board, used_detections, free, air_covariance,
                args.air_uncertainty)
    report["worst_corners"] = trust.worst_corners(residuals, names)
    report["warnings"] = trust.warnings_for(report) + [
        f"{line}: left out (a photo given twice is one pose)" for line in report["repeats"]]
    if args.intrinsics and os.path.isfile(args.intrinsics):
        from synth.products.dataset import read_calib

        said = underwater_note(args.intrinsics, read_calib(args.intrinsics))
        if said:
            report["warnings"].append(said[len("note: "):])
    edge = trust.unseen_edge(board, detections, (0, 1))
    if edge:
        report["warnings"].append(edge)
    report["failures"] = trust.air_failures(report) if args.air else []
    if not args.air and report["housing"].get("uniqueness", {}).get("note"):
        report["failures"].append(report["housing"]["uniqueness"]["note"])
    if not args.air:
        misfit = gross_misfit(housing, board, used_detections, size, bool(pair))
        if misfit:
            report["failures"].append(misfit)
    report["timings_s"] = timings
    log("write the calibration, report and figures …")
    with output.staged() as tmp:
        write_calibrations(tmp, rig, housing, report, None if args.air else start_rig,
                            air_covariance)
        report_lib.residual_figure(tmp, used_detections, residuals, size)
        photos_report.coverage_figure(tmp, detections, set(used), size, report)
        report = report_lib.write_report(tmp, report, photos_report.markdown, start)
    code = print_written(output, photos_report.summary_lines(report), args, housing is not None)
    return failed(args.dir, report["failures"], output.path) or code


def _pair_corners(args, board, log, where):
    """``(names, images or None, size, detections, timings)`` of a pair's photos (read and
    detected) or, ``--detections``, of its detection files; CLIError where the board is in no
    photo, or the photos show another board (photos only: the checks need the images)."""
    from measure.calibration.air import detect_boards

    from eval.calibrate import photos as trust
    from eval.calibrate.sources import read_detection_views
    from eval.core.photos import photo_folder, read_pairs

    t = time.perf_counter()
    if args.detections:
        names, detections, size = read_detection_views(args, board, 2)
        return names, None, size, detections, {"read": time.perf_counter() - t}
    pairs = photo_folder(args.dir)
    log(f"read {len(pairs.names)} photo pairs from {args.dir} …")
    note = encoding_note(pairs.left[0], args.encoding) if pairs.left else None
    if note:
        print(note, file=sys.stderr, flush=True)
    images, size = read_pairs(pairs, args.encoding)
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


def _calibrate_detections(args, output, log, start, free) -> int:
    """``--detections``: one camera's files, or a pair's in ``left/`` and ``right/``, through
    the paths of photos (:mod:`eval.calibrate.sources`)."""
    from eval.core.detections import DetectionError, detection_layout

    try:
        layout = detection_layout(args.dir)
    except DetectionError as exc:
        raise CLIError(str(exc)) from None
    if not layout:
        return _calibrate_single(args, output, log, start)
    refuse_given(args, DOME_DESIGN_OPTIONS, f"to a pair's detections ({args.dir}): the housing "
                                            "calibration of a pair's photos models flat ports")
    return _calibrate_photos(args, output, log, parse_free(free), start)


def _calibrate_single(args, output, log, start) -> int:
    """``eval calibrate`` of one camera's photo folder: in air (:mod:`eval.calibrate.single`)
    or, with ``--intrinsics``, its housing (:mod:`eval.calibrate.single_housing`)."""
    from eval.calibrate.single import calibrate_single

    where = f"{args.dir} (one camera's photos)"
    if not args.air and not args.intrinsics:
        raise CLIError(f"{where}: say --air (photos taken in air) or --intrinsics camera.yaml "
                       f"(photos taken underwater, with the camera's in-air calibration)")
    if not args.air:
        return _calibrate_single_housing(args, output, log, start, where)
    if args.intrinsics:
        raise CLIError("--intrinsics does not apply with --air: in-air photos calibrate the "
                       "intrinsics themselves")
    refuse_given(args, HOUSING_OPTIONS + DOME_DESIGN_OPTIONS + ("intrinsics",),
                 "to one camera's in-air photos (--air): they calibrate the camera, no housing")
    require_board(args, where)
    report, summary = calibrate_single(args, output, log, start, board_from_args(args))
    print(summary)
    print(f"wrote {output.path} (camera.yaml for OpenCV; calibmar.yaml; cameras.txt for COLMAP)")
    return failed(args.dir, report["failures"], output.path)


def _calibrate_single_housing(args, output, log, start, where) -> int:
    """One camera's underwater photos with its in-air calibration: the housing of that camera
    (:mod:`eval.calibrate.single_housing`). A dome when a dome design option is given, else a
    flat port (the stereo calibration's options)."""
    from measure import StereoRig
    from measure.calibration.housing import DEFAULT_DOME_FREE

    from eval.calibrate.single_housing import calibrate_single_housing, read_intrinsics

    refuse_given(args, ("lens",), LENS_UNDERWATER)
    refuse_given(args, ("port_distance",), f"to one camera's photos ({args.dir}): it is the "
                                           f"design of two housings (one camera's port: "
                                           f"--start-distance)")
    dome = any(given(args, dest) for dest in DOME_DESIGN_OPTIONS)
    if dome:
        refuse_given(args, FLAT_DESIGN_OPTIONS, "to a camera inside a dome (--dome-radius / "
                                                "--dome-thickness given): the design is "
                                                "--dome-radius, --dome-thickness, --n-glass, "
                                                "--n-water")
    free = parse_free(args.free if given(args, "free") or not dome
                      else ",".join(DEFAULT_DOME_FREE), dome)
    if "extrinsics" in free:
        raise CLIError(f"--free {args.free}: extrinsics is the stereo pose; {args.dir} holds one "
                       f"camera's photos")
    require_board(args, where)
    board = board_from_args(args)
    if not dome:
        design_port(args, (0.0, 0.0, 1.0))  # a bad --design-port is refused before any work
    intrinsics = read_intrinsics(args.intrinsics)
    camera = intrinsics["camera"]
    if dome:
        start_port = design_domes(args, StereoRig(camera, camera, None)).port
    else:
        start_port = design_port(args, camera.R[:, 2])
    report, summary = calibrate_single_housing(args, output, log, start, board, intrinsics,
                                               start_port, free, dome)
    print_n_water_note(args)
    print(summary)
    print(f"wrote {output.path} (camera.yaml for OpenCV; calibmar.yaml; cameras.txt for the "
          f"refractive COLMAP fork — {COLMAP_NOTE})")
    return failed(args.dir, report["failures"], output.path)
