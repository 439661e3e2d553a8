"""Lock-on: the first pose of a known rigid set of points from a stereo pair's detections, with
no guess — which detection is which marker is not known.

The detections of both views are matched with the refractive epipolar constraint
(:func:`measure.stereo.matching.match_targets`) and triangulated (the optical path); the known
object points ``(M, 3)`` are then registered to those points, which may hold points of no marker
(spurious detections that matched) and miss markers: every triplet of markers (not near
collinear) paired with every triplet of points whose three distances agree within ``gate_mm``
gives a start (the rigid fit of the three, Kabsch); from each distinct start, rounds of an
optimal one-to-one assignment (:func:`scipy.optimize.linear_sum_assignment`, within
``gate_mm``) and the rigid fit of the assigned pairs. The start whose fit assigns
the most markers with the smallest RMS wins. An object that maps onto itself under a rotation
(the square docking frame under 90° turns) has as many equally good answers: the one whose
rotation is nearest to ``prefer`` (default: the identity — the object upright, as a docking run
knows roughly) is taken, and ``ambiguous`` says how many there were.

Units mm, the reference frame of the rig (the left camera's).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
from scipy.optimize import linear_sum_assignment

from .matching import match_targets
from .rig import Rig
from .triangulate import triangulate

#: Object triplets used as bases: at least this smallest height per longest side (no
#: near-collinear ones, whose rotation about their line is not determined).
MIN_TRIANGLE_HEIGHT = 0.2
#: Assignment-and-fit rounds from each start.
ROUNDS = 10
#: Two answers within this RMS (mm) of each other fit equally well (a symmetric object).
TIE_MM = 1.0


@dataclass(frozen=True)
class LockOn:
    """``R`` ``(3, 3)``, ``t`` ``(3,)``: the pose ``X_ref = R · X_obj + t`` (NaN: none);
    ``pixels`` ``(2, M, 2)``: each marker's detection per view (NaN where none);
    ``assigned`` markers given a triangulated point, ``rms_mm`` of the fit over them,
    ``ambiguous`` how many equally good answers (1: unique), ``reason`` text (None: found)."""

    R: np.ndarray
    t: np.ndarray
    pixels: np.ndarray
    assigned: int
    rms_mm: float
    ambiguous: int
    reason: str | None = None


def kabsch(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` minimizing ``Σ |R · source + t − target|²`` over rotations (no reflection)."""
    cs, ct = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((source - cs).T @ (target - ct))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return R, ct - R @ cs


def _triangles(points: np.ndarray, min_height: float) -> np.ndarray:
    """``(T, 3)`` index triplets ``i < j < k`` of ``points`` whose triangle's smallest height
    is at least ``min_height`` × its longest side (no near-collinear triplets)."""
    i, j, k = np.array(list(combinations(range(len(points)), 3))).T.reshape(3, -1)
    a, b, c = points[i], points[j], points[k]
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    longest = np.max([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - a, axis=1),
                      np.linalg.norm(c - b, axis=1)], axis=0)
    keep = area2 / np.maximum(longest, 1e-300) ** 2 >= min_height
    return np.column_stack([i, j, k])[keep]


def _hypotheses(obj: np.ndarray, pts: np.ndarray, tol_mm: float) -> np.ndarray:
    """``(H, 2, 3)``: pairs of an object triplet and a triplet of points whose three side
    lengths agree within ``tol_mm`` (each ordering of the points' triplet)."""
    d_obj = np.linalg.norm(obj[:, None] - obj[None], axis=2)
    d_pts = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    out = []
    for a, b, c in _triangles(obj, MIN_TRIANGLE_HEIGHT):
        ok_ab = np.abs(d_pts - d_obj[a, b]) <= tol_mm  # (i, j)
        ok_ac = np.abs(d_pts - d_obj[a, c]) <= tol_mm  # (i, k)
        ok_bc = np.abs(d_pts - d_obj[b, c]) <= tol_mm  # (j, k)
        ii, jj, kk = np.nonzero(ok_ab[:, :, None] & ok_ac[:, None, :] & ok_bc[None, :, :])
        distinct = (ii != jj) & (ii != kk) & (jj != kk)
        for i, j, k in zip(ii[distinct], jj[distinct], kk[distinct]):
            out.append(((a, b, c), (i, j, k)))
    return np.array(out, dtype=int).reshape(-1, 2, 3)


def _refine(obj, pts, R, t, gate_mm):
    """Rounds of an optimal one-to-one assignment within ``gate_mm`` and the rigid fit of the
    assigned pairs, from the pose ``(R, t)``: ``(R, t, assignment (M,), assigned, rms_mm)``."""
    assignment = np.full(len(obj), -1)
    for _ in range(ROUNDS):
        moved = obj @ R.T + t
        cost = np.linalg.norm(moved[:, None] - pts[None], axis=2)
        rows, cols = linear_sum_assignment(np.where(cost <= gate_mm, cost, 1e9))
        keep = cost[rows, cols] <= gate_mm
        new = np.full(len(obj), -1)
        new[rows[keep]] = cols[keep]
        if keep.sum() < 3:
            return R, t, new, 0, np.inf
        R, t = kabsch(obj[rows[keep]], pts[cols[keep]])
        if np.array_equal(new, assignment):
            break
        assignment = new
    used = assignment >= 0
    r = obj[used] @ R.T + t - pts[assignment[used]]
    return R, t, assignment, int(used.sum()), float(np.sqrt(np.mean(np.sum(r * r, axis=1))))


def register(object_points, points, gate_mm: float, prefer=None):
    """``(R, t, assignment (M,) index into points or −1, rms_mm, ambiguous)``: the known object
    registered to ``points`` ``(K, 3)`` with an unknown correspondence (module docs); None when
    no three points fit three markers."""
    obj = np.asarray(object_points, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64)
    prefer = np.eye(3) if prefer is None else np.asarray(prefer, dtype=np.float64)
    if len(obj) < 3 or len(pts) < 3:
        return None
    answers, seen = [], []
    for (a, b, c), (i, j, k) in _hypotheses(obj, pts, gate_mm):
        R, t = kabsch(obj[[a, b, c]], pts[[i, j, k]])
        if any(np.linalg.norm(R - S) < 1e-2 and np.linalg.norm(t - u) < gate_mm
               for S, u in seen):
            continue  # a start already tried (the same pose from another triplet)
        seen.append((R, t))
        R, t, assignment, assigned, rms = _refine(obj, pts, R, t, gate_mm)
        if assigned >= 3:
            answers.append((assigned, rms, R, t, assignment))
    if not answers:
        return None
    most = max(a[0] for a in answers)
    best = min(a[1] for a in answers if a[0] == most)
    good = [a for a in answers if a[0] == most and a[1] <= best + TIE_MM]
    distinct = []  # answers that differ in rotation (the same one found from several starts)
    for a in good:
        if all(np.linalg.norm(a[2] - b[2]) > 1e-3 for b in distinct):
            distinct.append(a)
    chosen = min(distinct, key=lambda a: np.linalg.norm(a[2] - prefer))
    return chosen[2], chosen[3], chosen[4], chosen[1], len(distinct)


def lock_on(rig: Rig, object_points, uv_left, uv_right, gate_mm: float = 20.0,
            match_gate_mm: float = 2.0, prefer=None) -> LockOn:
    """The first pose of ``object_points`` ``(M, 3)`` from the detections ``uv_left``
    ``(A, 2)``, ``uv_right`` ``(B, 2)`` of ``rig`` (module docs): ``match_gate_mm`` the
    epipolar gate of the matching, ``gate_mm`` the largest distance of a triangulated point from
    the marker it is given. ``reason`` says why there is none (fewer than 4 markers found)."""
    obj = np.asarray(object_points, dtype=np.float64)
    nan = LockOn(np.full((3, 3), np.nan), np.full(3, np.nan), np.full((2, len(obj), 2), np.nan),
                 0, np.nan, 0)
    uv_left = np.asarray(uv_left, dtype=np.float64).reshape(-1, 2)
    uv_right = np.asarray(uv_right, dtype=np.float64).reshape(-1, 2)
    matches = match_targets(rig, uv_left, uv_right, gate_mm=match_gate_mm)
    if len(matches.left) < 4:
        return LockOn(**{**nan.__dict__, "reason": f"{len(matches.left)} detections matched in "
                                                   f"both views; a lock-on needs 4"})
    found = triangulate(rig, uv_left[matches.left], uv_right[matches.right])
    ok = found.valid
    points = found.points[ok]
    left, right = matches.left[ok], matches.right[ok]
    answer = register(obj, points, gate_mm, prefer)
    if answer is None or (answer[2] >= 0).sum() < 4:
        return LockOn(**{**nan.__dict__, "reason": "the triangulated detections do not fit the "
                                                   "object's shape (fewer than 4 markers)"})
    R, t, assignment, rms, ambiguous = answer
    pixels = np.full((2, len(obj), 2), np.nan)
    used = assignment >= 0
    pixels[0, used] = uv_left[left[assignment[used]]]
    pixels[1, used] = uv_right[right[assignment[used]]]
    return LockOn(R, t, pixels, int(used.sum()), rms, ambiguous)


__all__ = ["LockOn", "kabsch", "lock_on", "register"]
