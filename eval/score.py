"""``python -m eval score DATASET``: score anyone's reconstruction against a rendered dataset.

Users render a dataset (``python -m synth dataset``), run their own pipeline on its images and
hand back either

* ``--points THEIRS.ply`` — their 3D points (any point cloud Open3D reads, read whole;
  millimetres, or metres with ``--units m``; the dataset's reference frame: the left camera's,
  OpenCV axes), or
* ``--pixels THEIRS.csv`` — matched pixel pairs (columns ``u_left, v_left, u_right, v_right``,
  OpenCV pixel convention), triangulated here with ``--method`` and the dataset's
  ``calib.yaml``,

and get the same metrics as ``eval run``: each point is associated with the nearest true target
within ``--gate-mm`` (default: half the smallest distance between two targets, so that the
nearest target is the right one; one point per target, the nearest wins; the others count as
``unassociated``), dX, dY, dZ, dP over the associated points, Open3D's cloud distances of all
points against the targets visible in both views, the rigid alignment, and the flatness (seeded
with the dataset's seed). ``eval score`` on an ``eval run --from DATASET`` output's own
``points_<method>.ply`` reproduces that run's numbers (all but ``coverage_95``: a point's
covariance needs its two pixels, which a PLY file does not hold — ``--pixels`` gets one).

A submission is checked for plausibility before it is scored (:func:`plausibility`): when the
points fit the targets markedly better scaled by 1000 (metres), reflected (an axis negated) or
shifted rigidly, or some repeat others, one line ``warning: …`` names the likely cause on
stderr and in the report (``warnings``); the points are scored as given all the same.

Writes to ``--out``: ``report.json``, ``report.md``, ``error_maps.png``, ``histograms.png`` and
``points_scored.ply`` (the associated points coloured by dP).
"""

from __future__ import annotations

import os
import sys
import time

from eval.cli import CLIError, positive_float
from synth.infra.cli import add_json_option, add_out_option, add_progress_option
from eval.core.formatting import format_number as fmt
from eval.core.uncertainty import AUTO, add_pixel_sigma_option, parse_pixel_sigma
from eval.core.scoring import (PIXEL_COLUMNS, UNITS, read_pixel_pairs, read_points,
                               score_dataset, unassociated_text)
# the scoring functions, where they were before eval.core.scoring held them
from eval.core.scoring import associate_points, default_gate_mm, plausibility  # noqa: F401

COMMAND = "eval score"


def add_parser(subparsers):
    from measure.stereo.triangulate import METHODS

    p = subparsers.add_parser(
        "score", help="score an external reconstruction against a rendered dataset",
        description="Score your own pipeline's points (or matched pixel pairs) against the "
                    "truth of a python -m synth dataset, with eval run's metrics.")
    p.add_argument("dataset", help="dataset folder (python -m synth dataset), or a suite folder "
                                   "(python -m synth suite) with --submission")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--submission", metavar="DIR",
                        help="score a whole suite: DIR/<dataset folder>/ holds points.ply, "
                             "points_<method>.ply or pairs.csv (targets), depth.pfm, depth.npy "
                             "or points.ply (surfaces); a missing or unreadable one counts as a failure")
    source.add_argument("--points", metavar="THEIRS.ply",
                        help="your 3D points, mm, in the dataset's reference frame")
    source.add_argument("--pixels", metavar="THEIRS.csv",
                        help="your matched pixel pairs: CSV with columns "
                             + ", ".join(PIXEL_COLUMNS))
    p.add_argument("--method", default=None, choices=METHODS[:3] + ("absorbed",),
                   help="triangulation of --pixels (default optical_path; absorbed: the port "
                        "absorbed by a pinhole calibration, docs/absorbed.md)")
    p.add_argument("--absorbed-calib", metavar="FILE", default=None,
                   help="with --method absorbed: its calibration, a calib.yaml without a port "
                        "(default: the dataset's boards seen through its port, calibrated as "
                        "pinhole cameras)")
    p.add_argument("--units", default=None, choices=UNITS,
                   help="units of --points (default mm; m: the points are multiplied by 1000)")
    p.add_argument("--gate-mm", type=positive_float, default=None,
                   help="largest distance of a point from its target, mm (default: half the "
                        "smallest distance between two targets, where the nearest target is "
                        "unambiguous)")
    add_pixel_sigma_option(p)
    add_out_option(p, COMMAND, "out/score")
    add_json_option(p)
    add_progress_option(p)


def _inside(path, folder) -> bool:
    """Whether ``path`` is ``folder`` or lies below it (symbolic links resolved)."""
    path, folder = os.path.realpath(path), os.path.realpath(folder)
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def main(args) -> int:
    from synth.infra.fileio import OutputDir

    log = lambda text: print(text, file=sys.stderr, flush=True)  # noqa: E731
    start = time.perf_counter()
    method, pixel_sigma = _check_options(args)
    output = OutputDir(args.out, COMMAND).claim()
    if args.submission:
        return score_suite_main(args, output, method, log, start)
    data, several = _read_data(args)
    if not several and data.is_surface:
        if not args.points:
            raise CLIError(f"--pixels does not apply to {args.dataset}: a surface dataset "
                           f"(per-pixel truth maps, no targets); score its --points (eval "
                           f"measure --dense writes points.ply)")
        return score_surface_main(args, data, output, log, start)
    points, uv, label, source = _points_to_score(args, data, method)
    report, arrays, warnings = score_dataset(data, points, label, args.gate_mm,
                                             units=source.get("units"))
    if warnings:  # one line naming the likely cause; scored as given all the same
        what = f"--points {args.points}" if args.points else f"--pixels {args.pixels}"
        log(f"warning: {what}: " + "; ".join(warnings))
    report = {"dataset": report["dataset"], "source": source, **{k: v for k, v in report.items()
                                                               if k != "dataset"}}
    report["uncertainty"] = (score_covariances(data, arrays, label, uv, pixel_sigma)
                             if args.pixels else {"note": "no covariance: --points have no "
                                                          "pixels (score --pixels for one)"})
    summary_of = report["uncertainty"].get("summaries", {}).get(label)
    report["methods"][label]["coverage_95"] = (summary_of["coverage"]["coverage_95"]
                                               if summary_of else None)
    with output.staged() as tmp:
        report = _write_outputs(tmp, report, arrays, label, start)
    summary = _summary_line(data, report, label, summary_of, several)
    if args.json:
        import json

        log(summary)
        print(json.dumps(report, indent=2, allow_nan=False))
    else:
        print(summary)
    print(f"wrote {output.path}", file=sys.stderr if args.json else sys.stdout)
    return _verdict(args, report, label, log)


def _check_options(args) -> tuple[str, object]:
    """``(method, pixel σ)`` to score with; CLIError for options that do not apply together."""
    if args.points and args.method is not None:
        raise CLIError("--method does not apply with --points: your points are scored as they "
                       "are (--method triangulates --pixels)")
    if args.pixels and args.units is not None:
        raise CLIError("--units does not apply with --pixels: the pairs are triangulated here, "
                       "in mm (--units is the unit of --points)")
    pixel_sigma = parse_pixel_sigma(args.pixel_sigma)
    if not args.pixels and pixel_sigma != AUTO:
        raise CLIError("--pixel-sigma applies with --pixels only: the covariance of a point "
                       "comes from its two pixels")
    method = args.method or "optical_path"
    if args.absorbed_calib and method != "absorbed":
        raise CLIError(f"--absorbed-calib {args.absorbed_calib} applies with --method absorbed "
                       f"only")
    if args.submission and method == "absorbed":
        raise CLIError("--method absorbed does not apply with --submission: score a dataset's "
                       "--pixels with it")
    if args.submission and args.method is not None:
        refuse_method_without_pairs(args.dataset, args.submission, method)
    if args.submission and args.out and _inside(args.out, args.dataset):
        raise CLIError(f"--out {args.out}: inside the suite {args.dataset} (a suite's folder holds "
                       f"what synth suite wrote; scores there would make it refuse to resume): "
                       f"write the scores beside it")
    return method, pixel_sigma


def _read_data(args):
    """``(dataset, several)``: the dataset (of two cameras, or of N: ``several``)."""
    from synth.products.dataset import DatasetError, is_views_dataset, read_dataset

    several = is_views_dataset(args.dataset)
    if several and not args.points:
        raise CLIError(f"--pixels {args.pixels}: pairs of pixels are two views, and "
                       f"{args.dataset} is a dataset of N cameras: score its --points (eval run "
                       f"--from measures its images with every view)")
    try:
        return read_dataset(args.dataset), several
    except DatasetError as exc:
        raise CLIError(str(exc)) from None


def _points_to_score(args, data, method):
    """``(points (N, 3) mm, uv, label, source)``: ``--points`` as given (in mm), or
    ``--pixels`` triangulated with ``method`` and the dataset's calibration (``uv``: the valid
    pairs' left and right pixels; None for points)."""
    from measure import triangulate

    if args.points:
        units = args.units or "mm"
        return (read_points(args.points) * UNITS[units], None, "theirs",
                {"points": os.path.abspath(args.points), "units": units})
    pairs = read_pixel_pairs(args.pixels)
    if method == "absorbed":
        result = triangulate(_absorbed_rig(args, data), pairs[:, :2], pairs[:, 2:],
                             "optical_path")
    else:
        result = triangulate(data.rig, pairs[:, :2], pairs[:, 2:], method)
    if not result.valid.any():
        raise CLIError(f"--pixels {args.pixels}: no pair triangulates with {method} "
                       f"and the dataset's calibration")
    return (result.points[result.valid], (pairs[result.valid, :2], pairs[result.valid, 2:]),
            method, {"pixels": os.path.abspath(args.pixels), "method": method,
                     "pairs": int(len(pairs)), "invalid": int((~result.valid).sum())})


def _write_outputs(tmp, report, arrays, label, start) -> dict:
    """The scored points' PLY, the figures, the covariances' files, ``report.json`` and
    ``report.md`` into ``tmp``; returns the report as written."""
    from synth.infra.fileio import atomic_write_json, atomic_write_text, jsonable

    from eval.core.cloud_metrics import write_error_ply
    from eval.core.figures import ellipses_figure, error_maps_figure, histograms_figure
    from eval.core.uncertainty import write_uncertainty_files

    report["ply"] = write_error_ply(tmp, "points_scored.ply", arrays["points"], arrays["errors"])
    error_maps_figure(os.path.join(tmp, "error_maps.png"), {label: arrays})
    histograms_figure(os.path.join(tmp, "histograms.png"), {label: arrays})
    if "covariance" in arrays:
        report["uncertainty"]["files"] = {label: write_uncertainty_files(
            tmp, label, arrays["points"], arrays["covariance"], arrays["errors"])}
        ellipses_figure(os.path.join(tmp, "ellipses.png"), {label: arrays})
    report["timings_s"] = {"total": time.perf_counter() - start}
    report = jsonable(report)
    atomic_write_json(os.path.join(tmp, "report.json"), report)
    atomic_write_text(os.path.join(tmp, "report.md"), markdown(report))
    return report


def _summary_line(data, report, label, summary_of, several) -> str:
    """The one line printed: association, scores and coverage."""
    st = report["methods"][label]
    a = report["association"]
    summary = (f"{data.path}: {a['associated']} of {a['points']} points within "
               f"{a['gate_mm']:g} mm of a target ({unassociated_text(a)}); "
               f"{a['visible_in_both_scored']} of {a['visible_in_both']} targets visible in "
               f"{'two or more' if several else 'both'} views scored; RMS dP "
               f"{fmt(st['rms_dp_mm'])} mm, max dP {fmt(st['max_dp_mm'])} mm, mean dZ "
               f"{fmt(st['mean_dz_mm'])} mm, Chamfer {fmt(st['chamfer_mm'])} mm, F@1mm "
               f"{fmt(st['fscore_1mm'])}")
    if not summary_of and report["uncertainty"].get("note", "").startswith("no coverage"):
        summary += f"; {report['uncertainty']['note'].split(' (')[0]}"
    if summary_of:
        summary += (f"; coverage of the 95 % ellipsoids {fmt(summary_of['coverage']['coverage_95'])}"
                    f" (median σz {fmt(summary_of['sigma']['median_sigma_mm']['z'], 4)} mm)")
    return summary


def _verdict(args, report, label, log) -> int:
    """1 (with a FAIL line naming the likely cause) when none of the points was scored, else
    0."""
    a = report["association"]
    if not a["points"] or a["associated"]:
        return 0
    if not args.pixels:
        log(f"FAIL: none of the {a['points']} points lies within {a['gate_mm']:g} mm of a "
            f"target (Chamfer {fmt(report['methods'][label]['chamfer_mm'])} mm): nothing was "
            f"scored (the points in another unit or frame? the warnings say which)")
        return 1
    # the pixels were triangulated here and none of the points was scored
    hint = (" --method absorbed puts its points in the pinhole model's virtual frame, tens "
            "of mm off the targets: give a wider --gate-mm (e.g. 200) and read its length "
            "errors" if label == "absorbed" else
            " the pixels do not fit this dataset's calibration (another rig, or left and "
            "right swapped), or give a wider --gate-mm")
    log(f"FAIL: none of the {a['points']} points lies within {a['gate_mm']:g} mm of a "
        f"target (Chamfer {fmt(report['methods'][label]['chamfer_mm'])} mm): nothing was "
        f"scored;{hint}")
    return 1


def _absorbed_rig(args, data):
    """The absorbed method's rig for ``data``: ``--absorbed-calib``'s, or the dataset's boards
    through its port calibrated as pinhole cameras (:mod:`eval.core.absorbed`)."""
    from eval.core.absorbed import analytic_absorbed_calibration, read_absorbed_calibration

    size = data.rig.left.size
    try:
        if args.absorbed_calib:
            return read_absorbed_calibration(args.absorbed_calib, size).rig
        if not data.rig.port.refracts:
            raise ValueError(f"{data.path}: the dataset has no port (all air): there is nothing "
                             f"for --method absorbed to absorb")
        return analytic_absorbed_calibration(data.rig).rig
    except ValueError as exc:
        raise CLIError(str(exc)) from None


def score_covariances(data, arrays, label, uv, pixel_sigma) -> dict:
    """The report's ``uncertainty`` of ``--pixels`` triangulated with ``label``: covariances of
    the associated points (into ``arrays["covariance"]``) from ``pixel_sigma`` (``auto``: the
    reprojection residuals; no detections here) and the covariance of the dataset's
    ``calib.yaml``, if it holds one; their σ and coverage against the truth. Only the
    optical-path points get covariances (:mod:`measure.stereo.uncertainty`)."""
    from synth.products.dataset import read_calib

    from eval.core.uncertainty import (method_covariances, pair_sigmas, rig_covariance_note,
                                       uncertainty_summary)

    calib_path = os.path.join(data.path, "calib.yaml")
    rig_covariance = read_calib(calib_path)["covariance"]
    info = {"rig": rig_covariance_note(rig_covariance, calib_path)}
    if label != "optical_path":
        info["note"] = f"no covariance for {label} (only optical_path gets one)"
        return info
    ok = arrays["associated"]
    points = arrays["all_points"]
    sigma, info["pixel_sigma"] = pair_sigmas(pixel_sigma, uv[0], uv[1], points, data.rig)
    noise = info["pixel_sigma"].get("median_px")
    if pixel_sigma == AUTO and rig_covariance is None and (noise is None or noise < EXACT_PX):
        info["note"] = (f"no coverage: the pixels carry no noise (σ from the reprojection "
                        f"residuals {noise if noise is not None else float('nan'):.2g} px, below "
                        f"{EXACT_PX:g} px: exact pixels, e.g. a simulator's), so the errors are "
                        f"rounding and ellipsoids of that size say nothing (--pixel-sigma PX "
                        f"states a σ)")
        return info
    covariance = method_covariances(data.rig, {label: points}, sigma, rig_covariance)[label]
    arrays["covariance"] = covariance.total[ok]
    info["summaries"] = {label: uncertainty_summary(arrays["covariance"], arrays["errors"])}
    return info


#: A pixel σ (px) from the residuals below this is rounding: the pixels carry no noise (a
#: detector's σ is 1e-3 px and more; a float32 render's ray positions 1e-4 px).
EXACT_PX = 1e-9


def refuse_method_without_pairs(suite_dir: str, sub_dir: str, method: str) -> None:
    """CLIError when ``--method`` cannot apply to any submission of ``sub_dir``: it triangulates
    a ``pairs.csv`` and picks ``points_<method>.ply``; a ``points.ply`` cloud or a depth map is
    scored as it is."""
    from eval.core.suite_scores import find_submission, read_suite

    if not os.path.isdir(sub_dir):
        return  # said by score_suite
    _, index = read_suite(suite_dir)
    for row in index:
        if row.get("status") != "ok" or row.get("render") != "targets":
            continue
        found = find_submission(os.path.join(sub_dir, row["folder"]), row["render"], method)
        if found and (found[0] == "pairs" or os.path.basename(found[1]) != "points.ply"):
            return
    raise CLIError(f"--method {method} does not apply: no submission in {sub_dir} is a pairs.csv "
                   f"or a points_{method}.ply (a points.ply cloud or a depth map is scored as it "
                   f"is; --method triangulates pairs.csv)")


def score_suite_main(args, output, method, log, start) -> int:
    """``--submission DIR``: every dataset of the suite ``args.dataset`` scored; the summary
    files into ``--out``; exit 1 when a dataset is missing or failed, 3 when the scoring of a
    dataset met an internal error (the others are scored and the summary written)."""
    from synth.infra.fileio import atomic_write_json, jsonable

    from eval.core.suite_scores import FAILURES, INTERNAL_ERROR, score_suite, write_summary
    from synth.infra.cli import EXIT_CHECK_FAILED, EXIT_INTERNAL_ERROR

    if args.units is not None:
        raise CLIError("--units does not apply with --submission: the points of a submission "
                       "are in mm (metres are detected and reported)")
    info, rows = score_suite(args.dataset, args.submission, method, args.gate_mm,
                             log=None if args.no_progress else log)
    with output.staged() as tmp:
        files = write_summary(tmp, info, rows, args.dataset, args.submission)
        atomic_write_json(os.path.join(tmp, "summary.json"), jsonable(
            {"suite": os.path.abspath(args.dataset), "submission":
             os.path.abspath(args.submission), "method": method, "datasets": rows,
             "timings_s": {"total": time.perf_counter() - start}}))
    failed = [r for r in rows if r["status"] in FAILURES]
    warned = [r for r in rows if r.get("warnings")]
    for r in failed:
        log(f"failure: {r['folder']} ({r['status']}): {r['error']}")
    for r in warned:
        log(f"warning: {r['folder']}: {r['warnings']}")
    if args.json:
        import json

        print(json.dumps(jsonable(rows), indent=1))
    print(f"{args.dataset}: {len(rows)} datasets, {len(rows) - len(failed)} scored, "
          f"{len(failed)} missing or failed, {len(warned)} with warnings; wrote {output.path}/"
          f"{', '.join(files[:3])} and {len(files) - 3} figure(s)",
          file=sys.stderr if args.json else sys.stdout)
    if any(str(r.get("error") or "").startswith(INTERNAL_ERROR) for r in failed):
        return EXIT_INTERNAL_ERROR
    return EXIT_CHECK_FAILED if failed else 0


def score_surface_main(args, data, output, log, start) -> int:
    """``--points`` scored against a surface dataset (``eval measure --dense``'s ``points.ply``
    outside a suite): every point against the true mesh and its pixel's true point
    (:func:`eval.core.suite_scores.score_surface_points`, the suite's scores); ``report.json``,
    ``report.md``; exit 1 when no point lies within 5 mm of the surface."""
    from eval.core.suite_scores import SURFACE_GATE_MM, SURFACE_METRICS, score_surface_points
    from synth.infra.fileio import atomic_write_json, atomic_write_text, jsonable

    units = args.units or "mm"
    points = read_points(args.points) * UNITS[units]
    if args.gate_mm is not None:
        raise CLIError(f"--gate-mm does not apply to {args.dataset}: a surface dataset's points "
                       f"are scored against its mesh, not associated with targets")
    scores, warnings = score_surface_points(data, points)
    if warnings:
        log(f"warning: --points {args.points}: " + "; ".join(warnings))
    report = jsonable({"dataset": os.path.abspath(data.path), "kind": "surface",
                       "source": {"points": os.path.abspath(args.points), "units": units},
                       "warnings": warnings, "scores": scores,
                       "timings_s": {"total": time.perf_counter() - start}})
    lines = [f"# Score of {args.points} against the surface of {data.path}", "",
             *[f"**Warning:** {w}" for w in warnings], *([""] if warnings else []),
             f"{len(points)} points against the true mesh and each point's pixel's true point "
             f"(mm):", "", "| " + " | ".join(SURFACE_METRICS) + " |",
             "|" + "---|" * len(SURFACE_METRICS),
             "| " + " | ".join(fmt(scores.get(k)) for k in SURFACE_METRICS) + " |"]
    with output.staged() as tmp:
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        atomic_write_text(os.path.join(tmp, "report.md"), "\n".join(lines) + "\n")
    print(f"{data.path} (a surface): {len(points)} points; point to mesh RMS "
          f"{fmt(scores.get('p2m_rms_mm'))} mm, median {fmt(scores.get('p2m_median_mm'))} mm; "
          f"depth RMS {fmt(scores.get('depth_rms_mm'))} mm; F@1mm "
          f"{fmt(scores.get('fscore_1mm'))}; {fmt(scores.get('measured_fraction'))} of the "
          f"overlap pixels measured")
    print(f"wrote {output.path}")
    near = scores.get(f"precision_{SURFACE_GATE_MM:g}mm")
    if not len(points) or near == 0:
        print(f"FAIL: none of the {len(points)} points lies within {SURFACE_GATE_MM:g} mm of the "
              f"surface", file=sys.stderr)
        return 1
    return 0


def markdown(report: dict) -> str:
    """``report.md``: the association and one table of the metrics."""

    a = report["association"]
    label, st = next(iter(report["methods"].items()))
    keys = ["n", "rms_dp_mm", "max_dp_mm", "mean_dx_mm", "mean_dy_mm", "mean_dz_mm",
            "chamfer_mm", "fscore_1mm", "fscore_5mm", "rms_dp_aligned_mm", "flatness_mm"]
    lines = [f"# Score of {label} against {report['dataset']}", "",
             *[f"**Warning:** {warning}" for warning in report.get("warnings", [])],
             *([""] if report.get("warnings") else []),
             f"{a['associated']} of {a['points']} points associated with a target within "
             f"{a['gate_mm']:g} mm ({unassociated_text(a)}); {a['visible_in_both_scored']} of "
             f"{a['visible_in_both']} targets visible in both views scored. Errors over the "
             f"associated points (mm); Chamfer and F-scores of all points against the targets "
             f"visible in both views.", "",
             "| " + " | ".join(keys) + " |", "|" + "---|" * len(keys),
             "| " + " | ".join(str(st[k]) if k == "n" else fmt(st[k]) for k in keys) + " |"]
    return "\n".join(lines) + "\n"
