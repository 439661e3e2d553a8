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
``points_<method>.ply`` reproduces that run's numbers.

A submission is checked for plausibility before it is scored (:func:`plausibility`): when the
points fit the targets markedly better scaled by 1000 (metres), reflected (an axis negated) or
shifted rigidly, or some repeat others, one line ``warning: …`` names the likely cause on
stderr and in the report (``warnings``); the points are scored as given all the same.

Writes to ``--out``: ``report.json``, ``report.md``, ``error_maps.png``, ``histograms.png`` and
``points_scored.ply`` (the associated points coloured by dP).
"""

from __future__ import annotations

import csv
import os
import sys
import time

import numpy as np

from eval.cli import CLIError, positive_float
from synth.cli import add_json_option, add_out_option
from eval.core.formatting import format_number as fmt

COMMAND = "eval score"
PIXEL_COLUMNS = ("u_left", "v_left", "u_right", "v_right")
#: ``--units`` of ``--points``: millimetres per unit.
UNITS = {"mm": 1.0, "m": 1000.0}
#: Points closer than this to an earlier point count as repeats of it (mm).
DUPLICATE_MM = 1e-6
#: Most points the plausibility check looks at (an evenly spaced subsample beyond).
PLAUSIBILITY_POINTS = 20_000


def add_parser(subparsers):
    from measure.triangulate import METHODS

    p = subparsers.add_parser(
        "score", help="score an external reconstruction against a rendered dataset",
        description="Score your own pipeline's points (or matched pixel pairs) against the "
                    "truth of a python -m synth dataset, with eval run's metrics.")
    p.add_argument("dataset", help="dataset folder (python -m synth dataset)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--points", metavar="THEIRS.ply",
                        help="your 3D points, mm, in the dataset's reference frame")
    source.add_argument("--pixels", metavar="THEIRS.csv",
                        help="your matched pixel pairs: CSV with columns "
                             + ", ".join(PIXEL_COLUMNS))
    p.add_argument("--method", default=None, choices=METHODS[:3],
                   help="triangulation of --pixels (default optical_path)")
    p.add_argument("--units", default=None, choices=UNITS,
                   help="units of --points (default mm; m: the points are multiplied by 1000)")
    p.add_argument("--gate-mm", type=positive_float, default=None,
                   help="largest distance of a point from its target, mm (default: half the "
                        "smallest distance between two targets, where the nearest target is "
                        "unambiguous)")
    add_out_option(p, COMMAND, "out/score")
    add_json_option(p)


def read_points(path) -> np.ndarray:
    """``(N, 3)`` float64 points of a point-cloud file, read whole (a truncated file is
    refused: :mod:`synth.cloudfile`); CLIError when unreadable, empty or not finite."""
    from synth.cloudfile import CloudFileError, read_cloud_points

    if not os.path.isfile(path):
        raise CLIError(f"--points {path}: no such file")
    try:
        points = read_cloud_points(path)
    except CloudFileError as exc:
        raise CLIError(f"--points {exc}") from None
    if points.shape[0] == 0:
        raise CLIError(f"--points {path}: no points (not a point cloud Open3D can read, or empty)")
    bad = ~np.all(np.isfinite(points), axis=1)
    if bad.any():
        raise CLIError(f"--points {path}: {int(bad.sum())} of {len(points)} points have NaN or "
                       f"infinite coordinates (row {int(np.flatnonzero(bad)[0])} first)")
    return points


def read_pixel_pairs(path) -> np.ndarray:
    """``(N, 4)`` ``u_left, v_left, u_right, v_right`` from a CSV with those columns (others
    ignored); CLIError naming what is wrong."""
    if not os.path.isfile(path):
        raise CLIError(f"--pixels {path}: no such file")
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        missing = [c for c in PIXEL_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise CLIError(f"--pixels {path}: missing column(s) {', '.join(missing)} (needs "
                           f"{', '.join(PIXEL_COLUMNS)})")
        rows = []
        for line, row in enumerate(reader, start=2):
            try:
                values = [float(row[c]) for c in PIXEL_COLUMNS]
            except (TypeError, ValueError):
                raise CLIError(f"--pixels {path}: line {line}: not a number in "
                               f"{', '.join(PIXEL_COLUMNS)}") from None
            if not np.all(np.isfinite(values)):
                raise CLIError(f"--pixels {path}: line {line}: NaN or infinite pixel")
            rows.append(values)
    if not rows:
        raise CLIError(f"--pixels {path}: no pixel pairs")
    return np.asarray(rows, dtype=np.float64)


def associate_points(points: np.ndarray, truth: np.ndarray, gate_mm: float) -> np.ndarray:
    """Index of each point's true target ``(N,)``, −1 where none: the nearest target within
    ``gate_mm``; when several points claim one target, the nearest keeps it."""
    from scipy.spatial import cKDTree

    distance, index = cKDTree(truth).query(points, distance_upper_bound=gate_mm)
    order = np.argsort(distance, kind="stable")  # nearest first; misses (inf) last
    order = order[np.isfinite(distance[order])]
    winners = order[np.unique(index[order], return_index=True)[1]]
    result = np.full(len(points), -1)
    result[winners] = index[winners]
    return result


def default_gate_mm(truth: np.ndarray) -> float:
    """Half the smallest distance between two of the targets ``truth`` ``(M, 3)`` (mm): a point
    closer than that to a target is closer to it than to any other."""
    from scipy.spatial import cKDTree

    if len(truth) < 2:
        return float("inf")
    return float(cKDTree(truth).query(truth, k=2)[0][:, 1].min() / 2)


def score_points(points: np.ndarray, truth: np.ndarray, visible_both: np.ndarray, gate_mm: float,
                 seed: int):
    """``(scores, per_method_arrays, association)`` of ``points`` against the true targets
    ``truth`` ``(M, 3)``; Chamfer and F-scores against ``truth[visible_both]``."""
    from eval.core.cloud_metrics import cloud_distances, flatness, rigid_alignment
    from eval.core.results import ErrorStats, MethodScores

    target = associate_points(points, truth, gate_mm)
    ok = target >= 0
    errors = points[ok] - truth[target[ok]]
    scores = MethodScores(errors=ErrorStats.of(errors),
                          cloud=cloud_distances(points, truth[visible_both]),
                          alignment=rigid_alignment(points[ok], truth[target[ok]]),
                          flatness=flatness(points, seed=seed), invalid=0)
    arrays = {"points": points[ok], "truth": truth[target[ok]], "errors": errors,
              "all_points": points}
    association = {"points": int(len(points)), "associated": int(ok.sum()),
                   "unassociated": int((~ok).sum()), "gate_mm": gate_mm,
                   "visible_in_both": int(visible_both.sum()),
                   "visible_in_both_scored": int(np.isin(np.flatnonzero(visible_both),
                                                         target[ok]).sum())}
    return scores, arrays, association


def _fit(points: np.ndarray, truth: np.ndarray, gate_mm: float) -> tuple[int, float]:
    """``(points associated with a target, RMS of their distances)`` (inf when none): one
    point per target (:func:`associate_points`), so that a cloud shrunk onto one target counts
    once."""
    target = associate_points(points, truth, gate_mm)
    ok = target >= 0
    if not ok.any():
        return 0, float("inf")
    distance = np.linalg.norm(points[ok] - truth[target[ok]], axis=1)
    return int(ok.sum()), float(np.sqrt(np.mean(distance ** 2)))


def _rigid_shift(points: np.ndarray, truth: np.ndarray, tree, gate_mm: float) -> np.ndarray:
    """The translation that best lays ``points`` on the targets: from centroid to centroid,
    then refined a few times on the points that fall within the gate (mm)."""
    shift = truth.mean(axis=0) - points.mean(axis=0)
    for _ in range(5):
        distance, index = tree.query(points + shift, distance_upper_bound=gate_mm)
        near = np.isfinite(distance)
        if not near.any():
            break
        shift = shift + (truth[index[near]] - (points[near] + shift)).mean(axis=0)
    return shift


#: Reflections and turns of the axes a submission may have been written in (label, diagonal).
FRAMES = (("x negated", (-1, 1, 1)), ("y negated: a y-up frame?", (1, -1, 1)),
          ("z negated", (1, 1, -1)), ("y and z negated: OpenGL axes, y up and z back?", (1, -1, -1)),
          ("x and y negated: turned by 180 degrees about z?", (-1, -1, 1)))


def plausibility(points: np.ndarray, truth: np.ndarray, gate_mm: float, units=None) -> list:
    """Warnings (text, without the file) about a submission ``points`` (N, 3) mm scored against
    the targets ``truth`` (M, 3) visible in both views: the likely cause when another scale
    (metres), a reflection of the axes or a rigid shift lays the points on the targets
    markedly better than as given, and repeated points. Empty when plausible."""
    from scipy.spatial import cKDTree

    warnings = []
    points = np.asarray(points, dtype=np.float64)
    if len(points) > 1:
        pairs = cKDTree(points).query_pairs(DUPLICATE_MM, output_type="ndarray")
        repeats = np.unique(pairs.max(axis=1)).size if len(pairs) else 0
        if repeats:
            warnings.append(f"{repeats} points repeat another point (within {DUPLICATE_MM:g} mm): "
                            f"the same match written twice?")
    if len(truth) == 0 or len(points) == 0:
        return warnings
    sample = points[::max(1, -(-len(points) // PLAUSIBILITY_POINTS))]
    tree = cKDTree(truth)
    given = _fit(sample, truth, gate_mm)
    candidates = []
    if units != "m":
        candidates.append(("looks like metres (pass --units m)", sample * 1000.0, None))
    else:
        candidates.append(("looks like millimetres already (drop --units m)", sample / 1000.0,
                           None))
    candidates += [(f"looks reflected ({label})", sample * np.array(diagonal, float), None)
                   for label, diagonal in FRAMES]
    shift = _rigid_shift(sample, truth, tree, gate_mm)
    candidates.append((f"looks offset by a rigid shift of ({shift[0]:+.1f}, {shift[1]:+.1f}, "
                       f"{shift[2]:+.1f}) mm (another origin or frame?)", sample + shift, shift))
    best = None
    for label, moved, moved_by in candidates:
        count, rms = _fit(moved, truth, gate_mm)
        more = count >= given[0] + max(2, 0.05 * len(sample))
        closer = count >= given[0] and count > 0 and rms < 0.5 * given[1]
        if moved_by is not None:
            # a frame's offset moves a cloud whole: the shift is large against the gate and
            # the residual, and the shifted points lie on the targets (a wrong model, such as
            # ignoring the port, is shifted too but not laid on them)
            size = float(np.linalg.norm(moved_by))
            if size < gate_mm / 4 or size < 5 * rms or rms > gate_mm / 4:
                continue
        if (more or closer) and (best is None or (count, -rms) > (best[1], -best[2])):
            best = (label, count, rms)
    if best is not None:
        label, count, rms = best
        as_given = (f"{given[0]}, RMS {given[1]:.3g} mm" if given[0] else "none")
        warnings.insert(0, f"{label}: moved so, {count} of {len(sample)} points lie within "
                           f"{gate_mm:g} mm of a target, RMS {rms:.3g} mm (as given: {as_given})")
    return warnings


def main(args) -> int:
    from measure import triangulate
    from synth.dataset import DatasetError, read_dataset
    from synth.fileio import OutputDir, atomic_write_json, atomic_write_text, jsonable

    from eval.core.analytic import visible_targets
    from eval.core.cloud_metrics import write_error_ply
    from eval.core.figures import error_maps_figure, histograms_figure

    log = lambda text: print(text, file=sys.stderr, flush=True)  # noqa: E731
    start = time.perf_counter()
    if args.points and args.method is not None:
        raise CLIError("--method does not apply with --points: your points are scored as they "
                       "are (--method triangulates --pixels)")
    if args.pixels and args.units is not None:
        raise CLIError("--units does not apply with --pixels: the pairs are triangulated here, "
                       "in mm (--units is the unit of --points)")
    method = args.method or "optical_path"
    output = OutputDir(args.out, COMMAND).claim()
    try:
        data = read_dataset(args.dataset)
    except DatasetError as exc:
        raise CLIError(str(exc)) from None
    if data.is_surface:
        raise CLIError(f"{args.dataset}: a surface dataset (per-pixel truth maps, no targets); "
                       f"eval score scores target datasets")
    if args.points:
        units = args.units or "mm"
        points = read_points(args.points) * UNITS[units]
        label, source = "theirs", {"points": os.path.abspath(args.points), "units": units}
    else:
        pairs = read_pixel_pairs(args.pixels)
        result = triangulate(data.rig, pairs[:, :2], pairs[:, 2:], method)
        if not result.valid.any():
            raise CLIError(f"--pixels {args.pixels}: no pair triangulates with {method} "
                           f"and the dataset's calibration")
        points = result.points[result.valid]
        label = method
        source = {"pixels": os.path.abspath(args.pixels), "method": method,
                  "pairs": int(len(pairs)), "invalid": int((~result.valid).sum())}
    radius = float(data.manifest["scene"].get("target_radius_mm", 0.0))
    inside = [visible_targets(camera, data.rig.port, data.targets, radius)[1]
              for camera in (data.rig.left, data.rig.right)]
    visible_both = inside[0] & inside[1]
    seed = int(data.manifest.get("seed", 0))
    gate = default_gate_mm(data.targets) if args.gate_mm is None else args.gate_mm
    warnings = plausibility(points, data.targets[visible_both], gate,
                            units=source.get("units"))
    if warnings:  # one line naming the likely cause; scored as given all the same
        what = f"--points {args.points}" if args.points else f"--pixels {args.pixels}"
        log(f"warning: {what}: " + "; ".join(warnings))
    scores, arrays, association = score_points(points, data.targets, visible_both, gate, seed)
    report = {"dataset": os.path.abspath(data.path), "source": source, "seed": seed,
              "targets": int(len(data.targets)), "association": association,
              "warnings": warnings, "methods": {label: scores.to_json()}}
    with output.staged() as tmp:
        report["ply"] = write_error_ply(tmp, "points_scored.ply", arrays["points"],
                                        arrays["errors"])
        error_maps_figure(os.path.join(tmp, "error_maps.png"), {label: arrays})
        histograms_figure(os.path.join(tmp, "histograms.png"), {label: arrays})
        report["timings_s"] = {"total": time.perf_counter() - start}
        report = jsonable(report)
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        atomic_write_text(os.path.join(tmp, "report.md"), markdown(report))
    st = report["methods"][label]
    a = report["association"]
    summary = (f"{data.path}: {a['associated']} of {a['points']} points within "
               f"{a['gate_mm']:g} mm of a target ({a['unassociated']} not); "
               f"{a['visible_in_both_scored']} of {a['visible_in_both']} targets visible in both "
               f"views scored; RMS dP {fmt(st['rms_dp_mm'])} mm, max dP "
               f"{fmt(st['max_dp_mm'])} mm, mean dZ {fmt(st['mean_dz_mm'])} mm, Chamfer "
               f"{fmt(st['chamfer_mm'])} mm, F@1mm {fmt(st['fscore_1mm'])}")
    if args.json:
        import json

        log(summary)
        print(json.dumps(report, indent=2, allow_nan=False))
    else:
        print(summary)
    print(f"wrote {output.path}", file=sys.stderr if args.json else sys.stdout)
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
             f"{a['gate_mm']:g} mm ({a['unassociated']} not); {a['visible_in_both_scored']} of "
             f"{a['visible_in_both']} targets visible in both views scored. Errors over the "
             f"associated points (mm); Chamfer and F-scores of all points against the targets "
             f"visible in both views.", "",
             "| " + " | ".join(keys) + " |", "|" + "---|" * len(keys),
             "| " + " | ".join(str(st[k]) if k == "n" else fmt(st[k]) for k in keys) + " |"]
    return "\n".join(lines) + "\n"
