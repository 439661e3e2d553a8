"""``python -m eval measure --calib FILE LEFT RIGHT``: measure a user's stereo photos — no truth.

LEFT RIGHT are two photos (one pair) or two folders (pairs by file name). The calibration
(``calib.yaml`` as ``synth dataset`` writes it; :func:`synth.formats.calib_yaml.read_calib`) must be for
the photos' size. Targets are detected (the detector options of ``eval run``), matched without
truth (:func:`measure.stereo.matching.match_targets`) and triangulated with ``--methods`` (default
``optical_path``); with ``--dense --depth-range NEAR,FAR`` a speckled surface is matched per
pixel (:func:`measure.dense.match.match_dense`) instead.

Writes into ``--out`` (whole or not at all): ``points.ply`` (the first method's points, mm,
binary; further methods ``points_<method>.ply``), ``points.csv``, ``report.json``,
``report.md`` and ``views.png`` (one pair) or ``views_<pair>.png`` (each pair of several).

Errors (one ``error:`` line, exit 2, nothing written): an unreadable calibration or photo, a
photo without a partner, a photo whose size is not the calibration's, an option that does not
apply, and a pair where nothing is matched — in a run of one pair. In a run of several pairs
such a pair is reported (``problem`` in the report, a line on stderr) and the others are
measured; only when no pair is measured is it an error (then only the error is printed).

Exit 1 (the report still written, one ``failed:`` line per pair on stderr): a pair that matched
fewer than half of the targets its sparser view detected — photos that are not the pair the
calibration describes (left and right swapped, not a stereo pair, one photo twice);
:func:`eval.measure.pipeline.pair_mismatch`.
"""

from __future__ import annotations

import json
import os
import sys
import time

from eval.cli import CLIError, positive_float
from eval.core.detection import DETECTOR_OPTIONS, add_detector_options
from eval.core.formatting import format_number as fmt
from eval.core.photos import add_encoding_option, encoding_note
from eval.core.uncertainty import add_pixel_sigma_option, parse_pixel_sigma
from measure.images.detect import FLOOR_FRACTION
from synth.infra.cli import (EXIT_CHECK_FAILED, add_json_option, add_out_option,
                             add_progress_option, option_number, refuse_given)

COMMAND = "eval measure"
DEFAULT_METHODS = ("optical_path",)
DEFAULT_GATE_MM = 0.5


def add_parser(subparsers):
    p = subparsers.add_parser(
        "measure", help="measure your own stereo photos with a calibration (no truth)",
        description="Detect, match and triangulate the targets of stereo photos (LEFT RIGHT: two "
                    "photos, or two folders of photos paired by file name) with a calibration; "
                    "or, with --dense, measure a speckled surface per pixel. Nothing is "
                    "compared with a truth.")
    p.add_argument("left", metavar="LEFT", help="left photo, or folder of left photos")
    p.add_argument("right", metavar="RIGHT", help="right photo, or folder of right photos "
                                                  "(paired with the left ones by file name)")
    p.add_argument("more", metavar="MORE", nargs="*",
                   help="a rig of N > 2 cameras: the photos of the third camera on, one capture "
                        "(LEFT RIGHT MORE… are cam0 cam1 cam2 … in the calibration's order)")
    p.add_argument("--calib", required=True, metavar="FILE",
                   help="the rig's calibration for the photos' image size: calib.yaml (as "
                        "python -m synth dataset and eval calibrate write it), calibmar's YAML "
                        "(either file of the pair) or the COLMAP fork's cameras.txt "
                        "(rig_config.json beside it)")
    add_out_option(p, COMMAND, "out/measure")
    p.add_argument("--methods", default=None,
                   help="comma-separated triangulation methods (default optical_path; targets: "
                        "optical_path, su, regular, reprojection; --dense: optical_path, "
                        "regular); the first one's points go into points.ply")
    p.add_argument("--gate-mm", type=positive_float, default=None,
                   help=f"largest common-perpendicular length of a matched pair of targets "
                        f"(mm, default {DEFAULT_GATE_MM:g})")
    p.add_argument("--depth-range", metavar="NEAR,FAR",
                   help="working range along the port normal (behind domes: the left camera's "
                        "optical axis) (mm): targets are matched only there (default: no "
                        "bound); required with --dense (the sweep's range)")
    add_detector_options(p)
    add_pixel_sigma_option(p)
    p.add_argument("--floor-fraction", type=floor_fraction, default=None, metavar="F",
                   help=f"the automatic detection threshold is at least F of the way from the "
                        f"background to the targets' level (default {FLOOR_FRACTION:g}: "
                        f"keeps JPEG ringing out of the targets; 0: no floor)")
    add_encoding_option(p)
    p.add_argument("--dense", action="store_true",
                   help="measure a speckled surface per pixel (dense matching through the port) "
                        "instead of targets; needs --depth-range; the target options are "
                        "refused")
    add_json_option(p)
    add_progress_option(p)


def floor_fraction(text: str) -> float:
    """argparse type: a number in [0, 1)."""
    import argparse

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 0 and below 1, got {text}")
    return value


def _methods(args) -> tuple:
    """The methods of the run; CLIError names an unknown one."""
    from measure import METHODS

    from eval.run.config import split_names
    from eval.run.dense import DENSE_METHODS

    known = tuple(DENSE_METHODS) if args.dense else METHODS
    if args.methods is None:
        return DEFAULT_METHODS
    names = split_names(args.methods)
    unknown = [m for m in names if m not in known]
    if not names or unknown:
        raise CLIError(f"unknown method {', '.join(unknown) or repr(args.methods)} in --methods "
                       f"(choose from {', '.join(known)}{' with --dense' if args.dense else ''})")
    return names


def options_of(args):
    """The run's :class:`~eval.measure.pipeline.TargetOptions` or
    :class:`~eval.measure.pipeline.DenseOptions`; CLIError for an option that cannot apply."""
    from eval.measure.pipeline import DenseOptions, TargetOptions
    from eval.run.config import parse_depth_range

    methods = _methods(args)
    depth_range = parse_depth_range(args.depth_range)
    if args.dense:
        refuse_given(args, ["gate_mm", "floor_fraction", "pixel_sigma",
                            *(d for d in DETECTOR_OPTIONS if d != "median_filter")],
                     "with --dense (it applies to targets; --median-filter does apply)")
        if depth_range is None:
            raise CLIError("--dense needs --depth-range NEAR,FAR (mm along the port normal; "
                           "behind domes along the left camera's optical axis): the range the "
                           "matcher sweeps")
        return DenseOptions(methods, depth_range, args.median_filter)
    return TargetOptions(methods, DEFAULT_GATE_MM if args.gate_mm is None else args.gate_mm,
                         depth_range or (None, None),
                         **{d: getattr(args, d) for d in DETECTOR_OPTIONS},
                         floor_fraction=FLOOR_FRACTION if args.floor_fraction is None
                         else args.floor_fraction,
                         pixel_sigma=parse_pixel_sigma(args.pixel_sigma))


def _progress_bar(quiet: bool):
    """``progress(method)`` for the dense matcher: a tqdm bar over the sweep planes."""
    if quiet:
        return None
    from tqdm import tqdm

    def for_method(method):
        bar = {}

        def update(done, total):
            if "bar" not in bar:
                bar["bar"] = tqdm(total=total, desc=f"{method} sweep", unit="plane",
                                  leave=False, file=sys.stderr)
            bar["bar"].update(done - bar["bar"].n)
            if done >= total:
                bar["bar"].close()

        return update

    return for_method


def measure_all(inputs, options, quiet: bool, log) -> list:
    """Every pair measured, in name order (a tqdm bar over several pairs)."""
    from eval.measure.pipeline import (DenseOptions, ambiguity_warning, measure_dense,
                                        measure_targets)

    dense = isinstance(options, DenseOptions)
    indices = range(len(inputs.names))
    if len(inputs.names) > 1 and not quiet:
        from tqdm import tqdm

        indices = tqdm(indices, desc="pairs", unit="pair", file=sys.stderr)
    results = []
    for index in indices:
        name = inputs.names[index]
        left, right = inputs.read(index)
        if dense:
            log(f"{name}: dense matching ({', '.join(options.methods)}, depth "
                f"{options.depth_range[0]:g}-{options.depth_range[1]:g} mm) …")
            try:
                result = measure_dense(inputs.rig, name, left, right, options,
                                       _progress_bar(quiet))
            except ValueError as exc:
                raise CLIError(f"--depth-range {option_number(options.depth_range[0])},"
                               f"{option_number(options.depth_range[1])}: {exc}") from None
        else:
            result = measure_targets(inputs.rig, name, left, right, options,
                                     inputs.rig_covariance)
            warning = ambiguity_warning(result, options)
            if warning:
                print(f"warning: {warning}", file=sys.stderr)
        results.append(result)
    if len(results) > 1 and not all(r.problem for r in results):  # else the error says it
        for result in results:
            if result.problem:
                print(f"warning: {result.problem}; the other pairs are measured",
                      file=sys.stderr)
    return results


def build_report(inputs, options, results) -> dict:
    from eval.measure.pipeline import DenseOptions
    from eval.measure.report import pair_entry, summarize

    dense = isinstance(options, DenseOptions)
    pairs = [pair_entry(r, (inputs.left[i], inputs.right[i])) for i, r in enumerate(results)]
    settings = ({"depth_range_mm": list(options.depth_range),
                 "median_filter": options.median_filter} if dense else
                {"gate_mm": options.gate_mm,
                 "depth_range_mm": [None if v is None else float(v)
                                    for v in options.depth_range],
                 **{d: getattr(options, d) for d in (*DETECTOR_OPTIONS, "floor_fraction")}})
    from eval.measure.report import uncertainty_report

    return {"command": COMMAND, "calib": inputs.calib_path, "has_port": inputs.has_port,
            "model": calibration_model(inputs.calib_path),
            "encoding": inputs.encoding,
            "image_size": list(inputs.size), "mode": "dense" if dense else "targets",
            "methods": list(options.methods), "options": settings, "pairs": pairs,
            "summary": summarize(pairs, options.methods, results),
            "uncertainty": uncertainty_report(inputs, options, results, pairs)}


def write_outputs(tmp: str, report: dict, results) -> None:
    """The point clouds, ``points.csv`` and the views into ``tmp`` (their names into the
    report's ``files``)."""
    from eval.measure.figures import views_figure
    from eval.measure.pipeline import pair_pixels
    from eval.measure.report import (method_points, write_cloud, write_points_csv,
                                     write_uncertainty_outputs)

    clouds = {}
    for i, method in enumerate(report["methods"]):
        name = "points.ply" if i == 0 else f"points_{method}.ply"
        write_cloud(os.path.join(tmp, name), method_points(results, method))
        clouds[method] = name
    rows = write_points_csv(os.path.join(tmp, "points.csv"), results, pair_pixels)
    write_uncertainty_outputs(tmp, report, results)
    views = []
    for result in results:
        name = "views.png" if len(results) == 1 else f"views_{result.name}.png"
        views_figure(os.path.join(tmp, name), result, report["methods"][0])
        views.append(name)
    report["files"] = {"clouds": clouds, "csv_rows": rows, "views": views}


def summary_line(report: dict) -> str:
    """The printed line. Targets: the gap RMS per method. Dense: the plane fit's RMS per method
    (of each measured pair, a range over several) — dense matches lie on the epipolar curves by
    construction, so their gap is ~0 and says nothing (docs/measure.md)."""
    s = report["summary"]
    if report["mode"] == "dense":
        what, check = "pixels", "plane fit RMS"
        values = {}
        for method in s["methods"]:
            rms = [p["methods"][method]["plane"]["rms_mm"] for p in report["pairs"]
                   if not p["problem"] and (p["methods"].get(method) or {}).get("plane")]
            values[method] = (f"{fmt(min(rms), 3)}–{fmt(max(rms), 3)}" if len(rms) > 1 else
                              fmt(rms[0], 3) if rms else "–")
    else:
        what, check = "targets", "gap RMS"
        values = {m: fmt(v["rms_mm"], 4) for m, v in s["methods"].items()}
    checks = ", ".join(f"{m} {v} mm" for m, v in values.items())
    return (f"{s['pairs']} pair(s), {s['measured_pairs']} measured: {s['matched']} {what} "
            f"matched; {check} {checks}; total {report['timings_s']['total']:.1f} s")


def _cameras_in(path) -> int:
    """How many cameras a calibration file holds (2 unless it is a calib.yaml of N cameras;
    an unreadable file is left to the reader that names the problem)."""
    from synth.products.dataset import DatasetError
    from synth.products.rig_file import read_rig_file

    try:
        return len(read_rig_file(path).cameras)
    except (DatasetError, ValueError, OSError):
        return 2


def calibration_model(path) -> str | None:
    """The ``model`` node of a calib.yaml (``absorbed`` for ``eval calibrate --model
    absorbed``), or None (another file, or none)."""
    import cv2

    if not str(path).lower().endswith((".yaml", ".yml")):
        return None
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error:
        return None
    try:
        node = fs.getNode("model") if fs.isOpened() else None
        return node.string() if node is not None and node.isString() else None
    finally:
        fs.release()


def main(args) -> int:
    from synth.infra.fileio import OutputDir, atomic_write_json, atomic_write_text, jsonable
    from synth.infra.provenance import package_versions

    from eval.measure.inputs import load_inputs
    from eval.measure.report import report_markdown

    quiet = args.no_progress
    log = (lambda text: None) if quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    start = time.perf_counter()
    if args.more or _cameras_in(args.calib) > 2:  # one capture of N cameras
        from eval.measure.views import measure_views_main

        if args.dense:
            raise CLIError(f"--dense does not apply to a capture of {2 + len(args.more)} "
                           f"cameras (dense matching is a two-view method)")
        options = options_of(args)
        output = OutputDir(args.out, COMMAND).claim()
        return measure_views_main(args, output, options, start, log)
    options = options_of(args)
    output = OutputDir(args.out, COMMAND).claim()  # before any work
    inputs = load_inputs(args.calib, args.left, args.right, args.encoding)
    note = encoding_note(inputs.left[0], args.encoding) if inputs.left else None
    if note:
        print(note, file=sys.stderr, flush=True)
    log(f"measure {len(inputs.names)} pair(s) of {inputs.size[0]}x{inputs.size[1]} px photos "
        f"with {args.calib} …")
    results = measure_all(inputs, options, quiet, log)
    problems = [r.problem for r in results if r.problem]
    if len(problems) == len(results):
        if len(results) == 1:  # named by its two files, not by the left file's stem
            problem = problems[0].removeprefix(f"{results[0].name}: ")
            raise CLIError(f"{inputs.left[0]}, {inputs.right[0]}: {problem}")
        raise CLIError(f"no pair was measured ({len(results)} pairs); the first: {problems[0]}")
    report = build_report(inputs, options, results)
    log("write the point clouds, points.csv, the report and the views …")
    with output.staged() as tmp:
        write_outputs(tmp, report, results)
        report["versions"] = package_versions()
        report["timings_s"] = {"total": time.perf_counter() - start}
        report = jsonable(report)
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        atomic_write_text(os.path.join(tmp, "report.md"), report_markdown(report))
    if not inputs.has_port:
        from eval.measure.report import calibration_note

        print(f"warning: {calibration_note(args.calib, calibration_model(args.calib))}",
              file=sys.stderr)
    stream = sys.stderr if args.json else sys.stdout
    print(summary_line(report), file=stream)
    print(f"wrote {output.path}", file=stream)
    if args.json:
        print(json.dumps(report, indent=2))
    failures = report["summary"]["failures"]
    for failure in failures:  # the run knows these points are not to be trusted
        print(f"failed: {failure} (report in {output.path})", file=sys.stderr)
    return EXIT_CHECK_FAILED if failures else 0
