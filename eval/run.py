"""``python -m eval run SCENE``: render, detect, match, triangulate and score — end to end.

Writes ``DIR/report.json``, ``DIR/report.md``, the figures (``views.png``, ``error_maps.png``,
``histograms.png``) and one PLY per method (``points_<method>.ply``, coloured by dP). The output
directory appears whole or not at all. See the README for the report's fields.
"""

from __future__ import annotations

import json
import os
import sys
import time

from eval.cli import CLIError, positive_int, prepare_output_dir

DEFAULT_METHODS = ("optical_path", "su", "regular")
PLY_COLORMAP = "viridis"


def add_parser(subparsers):
    parser = subparsers.add_parser(
        "run", help="render a scene, measure it and score the point clouds",
        description="Render SCENE (or reuse --from DIR), detect and match the targets without "
                    "ground truth, triangulate with each method and score against the truth.")
    parser.add_argument("scene", help="Mitsuba scene file (e.g. scenes/paper_plane.xml)")
    parser.add_argument("--out", default="out/run", help="output directory (default out/run)")
    parser.add_argument("--from", dest="from_dir", metavar="DIR",
                        help="reuse the images of a dataset written by python -m synth dataset")
    parser.add_argument("--spp", type=positive_int, help="samples per pixel (default: the scene's)")
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")
    parser.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                        help="comma-separated triangulation methods (default: all three)")
    parser.add_argument("--noise-px", type=float, default=0.0,
                        help="Gaussian noise σ (px) added to the detected centres (default 0)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the added noise and RANSAC")
    parser.add_argument("--gate-mm", type=float, default=0.5,
                        help="largest common-perpendicular length of a matched pair (mm, default 0.5)")
    parser.add_argument("--depth-range", metavar="NEAR,FAR",
                        help="working range along the port normal (mm); default: the scene's "
                             "target_z × (0.8, 1.25)")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="name=value",
                        help="override a scene default (repeatable)")
    parser.add_argument("--json", action="store_true", help="also print report.json to stdout")
    parser.add_argument("--no-progress", action="store_true", help="no progress output")


def _parse_methods(text: str):
    from measure import METHODS

    methods = tuple(m.strip() for m in text.split(",") if m.strip())
    unknown = [m for m in methods if m not in METHODS]
    if not methods or unknown:
        raise CLIError(f"unknown method {', '.join(unknown) or repr(text)} in --methods "
                       f"(choose from {', '.join(METHODS)})")
    return methods


def _parse_range(text):
    if text is None:
        return None
    try:
        near, far = (float(v) for v in text.split(","))
    except ValueError:
        raise CLIError(f"--depth-range must be NEAR,FAR in mm, got {text!r}") from None
    if not 0 <= near < far:
        raise CLIError(f"--depth-range must satisfy 0 <= NEAR < FAR, got {text!r}")
    return near, far


def load_inputs(args, log):
    """The scene (rig and truth) and its two images, rendered now or read from ``--from``."""
    from synth.dataset import DatasetError, read_dataset
    from synth.scene import SceneError, load_scene, parse_defines

    from .run_pipeline import RunInputs, visible_targets

    try:
        spec = load_scene(args.scene, parse_defines(args.defines))
    except SceneError as exc:
        raise CLIError(str(exc)) from None
    in_left = visible_targets(spec.rig.left, spec.rig.port, spec.targets, spec.target_radius)[1]
    in_right = visible_targets(spec.rig.right, spec.rig.port, spec.targets, spec.target_radius)[1]
    if not (in_left & in_right).any():
        raise CLIError(f"{args.scene}: no target is visible in both views")
    if args.from_dir:
        try:
            data = read_dataset(args.from_dir)
        except (DatasetError, OSError, KeyError) as exc:
            raise CLIError(f"--from {args.from_dir}: {exc}") from None
        if data.manifest.get("scene", {}).get("sha256") != spec.sha256:
            raise CLIError(f"--from {args.from_dir}: the dataset was rendered from another scene "
                           f"than {args.scene}")
        log(f"reusing the images of {args.from_dir}")
        return RunInputs(args.scene, spec.rig, spec.has_port, spec.targets, spec.target_ids,
                         spec.target_radius, data.left, data.right, spec.params,
                         data.manifest.get("variant", "?"), int(data.manifest.get("spp", 0)), 0.0,
                         {"from": os.path.abspath(args.from_dir)})
    from synth.render import render_stereo

    log("render both views …")
    start = time.perf_counter()
    try:
        left, right, info = render_stereo(spec, spp=args.spp, variant=args.variant,
                                          progress=not args.no_progress)
    except (SceneError, ValueError) as exc:
        raise CLIError(str(exc)) from None
    return RunInputs(args.scene, spec.rig, spec.has_port, spec.targets, spec.target_ids,
                     spec.target_radius, left, right, spec.params, info["variant"], info["spp"],
                     time.perf_counter() - start, {"render": info})


def _fmt(value, digits=3):
    if value is None or (isinstance(value, float) and value != value):
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


SUMMARY_COLUMNS = (("n", "n", 0), ("rms_dp_mm", "RMS dP", 3), ("max_dp_mm", "max dP", 3),
                   ("mean_dx_mm", "mean dX", 3), ("mean_dy_mm", "mean dY", 3),
                   ("mean_dz_mm", "mean dZ", 3), ("chamfer_mm", "Chamfer", 3),
                   ("fscore_1mm", "F@1mm", 3), ("fscore_5mm", "F@5mm", 3),
                   ("rms_dp_aligned_mm", "RMS dP aligned", 3), ("flatness_mm", "flatness", 3))


def summary_table(report: dict) -> str:
    """The per-method table (mm) as fixed-width text."""
    header = f"{'method':<13}" + "".join(f"{title:>15}" for _, title, _ in SUMMARY_COLUMNS)
    lines = [header]
    for method, stats in report["methods"].items():
        lines.append(f"{method:<13}" + "".join(f"{_fmt(stats.get(key), digits):>15}"
                                                for key, _, digits in SUMMARY_COLUMNS))
    return "\n".join(lines)


def report_markdown(report: dict) -> str:
    m, c, t = report["matching"], report["crosscheck"], report["timings_s"]
    lines = [f"# Run report: `{report['scene']}`", "",
             f"{report['targets']} targets; Mitsuba variant `{report['variant']}`, {report['spp']} spp; "
             f"added pixel noise σ = {report['noise_px']} px.", "",
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
             f"Fermat simulator: RMS {_fmt(c['rms_px'], 4)} px, max {_fmt(c['max_px'], 4)} px.", "",
             "## Accuracy per method (mm)", "",
             "| method | " + " | ".join(title for _, title, _ in SUMMARY_COLUMNS) + " |",
             "|---" * (len(SUMMARY_COLUMNS) + 1) + "|"]
    for method, stats in report["methods"].items():
        lines.append(f"| {method} | " + " | ".join(_fmt(stats.get(k), d) for k, _, d in SUMMARY_COLUMNS) + " |")
    lines += ["", "dP = |measured − true| over correctly matched targets; Chamfer = mean "
              "measured→truth + mean truth→measured nearest-neighbour distance (all matched points "
              "against the targets visible in both views); F@τ = harmonic mean of precision and "
              "recall at τ; aligned = after the best rigid transform with known correspondences; "
              "flatness = RMS distance to the RANSAC plane.", "",
              "## Files", "",
              "- `views.png`, `error_maps.png`, `histograms.png`",
              *[f"- `{p['file']}`: colour = dP on `{p['colormap']}` from {p['vmin_mm']} mm to "
                f"{_fmt(p['vmax_mm'])} mm (clipped)" for p in report.get("ply", {}).values()], "",
              "## Timings (s)", "",
              " · ".join(f"{k} {v:.2f}" for k, v in t.items())]
    return "\n".join(lines) + "\n"


def main(args) -> int:
    from .paper_report import jsonable

    quiet = args.no_progress
    log = (lambda text: None) if quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    methods = _parse_methods(args.methods)
    depth_window = _parse_range(args.depth_range)
    if not args.gate_mm > 0:
        raise CLIError(f"--gate-mm must be positive, got {args.gate_mm}")
    if args.noise_px < 0:
        raise CLIError(f"--noise-px must be >= 0, got {args.noise_px}")
    out = os.path.abspath(args.out)
    prepare_output_dir(os.path.dirname(out))
    start = time.perf_counter()
    inputs = load_inputs(args, log)

    import numpy as np

    from synth.dataset import package_versions
    from synth.fileio import staged_dir

    from . import run_figures
    from .cloud_metrics import write_colored_ply
    from .run_pipeline import run_pipeline

    report, arrays = run_pipeline(inputs, methods, args.noise_px, args.seed, args.gate_mm,
                                  depth_window, log)
    if report["matching"]["pairs"] == 0:
        raise CLIError(f"{args.scene}: no target was matched between the views "
                       f"(detected {report['detection']['left']['found']} left, "
                       f"{report['detection']['right']['found']} right)")
    log("write the report, figures and point clouds …")
    t = time.perf_counter()
    try:
        with staged_dir(out) as tmp:
            report["ply"] = {}
            for method, data in arrays["per_method"].items():
                dp = np.linalg.norm(data["errors"], axis=1)
                vmax = float(dp.max()) if dp.size else 1.0
                name = f"points_{method}.ply"
                write_colored_ply(os.path.join(tmp, name), data["points"], dp, vmax, PLY_COLORMAP)
                report["ply"][method] = {"file": name, "colormap": PLY_COLORMAP, "vmin_mm": 0.0,
                                         "vmax_mm": vmax, "points": int(dp.size)}
            run_figures.views_figure(os.path.join(tmp, "views.png"), inputs.left, inputs.right, arrays)
            run_figures.error_maps_figure(os.path.join(tmp, "error_maps.png"), arrays["per_method"])
            run_figures.histograms_figure(os.path.join(tmp, "histograms.png"), arrays["per_method"])
            report["timings_s"]["report"] = time.perf_counter() - t
            report["timings_s"]["total"] = time.perf_counter() - start
            report["versions"] = package_versions()
            report["inputs"] = jsonable(inputs.extra)
            report = jsonable(report)
            with open(os.path.join(tmp, "report.json"), "w") as handle:
                json.dump(report, handle, indent=2)
                handle.write("\n")
            with open(os.path.join(tmp, "report.md"), "w") as handle:
                handle.write(report_markdown(report))
    except OSError as exc:
        raise CLIError(f"cannot write to --out {args.out!r}: {exc.strerror or exc}") from None
    summary_stream = sys.stderr if args.json else sys.stdout
    m, c = report["matching"], report["crosscheck"]
    print(f"{report['scene']}: {m['visible_in_both']} targets visible in both views, "
          f"{m['pairs']} matched ({m['correct']} correct, {m['wrong']} wrong), cross-check RMS "
          f"{_fmt(c['rms_px'], 4)} px, max {_fmt(c['max_px'], 4)} px; "
          f"{report['variant']} {report['spp']} spp; total {report['timings_s']['total']:.1f} s",
          file=summary_stream)
    print(summary_table(report), file=summary_stream)
    print(f"wrote {out}", file=summary_stream)
    if args.json:
        print(json.dumps(report, indent=2))
    return 0
