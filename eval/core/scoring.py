"""Scoring a reconstruction against a target dataset's truth, shared by ``eval score`` on one
dataset and on a whole suite (:mod:`eval.core.suite_scores`): reading the points or pixel pairs
handed in, associating points with targets, the metrics of ``eval run``
(:func:`score_dataset`) and the plausibility check of a submission (metres for millimetres,
another frame, repeated points: :func:`plausibility`)."""

from __future__ import annotations

import csv
import os

import numpy as np

from synth.infra.cli import CLIError

PIXEL_COLUMNS = ("u_left", "v_left", "u_right", "v_right")
#: ``--units`` of ``--points``: millimetres per unit.
UNITS = {"mm": 1.0, "m": 1000.0}
#: Points closer than this to an earlier point count as repeats of it (mm).
DUPLICATE_MM = 1e-6
#: Most points the plausibility check looks at (an evenly spaced subsample beyond).
PLAUSIBILITY_POINTS = 20_000


def mesh_faces(path) -> int:
    """The number of faces a PLY file's header declares (0 for a point cloud or another
    format)."""
    from synth.formats.cloudfile import ply_layout

    if not os.fspath(path).lower().endswith(".ply"):
        return 0
    return sum(int(e["count"]) for e in ply_layout(path, os.fspath(path))["elements"]
               if e["name"] in ("face", "tristrips"))


def read_points(path) -> np.ndarray:
    """``(N, 3)`` float64 points of a point-cloud file, read whole (a truncated file is
    refused: :mod:`synth.formats.cloudfile`); CLIError when unreadable, empty, not finite or a
    mesh (a PLY with faces: its vertices are no measurement)."""
    from synth.formats.cloudfile import CloudFileError, read_cloud_points

    if not os.path.isfile(path):
        raise CLIError(f"--points {path}: no such file")
    try:
        faces = mesh_faces(path)
        if faces:
            raise CLIError(f"--points {path}: a mesh ({faces} faces), not a point cloud: its "
                           f"vertices are not measured points; submit the measured points")
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
    with open(path, newline="", encoding="utf-8-sig") as fh:  # a BOM (Excel's "CSV UTF-8")
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


def unassociated_text(association: dict) -> str:
    """``"N not"`` of an association, with how many of those lie on a target a nearer point
    holds (duplicates: the same match written twice, not points far from every target)."""
    a = association
    far = a["unassociated"] - a.get("duplicates", 0)
    if not a.get("duplicates"):
        return f"{a['unassociated']} not"
    return (f"{a['unassociated']} not: {a['duplicates']} duplicate(s) of a target a nearer point "
            f"holds, {far} farther than {a['gate_mm']:g} mm from every target")


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
    ``truth`` ``(M, 3)``; Chamfer and F-scores against ``truth[visible_both]``. The arrays:
    ``points``, ``truth``, ``errors`` of the associated points, ``all_points`` and
    ``associated`` (bool per point of ``points``)."""
    from eval.core.cloud_metrics import cloud_distances, flatness, length_errors, rigid_alignment
    from eval.core.results import ErrorStats, MethodScores

    target = associate_points(points, truth, gate_mm)
    ok = target >= 0
    errors = points[ok] - truth[target[ok]]
    scores = MethodScores(errors=ErrorStats.of(errors),
                          cloud=cloud_distances(points, truth[visible_both]),
                          alignment=rigid_alignment(points[ok], truth[target[ok]]),
                          flatness=flatness(points, seed=seed), invalid=0,
                          lengths=length_errors(points[ok], truth[target[ok]]))
    arrays = {"points": points[ok], "truth": truth[target[ok]], "errors": errors,
              "all_points": points, "associated": ok}
    from scipy.spatial import cKDTree

    near = (np.isfinite(cKDTree(truth).query(points, distance_upper_bound=gate_mm)[0])
            if len(truth) and len(points) else np.zeros(len(points), dtype=bool))
    association = {"points": int(len(points)), "associated": int(ok.sum()),
                   "unassociated": int((~ok).sum()), "gate_mm": gate_mm,
                   # within the gate of a target a nearer point holds: a match written twice
                   "duplicates": int((~ok & near).sum()),
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


def score_dataset(data, points: np.ndarray, label: str, gate_mm: float | None = None,
                  units: str | None = None) -> tuple[dict, dict, list]:
    """``(report, arrays, warnings)``: ``points`` (N, 3) mm scored against the target dataset
    ``data`` (:class:`synth.products.dataset.Dataset`, or a dataset of N cameras,
    :class:`synth.products.dataset.ViewsDataset`: the targets inside two or more images
    count as visible) as ``eval score`` does — the association, the
    metrics under ``report["methods"][label]``, the plausibility warnings (``units`` of the
    points as given: None or "mm", or "m")."""
    from eval.core.analytic import visible_targets

    radius = float(data.manifest["scene"].get("target_radius_mm", 0.0))
    inside = [visible_targets(camera, data.rig.view_port(view), data.targets, radius)[1]
              for view, camera in enumerate(data.rig.cameras)]
    visible_both = np.sum(inside, axis=0) >= 2  # of two cameras both; of N, two or more
    seed = int(data.manifest.get("seed", 0))
    gate = default_gate_mm(data.targets) if gate_mm is None else gate_mm
    warnings = plausibility(points, data.targets[visible_both], gate, units=units)
    scores, arrays, association = score_points(points, data.targets, visible_both, gate, seed)
    report = {"dataset": os.path.abspath(data.path), "seed": seed,
              "targets": int(len(data.targets)), "association": association,
              "warnings": warnings, "methods": {label: scores.to_json()}}
    return report, arrays, warnings


__all__ = ["DUPLICATE_MM", "FRAMES", "PIXEL_COLUMNS", "PLAUSIBILITY_POINTS", "UNITS",
           "associate_points", "default_gate_mm", "mesh_faces", "plausibility", "read_pixel_pairs",
           "read_points", "score_dataset", "score_points", "unassociated_text"]
