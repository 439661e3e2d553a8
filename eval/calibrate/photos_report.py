"""The report of a pair's own photos (``report.md``) and the lines ``eval calibrate`` prints,
from the report dict :mod:`eval.calibrate.pair_photos` builds (:mod:`eval.calibrate.photos`: what
can be trusted without truth). Lengths mm, angles degrees, pixels px."""

from __future__ import annotations

import os

import numpy as np

from eval.calibrate.photos import COVERAGE_CELLS, LENS_RULE, STEREO_RULE, VIEWS, verdict_lines
from eval.calibrate.report import format_value as _f


def _range(pair, digits) -> str:
    """``low–high`` of a ``(low, high)`` pair, or – when unknown."""
    return "–" if pair is None or None in pair else "–".join(_f(float(v), digits) for v in pair)


def markdown(report: dict) -> str:
    """``report.md``: the photos and board, the verdict, the poses, the in-air calibration,
    the worst corners, the housing, the files and the timings."""
    b = report["board"]
    lines = [f"# Calibration report: `{report['photos']}`", "",
             f"{report['poses']} photo pairs ({report['image_size'][0]}x{report['image_size'][1]}"
             f" px) of a {b['kind']} {b['squares'][0]}x{b['squares'][1]}, {b['square_mm']:g} mm "
             f"squares, {'in air' if report['air'] else 'underwater, behind the port'}; board "
             f"found in {report['found']['left']} left and {report['found']['right']} right "
             f"photos; {report['used']} pose(s) in the final fit. No truth: every number below "
             f"comes from the photos.", ""]
    lines += verdict_lines(report)
    lines += _poses_lines(report)
    if "in_air" in report:
        lines += _in_air_lines(report["in_air"])
    if report.get("worst_corners"):
        lines += ["", "## Worst corners", "", "Farthest from the fit (`residuals.png` draws "
                  "every residual):", "", "| pose | view | corner id | residual (px) |",
                  "|---|---|---|---|"]
        lines += [f"| {c['pose']} | {c['view']} | {c['id']} | {c['residual_px']:.3f} |"
                  for c in report["worst_corners"]]
    if "housing" in report:
        lines += _housing_lines(report["housing"], report["sigma_note"])
    lines += ["", "## Files", "", "- `calib.yaml`: the calibration in the dataset format"
              + (" (with an `uncertainty` map), `calib_in_air_only.yaml` (the in-air calibration "
                 "with the design port), `flatport.txt` (FLATPORT per camera)"
                 if "housing" in report else ""),
              "- `coverage.png`, `residuals.png` (residual vectors per pose and view)",
              "", "## Timings (s)", "",
              " · ".join(f"{k} {v:.2f}" for k, v in report["timings_s"].items())]
    return "\n".join(lines) + "\n"


def _poses_lines(report: dict) -> list:
    """The report's poses table (each pose's corners, RMS, distance, tilt, its own stereo pose
    in air, and status), the outlier and stereo rules, the boards' distances and coverage."""
    stereo = "in_air" in report
    lines = ["## Poses", "", f"Outlier rule: {report['outlier_rule']} (threshold here "
             f"{report['outliers']['threshold_px']:.3f} px)."
             + (f" Stereo rule: {STEREO_RULE}." if stereo else ""), "",
             "| pose | corners L | corners R | RMS L (px) | RMS R (px) | distance (mm) | "
             "tilt (°) |" + (" own baseline (mm) | from the median (mm, °) |" if stereo else "")
             + " status |", "|---|---|---|---|---|---|---|" + ("---|---|" if stereo else "")
             + "---|"]
    for p in report["per_pose"]:
        own = ""
        if stereo:
            s = p.get("stereo")
            own = (f" {s['baseline_mm']:.2f} | {s['deviation_mm']:.2f}, "
                   f"{s['deviation_deg']:.3f} |" if s else " – | – |")
        lines.append(f"| {p['name']} | {p['corners']['left']} | {p['corners']['right']} | "
                     f"{_f(p['rms_px']['left'])} | {_f(p['rms_px']['right'])} | "
                     f"{_f(p['distance_mm'], 5)} | {_f(p['tilt_deg'], 3)} |{own} {p['status']} |")
    g, c = report["geometry"], report["coverage"]
    lines += ["", f"Board distances {_f(g['distance_mm'], 5)} mm, tilts {_f(g['tilt_deg'], 3)}° "
              f"(poses in the final fit). Corners cover {100 * c['left']['fraction']:.0f} % of "
              f"the left and {100 * c['right']['fraction']:.0f} % of the right image "
              f"({COVERAGE_CELLS}×{COVERAGE_CELLS} cells; `coverage.png`)."]
    return lines


def _in_air_lines(a: dict) -> list:
    """The in-air calibration's section: RMS, lens models, each camera's parameters with σ,
    the baseline."""
    models = "; ".join(
        f"{cam} {m['model']} (" + ", ".join(f"{k} {v:.4f} px" for k, v in m["rms_px"].items())
        + ")" for cam, m in a["lens_models"].items())
    lines = ["", "## In-air calibration (OpenCV)", "",
             f"Reprojection RMS: left {a['rms_px']['left']:.4f} px, right "
             f"{a['rms_px']['right']:.4f} px, stereo {a['stereo_rms_px']:.4f} px. σ: "
             f"OpenCV's `calibrateCameraExtended` standard deviations.", "",
             f"Lens models (RMS of each model fitted; {LENS_RULE}): {models}."
             + ("" if a["covariance"] else " The joint covariance of the intrinsics and "
                "the stereo pose is written for the standard model only: calib.yaml has "
                "none, and a housing calibrated from it has σ conditional on these "
                "intrinsics."), "",
             "| parameter | left | σ | right | σ |", "|---|---|---|---|---|"]
    keys = dict.fromkeys([*a["cameras"]["left"], *a["cameras"]["right"]])
    for key in keys:
        cells = [(f"{v[key]['estimate']:.6g}", _f(v[key]["sigma"], 3)) if key in v
                 else ("–", "–") for v in (a["cameras"]["left"], a["cameras"]["right"])]
        lines.append(f"| {key} | {cells[0][0]} | {cells[0][1]} | {cells[1][0]} | "
                     f"{cells[1][1]} |")
    s = a["stereo"]
    lines += ["", f"Baseline {s['baseline_mm']:.4f} mm; σ {_f(s['baseline_sigma_mm'], 3)} mm "
              f"(the per-pose baselines' scatter {_f(s['baseline_std_over_poses_mm'], 3)} mm "
              f"over √{s['baseline_poses']}: OpenCV's stereoCalibrate gives no σ); right "
              f"camera rotated {s['right_rotation_deg']:.4f}° from the left."]
    return lines


def _housing_lines(h: dict, sigma_note: str) -> list:
    """The housing calibration's section: the fit, each free number with σ, correlations."""
    lines = ["", "## Housing calibration (refractive bundle adjustment)", "",
             f"Free: {', '.join(h['free'])}; {h['observations']} corner observations; "
             f"reprojection RMS {h['rms_px_start']:.3f} px at the start, {h['rms_px']:.4f} "
             f"px after ({h['evaluations']} evaluations). Start (design port): distance "
             f"{_f(h['start']['distance'])} mm, glass {_f(h['start']['thickness'])} mm, "
             f"indices {_f(h['start']['indices'])}.", "", sigma_note, "",
             "| parameter | estimate | σ |", "|---|---|---|"]
    for name, p in h["parameters"].items():
        if name.endswith("normal"):
            camera = "right" if "tilt_from_right_axis_deg" in p else "left"
            lines.append(f"| {name.replace('_', ' ')} | {_f(p['estimate'], 7)} "
                         f"({p[f'tilt_from_{camera}_axis_deg']:.4f}° from the {camera} "
                         f"optical axis) | {_f(p['sigma_deg'], 3)}° (two tilts) |")
        elif name == "extrinsics":
            lines.append(f"| right camera position | {_f(p['t'], 6)} mm | "
                         f"{_f(p['sigma_position_mm'], 3)} mm; rotation "
                         f"{_f(p['sigma_rotation_deg'], 3)}° |")
        else:
            lines.append(f"| {name} | {p['estimate']:.6f} {p['unit']} | {_f(p['sigma'], 3)} |")
    lines += ["", "Correlations of the free numbers (" + ", ".join(h["labels"]) + "):", ""]
    lines += ["    " + " ".join(f"{v:+.3f}" for v in row) for row in h["correlation"]]
    return lines


def summary_lines(report: dict) -> str:
    """The lines ``eval calibrate`` prints of a pair's photos."""
    lines = [f"{report['photos']}: board found in {report['found']['left']}/{report['poses']} "
             f"left and {report['found']['right']}/{report['poses']} right photos; "
             f"{report['used']} pose(s) used"
             + (f", not found in {', '.join(report['not_found'])}" if report["not_found"] else "")
             + (f", left out as outliers: {', '.join(report['left_out'])}"
                if report["left_out"] else "")]
    b = report["board"]
    lines.append(f"board: {b['kind']} of {b['squares'][0]}x{b['squares'][1]} squares "
                 f"({b['squares'][0] - 1}x{b['squares'][1] - 1} inner corners, OpenCV's pattern "
                 f"size), {b['square_mm']:g} mm")
    if "in_air" in report:
        a = report["in_air"]
        lines.append("lens model: " + ", ".join(f"{cam} {m['model']}" for cam, m in
                                                a["lens_models"].items())
                     + " (--lens; the report lists the RMS of each model tried)")
        for cam, v in a["cameras"].items():
            lines.append(f"in air {cam}: fx {v['fx']['estimate']:.3f} ± {_f(v['fx']['sigma'], 2)}, "
                         f"fy {v['fy']['estimate']:.3f} ± {_f(v['fy']['sigma'], 2)}, cx "
                         f"{v['cx']['estimate']:.3f} ± {_f(v['cx']['sigma'], 2)}, cy "
                         f"{v['cy']['estimate']:.3f} ± {_f(v['cy']['sigma'], 2)} px; RMS "
                         f"{a['rms_px'][cam]:.4f} px")
        s = a["stereo"]
        lines.append(f"in air baseline {s['baseline_mm']:.4f} ± {_f(s['baseline_sigma_mm'], 2)} "
                     f"mm, stereo RMS {a['stereo_rms_px']:.4f} px")
    if "housing" in report:
        lines += _housing_summary(report["housing"])
    g, c = report["geometry"], report["coverage"]
    lines.append(f"boards {_range(g['distance_mm'], 4)} mm away, tilted {_range(g['tilt_deg'], 3)}°; "
                 f"corners cover {100 * c['left']['fraction']:.0f} % / "
                 f"{100 * c['right']['fraction']:.0f} % of the images")
    lines += [f"warning: {w}" for w in report["warnings"]]
    return "\n".join(lines)


def _housing_summary(h: dict) -> list:
    """The printed lines of the housing: each free number with σ, the RMS, a conditional σ."""
    lines = []
    for name, p in h["parameters"].items():
        if name.endswith("normal"):
            camera = "right" if "tilt_from_right_axis_deg" in p else "left"
            lines.append(f"housing {name.replace('_', ' ')}: {_f(p['estimate'], 6)}, "
                         f"{p[f'tilt_from_{camera}_axis_deg']:.4f}° from the {camera} "
                         f"optical axis, σ {_f(p['sigma_deg'], 2)}°")
        elif name == "extrinsics":
            lines.append(f"housing right camera: position {_f(p['t'], 6)} mm, σ "
                         f"{_f(p['sigma_position_mm'], 2)} mm")
        else:
            lines.append(f"housing {name}: {p['estimate']:.6f} ± {_f(p['sigma'], 2)} "
                         f"{p['unit']}".rstrip())
    lines.append(f"housing reprojection RMS {h['rms_px']:.4f} px ({h['observations']} "
                 f"corners)")
    if h.get("uncertainty") == "conditional":
        lines.append("note: σ is conditional on the in-air calibration, taken as exact: the "
                     "--intrinsics file carried no covariance (calibmar's YAML and COLMAP's "
                     "cameras.txt hold none; the calib.yaml of eval calibrate --air does)")
    return lines


def coverage_figure(directory, detections_all, used, size, report, views=VIEWS) -> None:
    """``coverage.png``: every detected corner on each camera's image frame (colour = pose;
    poses left out as red crosses), the covered cells shaded (``report["coverage"][view]``
    for each of ``views``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w, h = size
    fig, axes = plt.subplots(1, len(views), figsize=(6 * len(views), 5),
                             constrained_layout=True, squeeze=False)
    cmap = plt.get_cmap("tab20")
    for view, ax in enumerate(axes[0]):
        name = views[view]
        grid = np.asarray(report["coverage"][name]["cells"])
        n = grid.shape[0]
        ax.imshow(grid, extent=(-0.5, w - 0.5, h - 0.5, -0.5), cmap="Greens", vmin=0, vmax=4,
                  alpha=0.6, interpolation="nearest")
        for i in range(1, n):
            ax.axvline(i * w / n - 0.5, color="0.85", lw=0.5)
            ax.axhline(i * h / n - 0.5, color="0.85", lw=0.5)
        for k in range(detections_all.n_poses):
            uv = np.asarray(detections_all.pixels[k][view]).reshape(-1, 2)
            if not len(uv):
                continue
            if k in used:
                ax.plot(uv[:, 0], uv[:, 1], ".", ms=2, color=cmap(k % 20))
            else:
                ax.plot(uv[:, 0], uv[:, 1], "x", ms=3, color="red")
        ax.set_xlim(-0.5, w - 0.5)
        ax.set_ylim(h - 0.5, -0.5)
        ax.set_aspect("equal")
        ax.set_title(f"{name}: corners of {len(used)} poses; {100 * grid.mean():.0f} % of "
                     f"{n}×{n} cells covered (red ×: left out)", fontsize=9)
    fig.savefig(os.path.join(directory, "coverage.png"), dpi=110)
    plt.close(fig)
