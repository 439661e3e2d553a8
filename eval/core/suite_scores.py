"""Scoring a whole benchmark suite (``python -m synth suite``) against a submission folder:
``python -m eval score SUITE --submission DIR``.

``DIR/<folder>/`` holds the pipeline's output for the dataset ``SUITE/<folder>/``
(:func:`find_submission`, first match wins):

* target datasets — ``points.ply`` (3D points, mm, the left camera's frame; ``eval measure``
  writes it), ``points_<method>_all.ply`` or ``points_<method>.ply`` (``eval run``'s clouds:
  every point, and the correctly matched ones; ``method`` = ``--method``, default
  optical_path) or ``pairs.csv`` (matched pixels ``u_left, v_left, u_right, v_right``,
  triangulated here with ``--method`` and the dataset's calibration);
* surface datasets — ``depth.pfm`` or ``depth.npy`` (depth along the left camera's z, mm, in
  the left image's pixel grid, NaN or 0 where none), turned into points on each pixel's refracted
  ray (the dataset's true rig) and scored with ``eval run``'s dense metrics; or ``points.ply``
  (a point cloud, mm, the left camera's frame), scored with the same metrics
  (:func:`eval.core.surface_metrics.score_surface_cloud`: every point against the mesh, each
  point against the true point of the left pixel it projects to) after the plausibility check
  of target clouds (metres, another frame) against the true surface points.

Every dataset of the index is scored with the metrics of ``eval score`` / ``eval run``
(:func:`eval.core.scoring.score_dataset`, :func:`eval.core.surface_metrics.score_surface`); a
missing or unreadable entry is a row with ``status`` ``missing`` or ``failed`` and its reason,
never skipped. Plausibility warnings (metres for millimetres, another frame) are kept per row.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from synth.infra.cli import CLIError

#: Metrics of target datasets carried into the summary (``eval run``'s names).
TARGET_METRICS = ("rms_dp_mm", "max_dp_mm", "mean_dx_mm", "mean_dy_mm", "mean_dz_mm",
                  "chamfer_mm", "fscore_1mm", "fscore_5mm", "rms_dp_aligned_mm", "flatness_mm")
#: Metrics of surface datasets carried into the summary.
SURFACE_METRICS = ("p2m_rms_mm", "p2m_median_mm", "p2m_max_mm", "fscore_1mm", "chamfer_mm",
                   "depth_rms_mm", "depth_mean_mm", "measured_fraction")
#: The metric the figures and the aggregation headline show, per kind of dataset.
HEADLINE = {"targets": "rms_dp_mm", "surface": "p2m_rms_mm"}
#: Statuses of a row that count as failures (``not_applicable``: a board sequence, not scored).
FAILURES = ("missing", "failed")
#: Metrics where larger is better (their "worst" is the minimum).
HIGHER_IS_BETTER = ("fscore_1mm", "fscore_5mm", "measured_fraction")


def read_suite(path) -> tuple[dict, list]:
    """``(suite.json, index rows)`` of a suite folder; CLIError when it is not one."""
    import pyarrow.parquet as pq

    info_path = os.path.join(path, "suite.json")
    index_path = os.path.join(path, "index.parquet")
    if not (os.path.isfile(info_path) and os.path.isfile(index_path)):
        raise CLIError(f"{path}: not a suite folder (no suite.json and index.parquet: write one "
                       f"with python -m synth suite)")
    try:
        with open(info_path, encoding="utf-8") as handle:
            info = json.load(handle)
        rows = pq.read_table(index_path).to_pylist()
    except (OSError, ValueError) as exc:
        raise CLIError(f"{path}: cannot read the suite ({exc})") from None
    return info, rows


def find_submission(directory: str, render: str, method: str) -> tuple[str, str] | None:
    """``(kind, path)`` of the first submission file in ``directory`` (module docs), or None."""
    names = ((("points", "points.ply"), ("points", f"points_{method}_all.ply"),
              ("points", f"points_{method}.ply"), ("pairs", "pairs.csv"))
             if render == "targets" else
             (("depth", "depth.pfm"), ("depth", "depth.npy"), ("points", "points.ply")))
    for kind, name in names:
        path = os.path.join(directory, name)
        if os.path.isfile(path):
            return kind, path
    return None


def depth_points(path: str, data) -> np.ndarray:
    """``(H, W, 3)`` mm: each left pixel's refracted ray at the submitted depth along z."""
    from measure.geometry.refraction import trace_through_port

    from synth.formats.exchange import read_pfm

    depth = read_pfm(path) if path.endswith(".pfm") else np.load(path, allow_pickle=False)
    w, h = data.rig.left.size
    if not (np.issubdtype(depth.dtype, np.integer) or np.issubdtype(depth.dtype, np.floating)):
        raise ValueError(f"{path}: holds {depth.dtype} values, not depths (numbers, mm)")
    if depth.ndim != 2:
        raise ValueError(f"{path}: a {depth.ndim}-d array of shape {depth.shape}, not a depth "
                         f"map of the left image's {h} x {w} (rows x columns) pixels")
    if depth.shape != (h, w):
        raise ValueError(f"{path}: {depth.shape[1]} x {depth.shape[0]} px, the left image is "
                         f"{w} x {h}")
    with np.errstate(invalid="ignore"):
        depth = np.where(depth > 0, depth.astype(np.float64), np.nan)
    depth[~np.isfinite(depth)] = np.nan
    if not np.isfinite(depth).any():
        raise ValueError(f"{path}: no pixel has a finite positive depth (all NaN, infinite, zero "
                         f"or negative): nothing to score")
    _check_byte_order(path, depth)
    rows, cols = np.nonzero(np.isfinite(depth))
    camera = data.rig.left
    rays = trace_through_port(camera.center, camera.rays(np.column_stack([cols, rows]).astype(
        np.float64)), data.rig.port, keep_interface_points=False)
    # the point of the ray at depth z along the left camera's z axis
    axis = camera.R[:, 2]
    z0 = (rays.origins - camera.center) @ axis
    s = (depth[rows, cols] - z0) / (rays.directions @ axis)
    points = np.full((h, w, 3), np.nan)
    points[rows, cols] = rays.origins + s[:, None] * rays.directions
    return points


#: Depths (mm) no scene of this project has: a median finite positive depth outside is a file
#: misread (a PFM whose scale's sign — its byte order — does not match its data: 1000 mm read
#: with the other byte order is 1e-41).
PLAUSIBLE_DEPTH_MM = (1e-3, 1e9)


def _check_byte_order(path: str, depth: np.ndarray) -> None:
    """ValueError when the depths of a PFM are implausible and the same bytes in the other byte
    order are plausible: the header's scale says the wrong byte order."""
    lo, hi = PLAUSIBLE_DEPTH_MM
    median = float(np.nanmedian(depth))
    if not path.endswith(".pfm") or lo <= median <= hi:
        return
    with np.errstate(invalid="ignore", over="ignore"):
        swapped = depth.astype(np.float32).byteswap()
    with open(path, "rb") as handle:
        handle.readline(), handle.readline()
        scale = float(handle.readline())
    order = "little" if scale < 0 else "big"
    other = "big" if scale < 0 else "little"
    finite = swapped[np.isfinite(swapped) & (swapped > 0)]
    if finite.size and lo <= float(np.median(finite)) <= hi:
        raise ValueError(f"{path}: the header's scale {scale:g} says {order}-endian data, but the "
                         f"data read as {order}-endian are not depths (median {median:.3g} mm) "
                         f"and read as {other}-endian are (median {float(np.median(finite)):.4g} "
                         f"mm): write the scale {'positive' if scale < 0 else 'negative'}")
    raise ValueError(f"{path}: the depths are not millimetres of a scene (median {median:.3g} mm)")


#: How the error of a dataset whose scoring met a bug starts (the run then exits 3).
INTERNAL_ERROR = "internal error"


def score_entry(suite_dir: str, sub_dir: str, row: dict, method: str, gate_mm) -> dict:
    """One row of the summary: the index row's folder and parameters, ``status`` (``ok``,
    ``missing``, ``failed``), ``error``, ``submission`` (the file), ``warnings`` and the
    metrics."""
    from synth.products.dataset import DatasetError, is_views_dataset, read_dataset

    out = {"status": "ok", "error": None, "submission": None, "warnings": ""}
    if row.get("status") != "ok":
        return {**out, "status": "failed", "error": f"the suite has no dataset here "
                                                     f"({row.get('error')})"}
    if row["render"] == "boards":
        return {**out, "status": "not_applicable",
                "error": "a board sequence: calibrate from it with python -m eval calibrate"}
    found = find_submission(os.path.join(sub_dir, row["folder"]), row["render"], method)
    if found is None:
        wanted = ("points.ply, points_<method>.ply or pairs.csv" if row["render"] == "targets"
                  else "depth.pfm, depth.npy or points.ply")
        return {**out, "status": "missing",
                "error": f"no submission: {os.path.join(sub_dir, row['folder'])} holds none of "
                         f"{wanted}"}
    kind, path = found
    out["submission"] = os.path.relpath(path, sub_dir)
    try:
        folder = os.path.join(suite_dir, row["folder"])
        if is_views_dataset(folder):  # N cameras: points are scored, pairs are two views
            if kind != "points":
                raise ValueError(f"{row['folder']}: a dataset of N cameras; pairs of pixels are "
                                 f"two views: submit points.ply")
        data = read_dataset(folder)
        if row["render"] == "targets":
            out.update(_score_targets(data, kind, path, method, gate_mm))
        else:
            out.update(_score_surface(data, kind, path))
    except (CLIError, DatasetError, ValueError, OSError) as exc:
        return {**out, "status": "failed", "error": _naming(exc, path, out["submission"])}
    except MemoryError:
        raise
    except Exception as exc:  # a bug: this dataset fails, named; the others are scored
        return {**out, "status": "failed",
                "error": f"{INTERNAL_ERROR}: {type(exc).__name__}: {' '.join(str(exc).split())}"}
    return out


def _naming(exc, path: str, name: str) -> str:
    """A submission's error as one line that names its file (``name``, relative to the
    submission folder): the single-file readers say ``--points PATH`` or ``--pixels PATH``,
    options a suite's user never gave, and some errors name no file at all."""
    message = " ".join(str(exc).split())
    for option in ("--points ", "--pixels "):
        message = message.replace(f"{option}{path}", name)
    return message if name in message or path in message else f"{name}: {message}"


def _suite_warnings(warnings) -> str:
    """The score's warnings as one line; a suite's submissions have no ``--units``, so the
    metres warning says what to write instead of naming the option."""
    return "; ".join(w.replace(" (pass --units m)", ": write millimetres") for w in warnings)


def _score_targets(data, kind: str, path: str, method: str, gate_mm) -> dict:
    from measure import triangulate

    from eval.core.scoring import read_pixel_pairs, read_points, score_dataset

    if kind == "points":
        points, label = read_points(path), "submission"
    else:
        pairs = read_pixel_pairs(path)
        result = triangulate(data.rig, pairs[:, :2], pairs[:, 2:], method)
        if not result.valid.any():
            raise ValueError(f"{path}: no pair triangulates with {method}")
        points, label = result.points[result.valid], method
    report, _, warnings = score_dataset(data, points, label, gate_mm)
    scores = report["methods"][label]
    a = report["association"]
    return {"warnings": _suite_warnings(warnings), "points": a["points"],
            "associated": a["associated"], "unassociated": a["unassociated"],
            "visible_in_both": a["visible_in_both"],
            "visible_in_both_scored": a["visible_in_both_scored"],
            **{k: scores.get(k) for k in TARGET_METRICS}, "scores": scores}


#: Gate (mm) of the plausibility check of a surface cloud (:func:`eval.core.scoring.plausibility`
#: against the true points of the overlap pixels): the largest F-score threshold of the surface
#: metrics — a point within it of a true point lies on the surface.
SURFACE_GATE_MM = 5.0


def _score_surface(data, kind: str, path: str) -> dict:
    from eval.core.surface_metrics import SurfaceCase, score_surface
    from synth.scene.surfaces import read_ply
    from synth.products.truth_maps import SURFACE_FILE, read_truth_maps

    truth = read_truth_maps(data.path, "left", data.rig.left.size)
    vertices, triangles = read_ply(os.path.join(data.path, SURFACE_FILE))
    if kind == "depth":
        measured = depth_points(path, data)
        scores = score_surface(SurfaceCase(vertices, triangles, measured, truth.points,
                                           truth.overlap, data.rig.port.normal))
        return {**{k: scores.get(k) for k in SURFACE_METRICS}, "scores": scores}
    from eval.core.scoring import read_points

    points = read_points(path)
    scores, warnings = score_surface_points(data, points, truth, (vertices, triangles))
    return {"warnings": _suite_warnings(warnings),
            "points": int(len(points)),
            **{k: scores.get(k) for k in SURFACE_METRICS}, "scores": scores}


def score_surface_points(data, points, truth=None, mesh=None) -> tuple[dict, list]:
    """``(scores, warnings)`` of a cloud ``points`` ``(N, 3)`` mm against the surface dataset
    ``data``: every point against the true mesh and, through the pixel it projects to in the
    left view, against that pixel's true point
    (:func:`eval.core.surface_metrics.score_surface_cloud`); the plausibility warnings
    (metres, another frame) against the true points of the overlap pixels. ``truth`` (the left
    truth maps) and ``mesh`` (vertices, triangles) are read when not given."""
    from measure.geometry.projection import project

    from eval.core.scoring import plausibility
    from eval.core.surface_metrics import score_surface_cloud
    from synth.products.truth_maps import SURFACE_FILE, read_truth_maps
    from synth.scene.surfaces import read_ply

    if truth is None:
        truth = read_truth_maps(data.path, "left", data.rig.left.size)
    vertices, triangles = mesh or read_ply(os.path.join(data.path, SURFACE_FILE))
    on_surface = truth.points[truth.overlap]
    on_surface = on_surface[np.isfinite(on_surface).all(axis=1)]
    warnings = plausibility(points, on_surface, SURFACE_GATE_MM)
    pixels = project(data.rig.left, data.rig.port, points)
    scores = score_surface_cloud(vertices, triangles, points, pixels, truth.points,
                                 truth.overlap, data.rig.port.normal)
    return scores, warnings


def score_suite(suite_dir: str, sub_dir: str, method: str = "optical_path",
                gate_mm=None, log=None) -> tuple[dict, list]:
    """``(suite.json, rows)``: every dataset of the suite's index scored (module docs)."""
    info, index = read_suite(suite_dir)
    if not os.path.isdir(sub_dir):
        raise CLIError(f"--submission {sub_dir}: no such folder")
    swept = [s for s in info.get("swept", []) if s != "scene"]
    rows = []
    for number, row in enumerate(index, start=1):
        result = score_entry(suite_dir, sub_dir, row, method, gate_mm)
        base = {"folder": row["folder"], "render": row["render"], "scene": row["scene"],
                "seed": row["seed"], **{k: row.get(k) for k in swept}}
        rows.append({**base, **result})
        if log is not None:
            log(f"[{number}/{len(index)}] {row['folder']}: {result['status']}"
                f"{' (' + result['error'] + ')' if result['error'] else ''}")
    return info, rows


def _finite(values) -> list:
    return [float(v) for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)
            and math.isfinite(v)]


def distinct_values(rows: list, name: str) -> list:
    """The values ``name`` takes over ``rows``, once each: numbers in numeric order first,
    then the others by their text."""
    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    values = {}
    for r in rows:
        v = r.get(name)
        values.setdefault(("n", float(v)) if number(v) else ("o", json.dumps(v)), v)
    return sorted(values.values(), key=lambda v: (0, v, "") if number(v) else (1, 0, str(v)))


def aggregate(rows: list, swept: list) -> list:
    """Rows of the aggregation: over all datasets, and per value of each swept parameter —
    ``group``, ``value``, ``datasets``, ``scored``, ``failed`` (missing or failed), and for each
    metric its mean, median and worst (the largest error; the smallest F-score or fraction)."""
    metrics = [m for m in TARGET_METRICS + SURFACE_METRICS
               if any(r.get(m) is not None for r in rows)]
    metrics = list(dict.fromkeys(metrics))
    groups = [("all", None, rows)]
    for name in swept:
        for value in distinct_values(rows, name):
            groups.append((name, value, [r for r in rows if r.get(name) == value]))
    out = []
    for name, value, members in groups:
        scored = [r for r in members if r["status"] == "ok"]
        entry = {"group": name, "value": None if value is None else str(value),
                 "datasets": len(members), "scored": len(scored),
                 "failed": sum(r["status"] in FAILURES for r in members)}
        for metric in metrics:
            values = _finite(r.get(metric) for r in scored)
            worst = (min if metric in HIGHER_IS_BETTER else
                     (lambda v: max(v, key=abs)) if metric.startswith("mean_") else max)
            entry[f"{metric}.mean"] = float(np.mean(values)) if values else None
            entry[f"{metric}.median"] = float(np.median(values)) if values else None
            entry[f"{metric}.worst"] = worst(values) if values else None
        out.append(entry)
    return out


def write_summary(directory: str, info: dict, rows: list, suite_dir: str, sub_dir: str) -> list:
    """``summary.csv`` / ``summary.parquet`` (one row per dataset, then the aggregation rows:
    ``row`` says which), ``summary.md`` and ``figures/error_vs_<param>.png``; returns the files
    written (relative)."""
    from synth.infra.fileio import atomic_write_text
    from synth.infra.tables import write_table

    swept = [s for s in info.get("swept", [])]
    aggregated = aggregate(rows, swept)
    table_rows = [{"row": "dataset", **{k: v for k, v in r.items() if k != "scores"}}
                  for r in rows]
    table_rows += [{"row": "aggregate", **a} for a in aggregated]
    columns = list(dict.fromkeys(k for r in table_rows for k in r))
    write_table(directory, "summary", table_rows, columns)
    figures = write_figures(os.path.join(directory, "figures"), rows, swept)
    atomic_write_text(os.path.join(directory, "summary.md"),
                      summary_markdown(info, rows, aggregated, suite_dir, sub_dir, figures))
    return ["summary.md", "summary.csv", "summary.parquet", *figures]


def _fmt(value) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def summary_markdown(info, rows, aggregated, suite_dir, sub_dir, figures) -> str:
    render = rows[0]["render"] if rows else "targets"
    metrics = [m for m in (TARGET_METRICS if render == "targets" else SURFACE_METRICS)][:6]
    failed = [r for r in rows if r["status"] in FAILURES]
    warned = [r for r in rows if r.get("warnings")]
    lines = [f"# Scores of {sub_dir} against the suite {info.get('name', suite_dir)}", "",
             f"{len(rows)} datasets, {len(rows) - len(failed)} scored, **{len(failed)} "
             f"missing or failed** (they count as failures: listed below).", ""]
    if warned:
        lines += ["## Warnings (the submission looks wrong)", ""]
        lines += [f"- `{r['folder']}`: {r['warnings']}" for r in warned] + [""]
    if failed:
        lines += ["## Missing or failed", ""]
        lines += [f"- `{r['folder']}` ({r['status']}): {r['error']}" for r in failed] + [""]
    lines += ["## Aggregated", "", "mean / median / worst over the scored datasets (mm).", "",
              "| group | value | scored | failed | " + " | ".join(metrics) + " |",
              "|---|---|---|---|" + "---|" * len(metrics)]
    for a in aggregated:
        cells = [f"{_fmt(a.get(m + '.mean'))} / {_fmt(a.get(m + '.median'))} / "
                 f"{_fmt(a.get(m + '.worst'))}" for m in metrics]
        lines.append(f"| {a['group']} | {_fmt(a['value'])} | {a['scored']} | {a['failed']} | "
                     + " | ".join(cells) + " |")
    lines += ["", "## Per dataset", "",
              "| folder | status | submission | " + " | ".join(metrics) + " |",
              "|---|---|---|" + "---|" * len(metrics)]
    for r in rows:
        lines.append(f"| {r['folder']} | {r['status']} | {_fmt(r.get('submission'))} | "
                     + " | ".join(_fmt(r.get(m)) for m in metrics) + " |")
    if figures:
        lines += ["", "## Figures", ""] + [f"![{f}]({f})" for f in figures]
    return "\n".join(lines) + "\n"


def write_figures(directory: str, rows: list, swept: list) -> list:
    """``error_vs_<param>.png`` per swept parameter: the headline metric of each scored dataset
    against the parameter's value (mean, min and max per value)."""
    from eval.core.figures import new_figure, save_figure

    scored = [r for r in rows if r["status"] == "ok"]
    if not scored or not swept:
        return []
    metric = HEADLINE.get(scored[0]["render"], "rms_dp_mm")
    os.makedirs(directory, exist_ok=True)
    written = []
    for name in swept:
        labels = distinct_values(scored, name)
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in labels)
        xs = labels if numeric else list(range(len(labels)))
        stats = []
        for value in labels:
            ys = _finite(r.get(metric) for r in scored if r.get(name) == value)
            stats.append((np.mean(ys), min(ys), max(ys)) if ys else (np.nan,) * 3)
        stats = np.array(stats, dtype=float)
        fig = new_figure(5.0, 3.4)
        ax = fig.add_subplot()
        ax.plot(xs, stats[:, 0], "o-", label="mean")
        ax.fill_between(xs, stats[:, 1], stats[:, 2], alpha=0.25, label="min – max")
        if not numeric:
            ax.set_xticks(xs, [os.path.basename(str(v)) for v in labels], rotation=20,
                          fontsize=7)
        ax.set_xlabel(name)
        ax.set_ylabel(metric)
        ax.legend(fontsize=7)
        safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in name)
        save_figure(fig, os.path.join(directory, f"error_vs_{safe}.png"))
        written.append(f"figures/error_vs_{safe}.png")
    return written


__all__ = ["FAILURES", "HEADLINE", "INTERNAL_ERROR", "PLAUSIBLE_DEPTH_MM", "SURFACE_METRICS",
           "TARGET_METRICS", "aggregate", "depth_points",
           "SURFACE_GATE_MM", "distinct_values", "find_submission",
           "read_suite", "score_entry", "score_suite", "score_surface_points", "summary_markdown",
           "write_figures",
           "write_summary"]
