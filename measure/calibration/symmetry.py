"""A board that looks the same turned (a chessboard of odd × odd or even × even squares, ROS's
8 × 6 inner corners; :meth:`measure.calibration.board.Board.symmetries`): one photo numbers its
corners in one of the turns, and two cameras of a rig may number one pose differently. One
camera does not care (each photo has its own pose). A rig settles it by its consistency: the
turn that makes a pose agree with the rig is the board's.

In air (:func:`settle_in_air`): each candidate turn of the right camera's board pose gives
that pose's own stereo pose; the medoid of the poses' stereo poses as numbered by the
detector (the one with the smallest median distance to the others: most poses are numbered
alike by both cameras) is the rig's stereo pose, and each pose keeps the turn whose stereo pose
lies nearest it (a wrong turn is off by the turn's angle about the board's normal).
Underwater (:func:`settle_by_rig`): the board's pose from
the left camera's corners (``cv2.solvePnP``, the port ignored: a wrong turn moves the corners
by the board's size) predicts the right camera's corners through the rig; each pose keeps the
turn that predicts them best.

Frames and units as in :mod:`measure.calibration.board`: board poses ``(R, t)`` map board to
camera (or reference) coordinates, mm.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from .board import MIN_CORNERS, Board


def turned_pose(R, t, symmetry):
    """The board pose ``(R, t)`` of a photo whose corners are numbered by ``symmetry`` ``(ids,
    R_s, t_s)`` of :meth:`Board.symmetries`: corner ``i`` is the board's ``ids[i]`` at
    ``R_s X_i + t_s``, so ``R' = R R_sᵀ`` and ``t' = t − R' t_s``."""
    _, R_s, t_s = symmetry
    R_new = np.asarray(R) @ R_s.T
    return R_new, np.asarray(t, np.float64) - R_new @ t_s


def relabelled(detections, view: int, turns: dict, board: Board):
    """``detections`` (:class:`measure.calibration.air.Detections`) with view ``view`` of each
    pose ``k`` in ``turns`` ``{k: symmetry index}`` renumbered by that symmetry."""
    symmetries = board.symmetries()
    ids = [list(v) for v in detections.ids]
    for k, s in turns.items():
        if s:
            ids[k][view] = symmetries[s][0][np.asarray(ids[k][view], int)]
    return type(detections)(ids, [list(v) for v in detections.pixels])


def settle_in_air(board: Board, left: dict, right: dict) -> dict:
    """``{pose: symmetry index}`` of the right camera's numbering that agrees with the rig
    (module docs), from each camera's board poses ``{pose: (R, t)}`` (board to camera, from
    its own calibration) of the poses both saw."""
    symmetries = board.symmetries()
    both = [k for k in left if k in right]
    if len(symmetries) == 1 or len(both) < 2:
        return {k: 0 for k in both}
    rotations, translations, owner = [], [], []
    for k in both:
        R_l, t_l = left[k]
        for s, symmetry in enumerate(symmetries):
            R_r, t_r = turned_pose(*right[k], symmetry)
            R = R_r @ R_l.T
            rotations.append(R)
            translations.append(t_r - R @ t_l)
            owner.append((k, s))
    rotations, translations = np.asarray(rotations), np.asarray(translations)
    angles = Rotation.from_matrix(np.einsum("pij,qkj->pqik", rotations, rotations)
                                  .reshape(-1, 3, 3)).magnitude().reshape(len(owner), -1)
    gaps = np.linalg.norm(translations[:, None] - translations[None], axis=2)
    scale = max(float(np.median(np.linalg.norm(translations, axis=1))), 1e-9)
    distance = angles + gaps / scale  # radians and baselines: both about one at a wrong turn
    # the rig's pose: the medoid of the numberings as found (most poses are numbered alike in
    # both cameras; boards facing the rig alike make each wrong turn a tight cluster too)
    found = [i for i, (_, s) in enumerate(owner) if s == 0]
    medoid = found[int(np.argmin(np.median(distance[np.ix_(found, found)], axis=1)))]
    best = {}
    for i, (k, s) in enumerate(owner):
        if k not in best or distance[i, medoid] < distance[best[k][1], medoid]:
            best[k] = (s, i)
    return {k: s for k, (s, _) in best.items()}


def settle_by_rig(rig, board: Board, detections) -> dict:
    """``{pose: symmetry index}`` of the right view's numbering that the rig ``rig`` (a
    :class:`measure.Rig` of two, its in-air cameras) predicts best from the left view's corners
    (module docs); poses without both views are left out."""
    symmetries = board.symmetries()
    corners = board.corners()
    left, right = rig.left, rig.right
    turns = {}
    for k in range(detections.n_poses):
        ids_l, ids_r = detections.ids[k][0], detections.ids[k][1]
        if len(ids_l) < MIN_CORNERS or len(ids_r) < MIN_CORNERS or len(symmetries) == 1:
            continue
        ok, rvec, tvec = cv2.solvePnP(corners[ids_l], detections.pixels[k][0], left.K,
                                      left.brown_conrady_dist("the board's turn"),
                                      flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            continue
        R_board = left.R @ Rotation.from_rotvec(rvec.ravel()).as_matrix()
        t_board = left.R @ tvec.ravel() + left.t
        errors = []
        for ids, _, _ in symmetries:
            points = corners[ids[ids_r]] @ R_board.T + t_board          # reference frame
            in_right = (points - right.t) @ right.R                      # right camera frame
            predicted = cv2.projectPoints(in_right, np.zeros(3), np.zeros(3), right.K,
                                          right.brown_conrady_dist("the board's turn"))[0]
            errors.append(float(np.median(np.linalg.norm(
                predicted.reshape(-1, 2) - detections.pixels[k][1], axis=1))))
        turns[k] = int(np.argmin(errors))
    return turns


__all__ = ["relabelled", "settle_by_rig", "settle_in_air", "turned_pose"]
