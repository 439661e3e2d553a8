"""What ``eval measure`` writes: ``report.json`` / ``report.md`` (counts, gap statistics, a plane
fit — no truth), ``points.csv`` and the PLY point clouds.

Units: millimetres in the left camera's frame (OpenCV axes), pixels in the OpenCV convention.
"""

from __future__ import annotations

import csv
import io
import os

import numpy as np

from eval.core.formatting import format_number as fmt

#: Columns of ``points.csv``: the pair, the method, the point (mm), the gap of the method's two
#: final rays (the water rays, or for ``regular`` the straight rays; mm) and the pixels (px) it
#: was triangulated from.
CSV_COLUMNS = ("pair", "method", "x_mm", "y_mm", "z_mm", "gap_mm", "u_left", "v_left",
               "u_right", "v_right")

#: Said (stderr, report.md) when ``--calib`` is an in-air calibration: the photos are measured
#: as if taken in air, so underwater photos come out at the wrong depth without an error (the
#: paper plane's JPEG pair with the in-air calibration: 162 of 496 targets matched, exit 0).
AIR_CALIBRATION = ("--calib {calib} is an in-air calibration (no port): the photos are measured "
                   "as if taken in air; photos taken through the port need the housing's "
                   "calibration (eval calibrate PHOTOS --intrinsics …)")
ABSORBED_CALIBRATION = ("--calib {calib} is an absorbed calibration (eval calibrate --model "
                        "absorbed: underwater photos fitted as pinhole cameras): the port is "
                        "absorbed, not modelled, and its error grows away from the boards' "
                        "distances (docs/absorbed.md)")


def calibration_note(calib: str, model: str | None) -> str:
    """What a report says of a calibration without a port: absorbed, or in air."""
    return (ABSORBED_CALIBRATION if model == "absorbed" else AIR_CALIBRATION).format(calib=calib)


def gap_stats(gap) -> dict:
    """RMS, median and largest gap (mm) of the valid points; None for each without points."""
    gap = np.asarray(gap, dtype=float)
    gap = gap[np.isfinite(gap)]
    if gap.size == 0:
        return {"rms_mm": None, "median_mm": None, "max_mm": None}
    return {"rms_mm": float(np.sqrt(np.mean(gap ** 2))), "median_mm": float(np.median(gap)),
            "max_mm": float(gap.max())}


def plane_fit(points) -> dict | None:
    """The least-squares plane of ``points`` ``(N, 3)`` mm (every point, no outlier rejection):
    ``normal`` (unit, towards the cameras: its z ≤ 0), ``distance_mm`` (of the plane from the
    left camera centre), ``centroid``, ``rms_mm`` and ``max_mm`` of the residuals; None for
    fewer than 3 points."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) < 3:
        return None
    centroid = points.mean(axis=0)
    centred = points - centroid
    values, vectors = np.linalg.eigh(centred.T @ centred)
    normal = vectors[:, 0]
    if normal[2] > 0:
        normal = -normal
    residual = centred @ normal
    return {"points": int(len(points)), "normal": [float(v) for v in normal],
            "distance_mm": float(abs(normal @ centroid)),
            "centroid_mm": [float(v) for v in centroid],
            "rms_mm": float(np.sqrt(np.mean(residual ** 2))),
            "max_mm": float(np.abs(residual).max())}


def method_summary(triangulation) -> dict:
    """One method's entry of a pair: points, invalid rows, gap statistics, plane fit."""
    valid = np.asarray(triangulation.valid, dtype=bool)
    return {"points": int(valid.sum()), "invalid": int((~valid).sum()),
            "gap": gap_stats(np.asarray(triangulation.gap)[valid]),
            "plane": plane_fit(np.asarray(triangulation.points)[valid])}


def pair_entry(result, files: tuple) -> dict:
    """The report's entry of one pair (:class:`eval.measure.pipeline.PairResult`)."""
    return {"name": result.name, "left": files[0], "right": files[1],
            "problem": result.problem, "failure": result.failure, **result.counts,
            "methods": {m: method_summary(t) for m, t in result.methods.items()},
            "timings_s": result.timings}


def summarize(pairs: list, methods: tuple, results: list) -> dict:
    """The run's totals over the measured pairs: pairs, measured pairs, matched (targets: pairs
    of detections; dense: pixels of the first method), and per method the points and the RMS
    gap of every valid point."""
    measured = [p for p in pairs if not p["problem"]]
    matched = sum(p["matched"] if isinstance(p["matched"], int) else p["matched"].get(methods[0], 0)
                  for p in measured)
    per_method = {}
    for method in methods:
        gaps = [np.asarray(r.methods[method].gap)[np.asarray(r.methods[method].valid, bool)]
                for r in results if method in r.methods]
        gaps = np.concatenate(gaps) if gaps else np.zeros(0)
        per_method[method] = {"points": int(gaps.size), **gap_stats(gaps)}
    return {"pairs": len(pairs), "measured_pairs": len(measured),
            "problems": [p["problem"] for p in pairs if p["problem"]],
            "failures": [p["failure"] for p in pairs if p.get("failure")], "matched": matched,
            "methods": per_method}


def write_points_csv(path, results, pixels) -> int:
    """``points.csv`` (:data:`CSV_COLUMNS`): one row per valid point of each pair and method;
    ``pixels(result, method)`` gives that method's ``(uv_left, uv_right)``. Returns the rows."""
    from synth.infra.fileio import atomic_write_text

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    rows = 0
    for result in results:
        for method, t in result.methods.items():
            valid = np.asarray(t.valid, dtype=bool)
            uv_left, uv_right = pixels(result, method)
            block = np.column_stack([np.asarray(t.points)[valid], np.asarray(t.gap)[valid],
                                     np.asarray(uv_left)[valid], np.asarray(uv_right)[valid]])
            name = io.StringIO()  # the pair's name quoted as csv quotes it
            csv.writer(name, lineterminator="").writerow((result.name, method))
            prefix = name.getvalue().replace("%", "%%") + ","
            np.savetxt(buffer, block, fmt=prefix + ",".join(["%.6f"] * 4 + ["%.4f"] * 4))
            rows += int(valid.sum())
    atomic_write_text(path, buffer.getvalue())
    return rows


def write_cloud(path, points) -> int:
    """``points`` ``(N, 3)`` mm as a binary PLY (Open3D); returns the number of points."""
    import open3d as o3d

    from synth.infra.fileio import atomic_write_bytes

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    tmp = os.path.join(os.path.dirname(path), "." + os.path.basename(path) + ".tmp.ply")
    if not o3d.io.write_point_cloud(tmp, cloud, write_ascii=False):
        raise OSError(f"cannot write {path}")
    with open(tmp, "rb") as handle:
        data = handle.read()
    os.remove(tmp)
    atomic_write_bytes(path, data)
    return int(len(points))


def method_points(results, method) -> np.ndarray:
    """The valid points of ``method`` over every pair, in pair order ``(N, 3)`` mm."""
    blocks = [np.asarray(r.methods[method].points)[np.asarray(r.methods[method].valid, bool)]
              for r in results if method in r.methods]
    return np.concatenate(blocks) if blocks else np.zeros((0, 3))


def _covariances(results, method):
    """The valid points of ``method`` over every pair and their covariances, pair order."""
    points, covariances = [], []
    for r in results:
        if method in r.covariances:
            valid = np.asarray(r.methods[method].valid, bool)
            points.append(np.asarray(r.methods[method].points)[valid])
            covariances.append(r.covariances[method].total[valid])
    if not points:
        return np.zeros((0, 3)), np.zeros((0, 3, 3))
    return np.concatenate(points), np.concatenate(covariances)


def uncertainty_report(inputs, options, results, pairs) -> dict:
    """The report's ``uncertainty``: where the covariances come from (the pixel σ of each pair,
    the calibration's covariance or its absence) and per method the σ summary over every pair;
    each pair's ``methods.<m>.sigma`` is filled in ``pairs``. Nothing for a dense run (no
    covariance per pixel yet)."""
    from eval.core.uncertainty import rig_covariance_note
    from measure.stereo.uncertainty import sigma_summary

    if not hasattr(options, "pixel_sigma"):
        return {"note": "dense: no covariance per pixel (not implemented)"}
    for entry, result in zip(pairs, results):
        for method, covariance in result.covariances.items():
            valid = np.asarray(result.methods[method].valid, bool)
            entry["methods"][method]["sigma"] = sigma_summary(covariance.total[valid])
    methods = sorted({m for r in results for m in r.covariances},
                     key=list(options.methods).index)
    return {"rig": rig_covariance_note(inputs.rig_covariance, inputs.calib_path),
            "pixel_sigma": {r.name: r.pixel_sigma for r in results if r.pixel_sigma},
            "methods": {m: {"sigma": sigma_summary(_covariances(results, m)[1])}
                        for m in methods}}


def write_uncertainty_outputs(tmp: str, report: dict, results) -> None:
    """``uncertainty_<method>.ply`` / ``.csv`` (the rows of ``points_<method>``: every pair's
    valid points in pair order) and ``ellipses.png`` (the first such method's points)."""
    from eval.core.figures import ellipses_figure
    from eval.core.uncertainty import write_uncertainty_files

    unc = report.get("uncertainty") or {}
    files, figure = {}, {}
    for method in unc.get("methods", {}):
        points, covariance = _covariances(results, method)
        files[method] = write_uncertainty_files(tmp, method, points, covariance)
        figure[method] = {"points": points, "covariance": covariance}
    if files:
        unc["files"] = files
        ellipses_figure(os.path.join(tmp, "ellipses.png"), figure)


def uncertainty_markdown(report: dict) -> list:
    """report.md's lines on the covariances."""
    unc = report.get("uncertainty") or {}
    if not unc.get("methods"):
        return [f"Uncertainty: {unc['note']}.", ""] if unc.get("note") else []
    lines = ["## Uncertainty", "", f"Point covariances: {unc['rig']}.", "",
             "| method | median σx | median σy | median σz | largest σP |", "|---|---|---|---|---|"]
    for method, entry in unc["methods"].items():
        sig = entry["sigma"]
        med = sig.get("median_sigma_mm") or {}
        lines.append(f"| {method} | {fmt(med.get('x'), 4)} | {fmt(med.get('y'), 4)} | "
                     f"{fmt(med.get('z'), 4)} | {fmt(sig.get('max_sigma_p_mm'), 4)} |")
    lines += ["", "σ in mm, first order: the pixel noise of each detection (its σ from the "
              "detector's SNR and size plus what the reprojection residuals show beyond it, or "
              "--pixel-sigma) and the calibration's covariance, if it holds one. "
              "`uncertainty_<method>.csv` / `.ply`: each point's σ and covariance.", ""]
    return lines


def report_markdown(report: dict) -> str:
    """``report.md``: what was measured, per pair and method, without any truth."""
    s = report["summary"]
    dense = report["mode"] == "dense"
    lines = [f"# Measurement: `{report['calib']}`", "",
             f"{s['pairs']} pair(s) of {report['image_size'][0]}x{report['image_size'][1]} px "
             f"photos, {s['measured_pairs']} measured; "
             f"{'dense matching of a speckled surface' if dense else 'targets'}; methods "
             f"{', '.join(report['methods'])}. No truth: the numbers below are what the photos "
             f"and the calibration say.", ""]
    if not report.get("has_port", True):
        lines += [f"**No port:** {calibration_note('`' + report['calib'] + '`', report.get('model'))}.",
                  ""]
    if s.get("failures"):
        lines += ["## Verdict: failed (exit code 1)", "", *[f"- {p}" for p in s["failures"]], ""]
    if s["problems"]:
        lines += ["## Problems", "", *[f"- {p}" for p in s["problems"]], ""]
    lines += ["## Pairs", ""]
    if dense:
        lines += ["| pair | method | matched pixels | points | gap RMS (mm) | gap max (mm) | "
                  "plane RMS (mm) | plane normal | plane distance (mm) |",
                  "|---|---|---|---|---|---|---|---|---|"]
    else:
        lines += ["| pair | detected L/R | matched | ambiguous | unmatched L/R | method | points | "
                  "gap RMS (mm) | gap max (mm) | plane RMS (mm) | plane normal | "
                  "plane distance (mm) |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for p in report["pairs"]:
        for method, m in (p["methods"] or {"–": None}).items():
            m = m or {"points": 0, "gap": {}, "plane": None}
            plane = m["plane"] or {}
            normal = ("(" + ", ".join(f"{v:.4f}" for v in plane["normal"]) + ")"
                      if plane.get("normal") else "–")
            numbers = (f"{m['points']} | {fmt(m['gap'].get('rms_mm'), 4)} | "
                       f"{fmt(m['gap'].get('max_mm'), 4)} | {fmt(plane.get('rms_mm'), 4)} | "
                       f"{normal} | {fmt(plane.get('distance_mm'), 2)} |")
            if dense:
                lines.append(f"| {p['name']} | {method} | {p['matched'].get(method, 0)} | "
                             f"{numbers}")
            else:
                d, u = p["detected"], p["unmatched"]
                lines.append(f"| {p['name']} | {d['left']}/{d['right']} | {p['matched']} | "
                             f"{p['ambiguous']} | {u['left']}/{u['right']} | {method} | "
                             f"{numbers}")
    lines += ["", "## All pairs", "", "| method | points | gap RMS (mm) | gap median (mm) | "
              "gap max (mm) |", "|---|---|---|---|---|"]
    for method, m in s["methods"].items():
        lines.append(f"| {method} | {m['points']} | {fmt(m['rms_mm'], 4)} | "
                     f"{fmt(m['median_mm'], 4)} | {fmt(m['max_mm'], 4)} |")
    lines += ["", "Gap: the length of the common perpendicular of the two final rays of a point "
              "(the water rays; for regular the straight rays): 0 for a perfect calibration and "
              "perfect pixels. Plane: the least-squares plane "
              "of the pair's points (all of them), its normal towards the cameras, the RMS and "
              "largest distance of the points from it.", "", *uncertainty_markdown(report),
              "## Files", "",
              f"- `points.ply`: the {report['methods'][0]} points of every pair (mm, binary PLY)",
              *[f"- `{f}`: the {m} points" for m, f in report["files"]["clouds"].items()
                if f != "points.ply"],
              f"- `points.csv`: {', '.join(CSV_COLUMNS)} ({report['files']['csv_rows']} rows)",
              *[f"- `{f}`" for f in report["files"]["views"]],
              *[f"- `{f['ply']}`, `{f['csv']}`: the {m} points with σx, σy, σz (mm) and their "
                f"covariance (mm²)" for m, f in
                ((report.get("uncertainty") or {}).get("files") or {}).items()],
              *(["- `ellipses.png`"] if (report.get("uncertainty") or {}).get("files") else []),
              ""]
    return "\n".join(lines)


__all__ = ["CSV_COLUMNS", "gap_stats", "method_points", "method_summary", "pair_entry",
           "plane_fit", "report_markdown", "summarize", "uncertainty_markdown",
           "uncertainty_report", "write_cloud", "write_points_csv", "write_uncertainty_outputs"]
