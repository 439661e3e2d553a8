"""``python -m eval run SCENE``: render, detect, match, triangulate and score — end to end.

Writes ``DIR/report.json``, ``DIR/report.md``, the figures (``views.png``, ``error_maps.png``,
``histograms.png``) and one PLY per method (``points_<method>.ply``, coloured by dP). The output
directory appears whole or not at all. See the README for the report's fields.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass

from eval.cli import CLIError, non_negative_float, non_negative_int, positive_float, positive_int
from synth.cli import finite_float

from .run_options import (COMMAND, DEFAULT_METHODS, _fmt, _measurement_rig, _parse_range,
                          _parse_sensor)

#: argparse type of --max-elongation and --max-area-ratio (a blob's axis or area ratio).
_ABOVE_ONE = finite_float(1.0, strict=True, description="finite (> 1)")

PLY_COLORMAP = "viridis"


def add_parser(subparsers):
    parser = subparsers.add_parser(
        "run", help="render a scene, measure it and score the point clouds",
        description="Render SCENE (or reuse --from DIR), detect and match the targets without "
                    "ground truth, triangulate with each method and score against the truth.")
    parser.add_argument("scene", help="Mitsuba scene file (e.g. scenes/paper_plane.xml)")
    parser.add_argument("--out", default="out/run",
                        help="output directory (default out/run); an existing one is replaced "
                             "only if it is an earlier output of eval run")
    parser.add_argument("--from", dest="from_dir", metavar="DIR",
                        help="reuse the images of a dataset written by python -m synth dataset")
    parser.add_argument("--spp", type=positive_int, help="samples per pixel (default: the scene's)")
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")
    parser.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                        help="comma-separated triangulation methods (default: all three)")
    parser.add_argument("--noise-px", type=non_negative_float, default=0.0,
                        help="Gaussian noise σ (px) added to the detected centres (default 0)")
    parser.add_argument("--seed", type=non_negative_int, default=None,
                        help="the run's one seed: the scene's seed (same as -D seed=S; with "
                             "--from, the dataset's images are used as they are), the added "
                             "noise and the plane fit (default: the scene's seed)")
    parser.add_argument("--gate-mm", type=positive_float, default=0.5,
                        help="largest common-perpendicular length of a matched pair (mm, default 0.5)")
    parser.add_argument("--depth-range", metavar="NEAR,FAR",
                        help="working range along the port normal (mm); default: the scene's "
                             "target_z × (0.8, 1.25), or for targets in depth their nearest "
                             "and farthest depths × (0.8, 1.25)")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="name=value",
                        help="override a scene default (repeatable)")
    parser.add_argument("--assume", action="append", default=[], metavar="name=value",
                        help="what the measurement believes, when it differs from the rendered "
                             "truth (repeatable): n_water, n_glass, port_distance, "
                             "glass_thickness, port_normal, focal, left_focal, right_focal, "
                             "left_dist, right_dist")
    parser.add_argument("--calib", metavar="FILE",
                        help="measure with this calib.yaml (as datasets write it) instead of the "
                             "scene's rig; --assume applies on top")
    parser.add_argument("--compare-calib", action="append", default=[], metavar="FILE",
                        help="error budget: also measure the same detections with this "
                             "calib.yaml (repeatable); with --calib or --assume the exact "
                             "calibration is always compared")
    parser.add_argument("--self-calibrate", metavar="NAMES", default="",
                        help="estimate these port parameters from the matched targets "
                             "(comma list of n_water, port_distance, port_normal), measure "
                             "again with them and report before and after")
    parser.add_argument("--eccentricity", action="store_true",
                        help="also measure with the detected centres corrected for the disk "
                             "targets' eccentricity (reported beside the uncorrected numbers)")
    parser.add_argument("--threshold-fraction", type=_fraction, default=None, metavar="F",
                        help="detect with a fixed threshold F of the way from the background "
                             "(median) to the targets' level (99.99th percentile) instead of "
                             "median + 5 noise sigmas; for speckled renders of scattering water")
    parser.add_argument("--max-elongation", type=_ABOVE_ONE, default=None, metavar="E",
                        help="detected blobs more elongated than E (major/minor axis) are taken "
                             "for merged targets (default 1.6); raise it (e.g. 3) for targets "
                             "seen obliquely: tilted planes, cylinders, spheres")
    parser.add_argument("--median-filter", type=int, choices=(3, 5), default=0, metavar="K",
                        help="median-filter each view (K×K, 3 or 5) before detection: removes "
                             "the fireflies of lights seen through scattering water (lit "
                             "targets) that pull the centroids; default: no filter")
    parser.add_argument("--max-area-ratio", type=_ABOVE_ONE, default=None, metavar="A",
                        help="detected blobs larger than A times the median blob are taken for "
                             "merged targets (default 2.5); raise it (e.g. 6) when the targets "
                             "span a wide range of depths (near ones image larger)")
    parser.add_argument("--sensor", metavar="PRESET[,name=value…]",
                        help="pass the rendered images through a camera sensor (exposure, shot "
                             "and read noise, dark level, gain, bit depth), seeded: preset "
                             "imx174; overrides full_well_e, read_noise_e, bit_depth, "
                             "dark_level_dn, exposure")
    parser.add_argument("--json", action="store_true", help="also print report.json to stdout")
    parser.add_argument("--no-progress", action="store_true", help="no progress output")


def _parse_methods(text: str):
    from measure import METHODS

    methods = tuple(dict.fromkeys(m.strip() for m in text.split(",") if m.strip()))
    unknown = [m for m in methods if m not in METHODS]
    if not methods or unknown:
        raise CLIError(f"unknown method {', '.join(unknown) or repr(text)} in --methods "
                       f"(choose from {', '.join(METHODS)})")
    return methods


def _parse_self_calibration(text: str) -> tuple:
    from measure.selfcal import PARAMETERS

    names = tuple(dict.fromkeys(n.strip() for n in (text or "").split(",") if n.strip()))
    unknown = [n for n in names if n not in PARAMETERS]
    if unknown:
        raise CLIError(f"--self-calibrate {text!r}: unknown parameter {', '.join(unknown)} "
                       f"(the refinement estimates {', '.join(PARAMETERS)})")
    return names


def _fraction(text: str) -> float:
    """argparse type: a number strictly between 0 and 1."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1 (exclusive), got {text}")
    return value






def _budget_rigs(args, inputs) -> dict:
    """``{label: rig}`` of the error budget: the exact calibration (when the measurement's rig
    differs from the truth) and every ``--compare-calib`` file."""
    from synth.dataset import read_calib

    from .assumption import rig_difference

    rigs = {}
    if args.compare_calib or rig_difference(inputs.true_rig, inputs.rig):
        rigs["exact calibration"] = inputs.true_rig
    for path in args.compare_calib:
        calib = read_calib(path)
        if tuple(calib["size"]) != tuple(inputs.true_rig.left.size):
            raise CLIError(f"--compare-calib {path}: image size {calib['size'][0]}x"
                           f"{calib['size'][1]} px, but the scene renders "
                           f"{inputs.true_rig.left.size[0]}x{inputs.true_rig.left.size[1]} px")
        rigs[path] = calib["rig"]
    return rigs


def budget_table(report: dict) -> str:
    """The error budget as fixed-width text: one row per calibration, the first method."""
    budget = report.get("budget") or {}
    method = next(iter(report["methods"]))
    rows = [(label, b) for label, b in budget.items()]
    rows.append((f"this run ({report['rigs'].get('source', 'as measured')})",
                 {"matching": report["matching"], "methods": report["methods"]}))
    lines = [f"error budget ({method}): {'calibration':<44}{'pairs':>7}{'wrong':>7}"
             f"{'RMS dP':>10}{'mean dZ':>10}{'max dP':>10}"]
    for label, b in rows:
        st = b["methods"].get(method, {})
        lines.append(f"{'':<{len('error budget (' + method + '): ')}}{label[:43]:<44}"
                     f"{b['matching']['pairs']:>7}{b['matching']['wrong']:>7}"
                     f"{_fmt(st.get('rms_dp_mm')):>10}{_fmt(st.get('mean_dz_mm')):>10}"
                     f"{_fmt(st.get('max_dp_mm')):>10}")
    return "\n".join(lines)


def load_inputs(args, log):
    """The scene (rig and truth) and its two images, rendered now or read from ``--from``."""
    from .run_options import load_run_scene, read_run_dataset
    from .run_pipeline import RunInputs, visible_targets

    spec = load_run_scene(args)
    seed = spec.seed if args.seed is None else args.seed
    measured_rig = _measurement_rig(args, spec)
    in_left = visible_targets(spec.rig.left, spec.rig.port, spec.targets, spec.target_radius)[1]
    in_right = visible_targets(spec.rig.right, spec.rig.port, spec.targets, spec.target_radius)[1]
    if not (in_left & in_right).any():
        raise CLIError(f"{args.scene}: no target is visible in both views")
    if args.from_dir:
        data = read_run_dataset(args, spec)
        log(f"reusing the images of {args.from_dir}")
        return RunInputs(args.scene, measured_rig, spec.has_port, spec.targets, spec.target_ids,
                         spec.target_radius, data.left, data.right, spec.params,
                         data.manifest.get("variant", "?"), int(data.manifest.get("spp", 0)), 0.0,
                         seed, {"from": os.path.abspath(args.from_dir),
                                "from_seed": data.manifest.get("seed")}, spec.target_normals,
                         spec.rig)
    from synth.render import render_stereo

    log(f"render both views ({spec.size[0]}x{spec.size[1]} px, {args.spp or spec.spp} spp, in "
        f"passes) …")
    start = time.perf_counter()
    left, right, info = render_stereo(spec, spp=args.spp, variant=args.variant,
                                      progress=not args.no_progress)
    timings = {"render_left": info["seconds"]["left"], "render_right": info["seconds"]["right"],
               "render_samples_per_second": info["samples_per_second"],
               **{f"render_samples_per_second_{view}": speed
                  for view, speed in info["samples_per_second_per_view"].items()}}
    render = {k: v for k, v in info.items()
              if k not in ("seconds", "samples_per_second", "samples_per_second_per_view")}
    log("rendered: " + ", ".join(f"{view} {info['seconds'][view]:.1f} s at {speed / 1e6:.2f} M "
                                 f"samples/s ({'+'.join(map(str, info['passes'][view]))} spp)"
                                 for view, speed in info["samples_per_second_per_view"].items()))
    return RunInputs(args.scene, measured_rig, spec.has_port, spec.targets, spec.target_ids,
                     spec.target_radius, left, right, spec.params, info["variant"], info["spp"],
                     time.perf_counter() - start, seed, {"render": render, "timings": timings},
                     spec.target_normals, spec.rig)



SUMMARY_COLUMNS = (("n", "n", 0), ("rms_dp_mm", "RMS dP", 3), ("max_dp_mm", "max dP", 3),
                   ("mean_dx_mm", "mean dX", 3), ("mean_dy_mm", "mean dY", 3),
                   ("mean_dz_mm", "mean dZ", 3), ("chamfer_mm", "Chamfer", 3),
                   ("fscore_1mm", "F@1mm", 3), ("fscore_5mm", "F@5mm", 3),
                   ("rms_dp_aligned_mm", "RMS dP aligned", 3), ("flatness_mm", "flatness", 3))


def summary_table(report: dict) -> str:
    """The per-method table (mm) as fixed-width text."""
    header = f"{'method':<17}" + "".join(f"{title:>15}" for _, title, _ in SUMMARY_COLUMNS)
    lines = [header]
    for method, stats in _method_rows(report):
        lines.append(f"{method:<17}" + "".join(f"{_fmt(stats.get(key), digits):>15}"
                                                for key, _, digits in SUMMARY_COLUMNS))
    return "\n".join(lines)


def _method_rows(report: dict):
    """``(label, stats)`` per method, then per method corrected for eccentricity (``+ecc``)."""
    rows = list(report["methods"].items())
    if report.get("eccentricity"):
        rows += [(f"{m}+ecc", st) for m, st in report["eccentricity"]["methods"].items()]
    return rows


def _sensor_lines(sensor) -> list:
    """report.md's paragraph on the ``--sensor`` (none without one)."""
    if not sensor:
        return []
    m = sensor["model"]
    return [f"Sensor `{m['name']}`: full well {m['full_well_e']:g} e⁻, read noise "
            f"{m['read_noise_e']:g} e⁻, {m['bit_depth']} bit, dark level {m['dark_level_dn']:g} DN, "
            f"gain {m['gain_e_per_dn']:.4g} e⁻/DN, brightest pixel exposed to "
            f"{m['exposure']:g} of the full well; saturated pixels left "
            f"{sensor['left']['saturated_pixels']}, right {sensor['right']['saturated_pixels']}.",
            ""]


def report_markdown(report: dict) -> str:
    m, c, t = report["matching"], report["crosscheck"], report["timings_s"]
    lines = [f"# Run report: `{report['scene']}`", "",
             f"{report['targets']} targets; Mitsuba variant `{report['variant']}`, {report['spp']} spp; "
             f"added pixel noise σ = {report['noise_px']} px.", "",
             *_sensor_lines(report.get("sensor")),
             "## Detection and matching", "",
             "| | left | right |", "|---|---|---|",
             f"| targets wholly in the image | {report['visibility']['in_both'] + report['visibility']['left_only']} "
             f"| {report['visibility']['in_both'] + report['visibility']['right_only']} |",
             f"| detections accepted | {report['detection']['left']['found']} | {report['detection']['right']['found']} |",
             f"| blobs rejected | {report['detection']['left']['rejected_by_reason']} | {report['detection']['right']['rejected_by_reason']} |",
             f"| cross-check RMS / max (px) | {_fmt(c['left']['rms_px'], 4)} / {_fmt(c['left']['max_px'], 4)} "
             f"| {_fmt(c['right']['rms_px'], 4)} / {_fmt(c['right']['max_px'], 4)} |", "",
             f"Targets visible in both views: {m['visible_in_both']}; matched pairs: {m['pairs']} "
             f"({m['correct']} correct, {m['wrong']} wrong, {m['ambiguous_dropped']} ambiguous dropped); "
             f"visible-in-both targets matched: {m['visible_in_both_matched']}. Gate {m['gate_mm']} mm, "
             f"depth window {m['depth_window_mm']} mm. Cross-check of all detections against the "
             f"Fermat simulator: RMS {_fmt(c['rms_px'], 4)} px, max {_fmt(c['max_px'], 4)} px "
             f"(against the image of each target's centre); RMS {_fmt(c['rms_px_outline'], 4)} px, "
             f"max {_fmt(c['max_px_outline'], 4)} px against the area centroid of the image of its "
             f"outline (the eccentricity removed).", "",
             "## Truth and assumption", "",
             ("The measurement used the rendered rig (no assumption differs from the truth)."
              if not report.get("rigs", {}).get("difference") else
              "The measurement believed a rig that differs from the rendered truth (assumed − "
              "true): " + "; ".join(f"`{k}` {v}" for k, v in report["rigs"]["difference"].items())
              + ". Matching, triangulation and the eccentricity correction use the assumed rig; "
                "the cross-check uses the true one."), "",
             "## Accuracy per method (mm)", "",
             "| method | " + " | ".join(title for _, title, _ in SUMMARY_COLUMNS) + " |",
             "|---" * (len(SUMMARY_COLUMNS) + 1) + "|"]
    for method, stats in _method_rows(report):
        lines.append(f"| {method} | " + " | ".join(_fmt(stats.get(k), d) for k, _, d in SUMMARY_COLUMNS) + " |")
    lines += ["", "dP = |measured − true| over correctly matched targets; Chamfer = mean "
              "measured→truth + mean truth→measured nearest-neighbour distance (all matched points "
              "against the targets visible in both views); F@τ = harmonic mean of precision and "
              "recall at τ; aligned = after the best rigid transform with known correspondences; "
              "flatness = RMS distance to the RANSAC plane.", "",
              *(["## Error budget", "", "The same detections measured with each calibration "
                 "(matching, triangulation and scoring repeated):", "", "```",
                 budget_table(report), "```", ""] if report.get("budget") else []),
              "## Files", "",
              "- `views.png`, `error_maps.png`, `histograms.png`",
              *[f"- `{p['file']}`: colour = dP on `{p['colormap']}` from {p['vmin_mm']} mm to "
                f"{_fmt(p['vmax_mm'])} mm (clipped)" for p in report.get("ply", {}).values()], "",
              "## Timings (s)", "",
              " · ".join(f"{k} {v:.2f}" for k, v in t.items())]
    return "\n".join(lines) + "\n"


def write_error_ply(directory: str, name: str, points, errors) -> dict:
    """``points`` ``(N, 3)`` coloured by their dP (norm of ``errors`` ``(N, 3)``, mm) on
    :data:`PLY_COLORMAP` from 0 to the largest, as ``directory/name``; returns the report entry."""
    import numpy as np

    from .cloud_metrics import write_colored_ply

    dp = np.linalg.norm(errors, axis=1)
    vmax = float(dp.max()) if dp.size else 1.0
    write_colored_ply(os.path.join(directory, name), points, dp, vmax, PLY_COLORMAP)
    return {"file": name, "colormap": PLY_COLORMAP, "vmin_mm": 0.0, "vmax_mm": vmax,
            "points": int(dp.size)}


def write_outputs(tmp: str, inputs, report: dict, arrays: dict) -> None:
    """The PLY files (their entries go into ``report["ply"]``) and figures of a run, into
    directory ``tmp``."""
    from . import run_figures

    report["ply"] = {method: write_error_ply(tmp, f"points_{method}.ply", data["points"],
                                             data["errors"])
                     for method, data in arrays["per_method"].items()}
    run_figures.views_figure(os.path.join(tmp, "views.png"), inputs.left, inputs.right, arrays)
    run_figures.error_maps_figure(os.path.join(tmp, "error_maps.png"), arrays["per_method"])
    run_figures.histograms_figure(os.path.join(tmp, "histograms.png"), arrays["per_method"])


@dataclass(frozen=True)
class RunOptions:
    """The checked options of a run (:func:`check_options`)."""

    methods: tuple
    depth_window: tuple | None
    self_calibration: tuple
    sensor: object


def check_options(args) -> RunOptions:
    """Parse and check the options of ``args`` that need more than argparse (CLIError names
    the bad one) — before any expensive work."""
    return RunOptions(_parse_methods(args.methods), _parse_range(args.depth_range),
                      _parse_self_calibration(args.self_calibrate), _parse_sensor(args.sensor))


def measure(args, options: RunOptions, log):
    """Everything of ``eval run`` but the output: load or render the images, expose them on the
    sensor, detect, match, triangulate, score. Returns ``(report, arrays, inputs)``; the report
    lacks ``versions``, ``inputs``, ``ply`` and the ``report`` / ``total`` timings. ``eval
    sweep`` runs its render cells through this function, in its workers."""
    inputs = load_inputs(args, log)
    sensor_info = None
    if options.sensor is not None:
        from synth.sensor_model import sensor_views, to_radiance

        log(f"expose both views on the {options.sensor.name} sensor …")
        left, right, sensor_info = sensor_views(inputs.left, inputs.right, options.sensor,
                                                inputs.seed)
        inputs.left, inputs.right = (to_radiance(codes, options.sensor,
                                                 sensor_info["electrons_per_unit"])
                                     for codes in (left, right))

    from .run_pipeline import run_pipeline

    report, arrays = run_pipeline(inputs, options.methods, args.noise_px, args.gate_mm,
                                  options.depth_window, log, eccentricity=args.eccentricity,
                                  self_calibrate=options.self_calibration,
                                  budget_rigs=_budget_rigs(args, inputs),
                                  threshold_fraction=args.threshold_fraction,
                                  max_elongation=args.max_elongation,
                                  max_area_ratio=args.max_area_ratio,
                                  median_filter=args.median_filter)
    report["sensor"] = sensor_info
    report["rigs"]["source"] = (f"--calib {args.calib}" if args.calib else "the scene's rig") + (
        " with --assume" if args.assume else "")
    return report, arrays, inputs


def main(args) -> int:
    from synth.fileio import OutputDir, atomic_write_json, atomic_write_text, jsonable
    from synth.provenance import package_versions

    quiet = args.no_progress
    log = (lambda text: None) if quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    from .dense_run import is_surface_scene

    if is_surface_scene(args.scene):
        from . import dense_run

        return dense_run.main(args, log)
    options = check_options(args)
    output = OutputDir(args.out, COMMAND).claim()  # before any expensive work
    start = time.perf_counter()
    report, arrays, inputs = measure(args, options, log)
    log("write the report, figures and point clouds …")
    t = time.perf_counter()
    with output.staged() as tmp:
        report["versions"] = package_versions()
        report["inputs"] = inputs.extra
        write_outputs(tmp, inputs, report, arrays)
        report["timings_s"]["report"] = time.perf_counter() - t
        report["timings_s"]["total"] = time.perf_counter() - start
        report = jsonable(report)
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        atomic_write_text(os.path.join(tmp, "report.md"), report_markdown(report))
    out = output.path
    summary_stream = sys.stderr if args.json else sys.stdout
    m, c = report["matching"], report["crosscheck"]
    print(f"{report['scene']}: {m['visible_in_both']} targets visible in both views, "
          f"{m['pairs']} matched ({m['correct']} correct, {m['wrong']} wrong), cross-check RMS "
          f"{_fmt(c['rms_px'], 4)} px, max {_fmt(c['max_px'], 4)} px (outline centroid: RMS "
          f"{_fmt(c['rms_px_outline'], 4)} px, max {_fmt(c['max_px_outline'], 4)} px); "
          f"{report['variant']} {report['spp']} spp"
          f"{'; sensor ' + report['sensor']['model']['name'] if report.get('sensor') else ''}; "
          f"total {report['timings_s']['total']:.1f} s",
          file=summary_stream)
    print(summary_table(report), file=summary_stream)
    print(f"wrote {out}", file=summary_stream)
    if report.get("budget"):
        print(budget_table(report), file=summary_stream)
    calibration = report.get("self_calibration")
    if calibration:
        if calibration.get("methods"):
            for name, value in calibration["estimates"].items():
                sigma = calibration["sigmas"][name]
                print(f"self-calibrated {name}: {value} ± {sigma} (truth {calibration['truth'][name]}, "
                      f"assumed {calibration['assumed'][name]}); reprojection RMS "
                      f"{calibration['rms_px_before']:.4f} -> {calibration['rms_px_after']:.4f} px",
                      file=summary_stream)
            print(summary_table({"methods": calibration["methods"]}), file=summary_stream)
        else:
            print(f"self-calibration: no trusted estimate ({calibration['reason'] or calibration['message']})",
                  file=summary_stream)
    if args.json:
        print(json.dumps(report, indent=2))
    return 0
