"""``python -m eval measure --calib calib.yaml CAM0 CAM1 CAM2 …``: one capture of a rig of N > 2
cameras measured with its calibration (a ``calib.yaml`` of N cameras, as ``eval calibrate``
writes it) — no truth.

Each photo is one camera's, in the order of the calibration's cameras. The targets are detected
in every photo (the detector options of ``eval run``), matched across all views without truth
(:func:`measure.stereo.multimatch.match_views`: every pair through the refractive epipolar
constraint, then consistent tracks) and each track triangulated from all its views with the
optical path of N views (:func:`measure.stereo.multiview.triangulate_views`). A target one view
alone saw is counted, never triangulated.

Writes into ``--out``: ``points.ply`` (mm, binary), ``points.csv`` (``track,x_mm,y_mm,z_mm,
gap_mm,views`` and ``u_NAME,v_NAME`` per camera, NaN where a camera did not see it),
``report.json`` and ``report.md`` (detections per camera, tracks and how many views each has,
the gap RMS by the number of views, the points' σ: ``uncertainty`` as for a pair) and
``uncertainty_optical_path.ply`` / ``.csv`` (every point's covariance in its pixels' noise,
:mod:`eval.core.views_uncertainty`; ``--pixel-sigma``). Exit 1 (everything written, a
``failed:`` line per camera) when a camera's photo has no target, or fewer than half of a
camera's detections end in a track: photos that are not the rig's capture (cameras swapped,
another moment, another rig; :func:`capture_failures` checks every camera). Units mm, px; the
reference frame is the first camera's.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from eval.cli import CLIError
from eval.core.views_uncertainty import (uncertainty_lines, views_uncertainty,
                                         write_views_uncertainty)

#: The options of a stereo pair's measurement that a capture of N cameras does not take.
NOT_FOR_N_CAMERAS = (("dense", "--dense"),)


#: A camera whose detections end in a track less often than this is not this capture's.
MIN_IN_TRACKS = 0.5


def capture_failures(names, photos, centers, in_tracks) -> list[str]:
    """Why the photos are not one capture of the rig, camera by camera: a photo with no target
    detected (black, covered, of another scene), or a camera fewer than :data:`MIN_IN_TRACKS`
    of whose detections end in a track with the others (cameras swapped, a photo of another
    moment, another rig)."""
    out = []
    for name, photo, found, used in zip(names, photos, centers, in_tracks):
        if len(found) == 0:
            out.append(f"{name} ({photo}): no target detected in its photo (black, covered, or "
                       f"of another scene)")
        elif used < MIN_IN_TRACKS * len(found):
            out.append(f"{name} ({photo}): {used} of its {len(found)} detections in a track "
                       f"with the other cameras: this photo is not this rig's capture (cameras "
                       f"swapped, a photo of another moment, or another rig)")
    return out


def measure_views_main(args, output, options, start, log) -> int:
    """``eval measure`` of one capture of N cameras (module docs); ``options`` the target
    options (:func:`eval.measure.command.options_of`)."""
    from synth.infra.cli import EXIT_CHECK_FAILED

    photos = [args.left, args.right, *args.more]
    _refuse_for_n_cameras(args, options, photos)
    rig = _read_rig(args, photos)
    images = _read_photos(args, rig, photos)
    log(f"detect the targets in {len(photos)} photos …")
    timings = {}
    t = time.perf_counter()
    detections = [_detections(image, options) for image in images]
    centers = [np.asarray(d.centers, dtype=float).reshape(-1, 2) for d in detections]
    timings["detect"] = time.perf_counter() - t
    t = time.perf_counter()
    tracks, pixels, result = _match_and_triangulate(rig, centers, options)
    timings["match_and_triangulate"] = time.perf_counter() - t
    ok = result.valid
    if not ok.any():
        raise CLIError(f"{', '.join(photos)}: no target was matched in two or more views "
                       f"(detections per camera: "
                       + ", ".join(f"{n} {len(c)}" for n, c in zip(rig.names, centers)) + ")")
    t = time.perf_counter()
    covariance, uncertainty = views_uncertainty(options.pixel_sigma, 0.0, rig, detections,
                                                tracks, pixels, result, "optical_path")
    timings["covariance"] = time.perf_counter() - t
    in_tracks = [int((tracks.detections[ok, v] >= 0).sum()) for v in range(len(photos))]
    failures = capture_failures(rig.names, photos, centers, in_tracks)
    report = _report(args, options, rig, photos, centers, in_tracks, tracks, result, failures)
    report["uncertainty"] = uncertainty
    by_views = report["by_views"]  # as computed (the report is written as plain JSON types)
    report = _write(output, args, rig, photos, (result, covariance), pixels, report, timings,
                    start)
    _print_summary(args, output, photos, report, by_views)
    for failure in failures:
        print(f"failed: {failure} (report in {output.path})", file=sys.stderr)
    return EXIT_CHECK_FAILED if failures else 0


def _refuse_for_n_cameras(args, options, photos) -> None:
    """The options of a stereo pair's measurement that a capture of N cameras refuses, and any
    method but the optical path of N views."""
    from synth.infra.cli import given

    for dest, flag in NOT_FOR_N_CAMERAS:
        if given(args, dest):
            raise CLIError(f"{flag} does not apply to a capture of {len(photos)} cameras")
    if tuple(options.methods) != ("optical_path",):
        raise CLIError(f"--methods {args.methods}: a capture of {len(photos)} cameras is "
                       f"measured with the optical path of N views (optical_path)")


def _read_rig(args, photos):
    """The rig of ``--calib``, one camera per photo."""
    from synth.products.dataset import DatasetError
    from synth.products.rig_file import read_rig_file

    try:
        rig = read_rig_file(args.calib)
    except DatasetError as exc:
        raise CLIError(f"--calib {exc}") from None
    if len(rig.cameras) != len(photos):
        raise CLIError(f"--calib {args.calib}: {len(rig.cameras)} cameras "
                       f"({', '.join(rig.names)}), but {len(photos)} photos were given (one per "
                       f"camera, in that order)")
    return rig


def _read_photos(args, rig, photos) -> list:
    """Each camera's photo (``--encoding``), of the size of its camera (px); the encoding's note
    on stderr."""
    from eval.core.photos import PhotoError, encoding_note, read_photo

    images = []
    for name, camera, photo in zip(rig.names, rig.cameras, photos):
        if os.path.isdir(photo):
            raise CLIError(f"{photo}: a folder; a capture of N cameras is given as one photo "
                           f"per camera")
        try:
            image = read_photo(photo, args.encoding)
        except PhotoError as exc:
            raise CLIError(str(exc)) from None
        if (image.shape[1], image.shape[0]) != tuple(camera.size):
            raise CLIError(f"{photo}: {image.shape[1]}x{image.shape[0]} px, but {name} of "
                           f"{args.calib} is {camera.size[0]}x{camera.size[1]} px")
        images.append(image)
    note = encoding_note(photos[0], args.encoding)
    if note:
        print(note, file=sys.stderr, flush=True)
    return images


def _detections(image, options):
    """The targets detected in one photo (:class:`measure.images.detect.Detections`)."""
    from eval.core.detection import detect_view

    return detect_view(image, options.threshold_fraction, options.max_elongation,
                       options.max_area_ratio, options.median_filter,
                       floor_fraction=options.floor_fraction)


def _match_and_triangulate(rig, centers, options):
    """``(tracks, pixels, result)``: the detections matched across all views, each track's
    pixels per view and its triangulation from all its views (mm)."""
    from measure.stereo.multimatch import match_views
    from measure.stereo.multiview import triangulate_views

    tracks = match_views(rig, centers, gate_mm=options.gate_mm,
                         depth_range=tuple(options.depth_range))
    pixels = tracks.pixels(centers)
    return tracks, pixels, triangulate_views(rig.views(), pixels)


def _report(args, options, rig, photos, centers, in_tracks, tracks, result, failures) -> dict:
    """The report: detections and tracks per camera, the targets and gap RMS (mm) by the
    number of views, the failures."""
    ok = result.valid
    by_views = {}
    for k in sorted(set(result.views[ok].tolist())):
        sel = ok & (result.views == k)
        by_views[str(k)] = {"targets": int(sel.sum()),
                            "gap_rms_mm": float(np.sqrt(np.mean(result.gap[sel] ** 2)))}
    return {"command": "eval measure", "calib": args.calib, "cameras": list(rig.names),
            "photos": photos, "encoding": args.encoding, "image_size": list(rig.cameras[0].size),
            "methods": ["optical_path"],
            "options": {"gate_mm": options.gate_mm,
                        "depth_range_mm": [None if v is None else float(v)
                                           for v in options.depth_range]},
            "detections": {n: len(c) for n, c in zip(rig.names, centers)},
            "in_tracks": dict(zip(rig.names, in_tracks)),
            "tracks": int(len(tracks.detections)), "triangulated": int(ok.sum()),
            "in_no_track": {n: int(len(a)) for n, a in zip(rig.names, tracks.alone)},
            "conflicts_dropped": int(tracks.n_conflicts), "by_views": by_views,
            "gap_rms_mm": float(np.sqrt(np.mean(result.gap[ok] ** 2))),
            "failures": failures}


def _write(output, args, rig, photos, measured, pixels, report, timings, start) -> dict:
    """``points.ply``, ``points.csv``, the uncertainty files, ``report.json`` (its timings, s)
    and ``report.md`` into ``output``; ``measured`` the triangulation and its covariances; the
    report as written."""
    from synth.infra.fileio import atomic_write_json, atomic_write_text, jsonable

    from eval.measure.report import write_cloud

    result, covariance = measured
    ok, by_views = result.valid, report["by_views"]
    with output.staged() as tmp:
        write_cloud(os.path.join(tmp, "points.ply"), result.points[ok])
        atomic_write_text(os.path.join(tmp, "points.csv"), _points_csv(rig, result, pixels))
        write_views_uncertainty(tmp, "optical_path", result, covariance, None,
                                report["uncertainty"])
        report["timings_s"] = {**timings, "total": time.perf_counter() - start}
        report = jsonable(report)
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        atomic_write_text(os.path.join(tmp, "report.md"),
                          _markdown(args, photos, report, by_views))
    return report


def _points_csv(rig, result, pixels) -> str:
    """``points.csv``: per triangulated track its point and gap (mm), views, and its pixels in
    every camera (NaN where a camera did not see it)."""
    header = ["track", "x_mm", "y_mm", "z_mm", "gap_mm", "views"] + [
        f"{a}_{n}" for n in rig.names for a in ("u", "v")]
    lines = [",".join(header)]
    for i in np.flatnonzero(result.valid):
        lines.append(",".join([str(int(i)), *(repr(float(v)) for v in result.points[i]),
                               repr(float(result.gap[i])), str(int(result.views[i])),
                               *(repr(float(v)) for v in pixels[i].ravel())]))
    return "\n".join(lines) + "\n"


def _markdown(args, photos, report, by_views) -> str:
    """``report.md``: detections per camera, the tracks, gap RMS by the number of views (mm),
    the failures."""
    return "\n".join([
        f"# eval measure: one capture of {len(photos)} cameras", "",
        f"Calibration `{args.calib}`. Detections per camera: "
        + ", ".join(f"{n} {c}" for n, c in report["detections"].items()) + ".", "",
        f"{report['triangulated']} targets triangulated (optical path of N views); "
        f"detections in no track (seen by one view, or ambiguous; not triangulated): "
        + ", ".join(f"{n} {c}" for n, c in report["in_no_track"].items())
        + f"; {report['conflicts_dropped']} ambiguous tracks dropped.", "",
        "| views | targets | gap RMS (mm) |", "|---|---|---|",
        *(f"| {k} | {v['targets']} | {v['gap_rms_mm']:.4g} |"
          for k, v in by_views.items()),
        *uncertainty_lines(report),
        "", *(f"**Failed:** {f}" for f in report["failures"])]) + "\n"


def _print_summary(args, output, photos, report, by_views) -> None:
    """The summary lines (on stderr with ``--json``, which prints the report alone on
    stdout)."""
    stream = sys.stderr if getattr(args, "json", False) else sys.stdout
    print(f"{len(photos)} cameras: {report['triangulated']} targets triangulated ("
          + ", ".join(f"{v['targets']} from {k} views" for k, v in by_views.items())
          + f"), gap RMS {report['gap_rms_mm']:.4g} mm; total {report['timings_s']['total']:.1f} s",
          file=stream)
    for line in filter(None, uncertainty_lines(report)):
        print("  " + line, file=stream)
    print(f"wrote {output.path}", file=stream)
    if getattr(args, "json", False):
        import json

        print(json.dumps(report, indent=2))


__all__ = ["measure_views_main"]
