"""``python -m eval run SCENE``: render, detect, match, triangulate and score — end to end.

Writes ``DIR/report.json``, ``DIR/report.md``, the figures (``views.png``, ``error_maps.png``,
``histograms.png``; none with ``--no-figures``) and one PLY per method (``points_<method>.ply``,
coloured by dP). The output directory appears whole or not at all. See the README for the
report's fields.
"""

from __future__ import annotations

import argparse

import json
import os
import sys
import time

from eval.cli import non_negative_float, positive_float, positive_int
from eval.core.formatting import format_number as fmt
from eval.core.detection import add_detector_options
from eval.core.uncertainty import add_pixel_sigma_option
from eval.run.config import COMMAND, RunConfig
from eval.run.report import (UNCORRECTED, budget_table, report_markdown, summary_table, verdict_exit_code,
                             write_outputs)
from synth.infra.cli import (add_define_option, add_full_film_option, add_json_option,
                       add_out_option, add_progress_option, add_scene_argument, scene_seed)


def add_parser(subparsers):
    parser = subparsers.add_parser(
        "run", help="render a scene, measure it and score the point clouds",
        description="Render SCENE (or reuse --from DIR), detect and match the targets without "
                    "ground truth, triangulate with each method and score against the truth.")
    add_scene_argument(parser)
    add_out_option(parser, COMMAND, "out/run")
    parser.add_argument("--from", dest="from_dir", metavar="DIR",
                        help="reuse the images of a dataset written by python -m synth dataset")
    parser.add_argument("--spp", type=positive_int, help="samples per pixel (default: the scene's)")
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")
    add_full_film_option(parser)
    parser.add_argument("--methods", default=None,
                        help="comma-separated triangulation methods: optical_path, su, regular, "
                             "reprojection, absorbed (the port absorbed by a pinhole "
                             "calibration; default: optical_path,su,regular)")
    parser.add_argument("--noise-px", type=non_negative_float, default=0.0,
                        help="Gaussian noise σ (px) added to the detected centres (default 0)")
    parser.add_argument("--seed", type=scene_seed, default=None,
                        help="the run's one seed: the scene's seed (same as -D seed=S; with "
                             "--from, the dataset's images are used as they are), the added "
                             "noise and the plane fit (default: the scene's seed)")
    parser.add_argument("--gate-mm", type=positive_float, default=0.5,
                        help="largest common-perpendicular length of a matched pair (mm, default 0.5)")
    parser.add_argument("--depth-range", metavar="NEAR,FAR",
                        help="working range along the port normal (mm); default: the scene's "
                             "target_z × (0.8, 1.25), or for targets in depth their nearest "
                             "and farthest depths × (0.8, 1.25)")
    add_define_option(parser)
    parser.add_argument("--assume", action="append", default=[], metavar="name=value",
                        help="what the measurement believes, when it differs from the rendered "
                             "truth (repeatable): n_water, n_glass, port_distance, "
                             "glass_thickness, port_normal, focal, left_focal, right_focal, "
                             "left_dist, right_dist; n_water=T=<°C>,S=<PSU>[,wavelength=<nm>] "
                             "computes the index (Quan & Fry 1995)")
    parser.add_argument("--calib", metavar="FILE",
                        help="measure with this calibration instead of the scene's rig: a "
                             "calib.yaml (as datasets write it), a calibmar stereo YAML or the "
                             "COLMAP fork's cameras.txt with rig_config.json beside it; --assume "
                             "applies on top")
    parser.add_argument("--compare-calib", action="append", default=[], metavar="FILE",
                        help="error budget: also measure the same detections with this "
                             "calib.yaml (repeatable); with --calib or --assume the exact "
                             "calibration is always compared")
    parser.add_argument("--absorbed-calib", metavar="FILE", default=None,
                        help="the absorbed method's calibration: a calib.yaml without a port "
                             "(eval calibrate --model absorbed); default: the scene's boards "
                             "projected through its port and calibrated as pinhole cameras")
    parser.add_argument("--self-calibrate", metavar="NAMES", default="",
                        help="estimate these port parameters from the matched targets "
                             "(comma list of n_water, port_distance, port_normal), measure "
                             "again with them and report before and after")
    parser.add_argument("--eccentricity", action=argparse.BooleanOptionalAction, default=None,
                        help="correct the detected centres for the disk targets' eccentricity "
                             "(default on target scenes; the uncorrected numbers are reported "
                             "beside); --no-eccentricity: the raw centroids only")
    add_detector_options(parser)
    add_pixel_sigma_option(parser)
    parser.add_argument("--sensor", metavar="PRESET[,name=value…]",
                        help="pass the rendered images through a camera sensor (exposure, shot "
                             "and read noise, dark level, gain, bit depth), seeded: preset "
                             "imx174; overrides full_well_e, read_noise_e, bit_depth, "
                             "dark_level_dn, exposure")
    parser.add_argument("--no-figures", action="store_true",
                        help="do not draw the figures (the PNG files; 1-3 s of a run on 2 "
                             "cores): the report, PLY and CSV files are the same")
    add_json_option(parser)
    add_progress_option(parser)


def main(args) -> int:
    from synth.infra.fileio import OutputDir, atomic_write_json, atomic_write_text, jsonable
    from synth.infra.provenance import package_versions

    from eval.run import dense

    quiet = args.no_progress
    log = (lambda text: None) if quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    config = RunConfig.from_args(args)
    for note in config.assumption_notes:  # e.g. n_water computed from T and S
        log(note)
    if dense.is_surface_scene(config.scene):
        return dense.main(config, args.out, args.json, log)
    from eval.run import multiview

    if multiview.is_multiview_scene(config.scene):  # more than two cameras
        return multiview.main(config, args.out, args.json, log)
    config.target_methods()  # refuses an unknown --methods before any expensive work
    output = OutputDir(args.out, COMMAND).claim()  # before any expensive work
    from eval.run.pipeline import measure_scene  # SciPy, Open3D: once the options are checked

    start = time.perf_counter()
    result = measure_scene(config, log)
    report = result.report
    log("write the report, figures and point clouds …")
    t = time.perf_counter()
    with output.staged() as tmp:
        report["versions"] = package_versions()
        report["inputs"] = result.inputs.extra
        write_outputs(tmp, result, figures=not config.no_figures)
        report["timings_s"]["report"] = time.perf_counter() - t
        report["timings_s"]["total"] = time.perf_counter() - start
        report = jsonable(report)
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        atomic_write_text(os.path.join(tmp, "report.md"), report_markdown(report))
    out = output.path
    from synth.rendering.render import spp_text

    summary_stream = sys.stderr if args.json else sys.stdout
    m, c = report["matching"], report["crosscheck"]
    print(f"{report['scene']}: {m['visible_in_both']} targets visible in both views, "
          f"{m['pairs']} matched ({m['correct']} correct, {m['wrong']} wrong), cross-check RMS "
          f"{fmt(c['rms_px'], 4)} px, max {fmt(c['max_px'], 4)} px (outline centroid: RMS "
          f"{fmt(c['rms_px_outline'], 4)} px, max {fmt(c['max_px_outline'], 4)} px); "
          f"{report['variant']} {spp_text(report['spp'], report.get('spp_rendered'))}"
          f"{'; sensor ' + report['sensor']['model']['name'] if report.get('sensor') else ''}; "
          f"total {report['timings_s']['total']:.1f} s",
          file=summary_stream)
    print(summary_table(report), file=summary_stream)
    coverage = {m: v["coverage_95"] for m, v in report["methods"].items()
                if v.get("coverage_95") is not None}
    uncorrected = ((report.get("eccentricity") or {}).get("uncorrected") or {})
    raw = (uncorrected.get("uncertainty") or {}).get("summaries") or {}
    coverage.update({f"{m} {UNCORRECTED}": v["coverage"]["coverage_95"] for m, v in raw.items()
                     if (v.get("coverage") or {}).get("coverage_95") is not None})
    if coverage:
        print("coverage of the 95 % ellipsoids: " + ", ".join(
            f"{m} {fmt(v, 3)}" for m, v in coverage.items()) + f" ({report['uncertainty']['rig']})",
            file=summary_stream)
        summaries = dict(report["uncertainty"].get("summaries") or {})
        summaries.update({f"{m} {UNCORRECTED}": v for m, v in raw.items()})
        for method, summary in summaries.items():
            verdict = (summary.get("coverage") or {}).get("verdict")
            if verdict:
                print(f"  {method}: {verdict}", file=summary_stream)
    print(f"wrote {out}", file=summary_stream)
    if report.get("budget"):
        print(budget_table(report), file=summary_stream)
    calibration = report.get("self_calibration")
    if calibration:
        if calibration.get("methods"):
            for name, value in calibration["estimates"].items():
                sigma = calibration["sigmas"][name]
                covered = (f"σ with the --calib covariance of "
                           f"{len(calibration['sigma_includes'])} fixed rig parameters; without "
                           f"{calibration['sigmas_conditional'][name]}"
                           if calibration.get("sigma_includes") else
                           "σ conditional on the rig, which has no covariance")
                print(f"self-calibrated {name}: {value} ± {sigma} (truth {calibration['truth'][name]}, "
                      f"assumed {calibration['assumed'][name]}; {covered}); reprojection RMS "
                      f"{calibration['rms_px_before']:.4f} -> {calibration['rms_px_after']:.4f} px",
                      file=summary_stream)
            print(summary_table({"methods": calibration["methods"]}), file=summary_stream)
        else:
            print(f"self-calibration: no trusted estimate "
                  f"({calibration['reason'] or calibration['message']})", file=summary_stream)
    if args.json:
        print(json.dumps(report, indent=2))
    return verdict_exit_code(report, out)

