"""Closest points of two 3D lines: the common perpendicular (paper equations 11-14)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CommonPerpendicular:
    """Feet of the common perpendicular of lines ``p1 + s1·d1`` and ``p2 + s2·d2``.

    ``foot1``, ``foot2``, ``midpoint``: ``(N, 3)`` (mm); ``length``: ``(N,)`` the distance
    between the lines (mm); ``s1``, ``s2``: ``(N,)`` line parameters (in units of the direction
    vectors' length). Rows with parallel lines are NaN.
    """

    foot1: np.ndarray
    foot2: np.ndarray
    midpoint: np.ndarray
    length: np.ndarray
    s1: np.ndarray
    s2: np.ndarray


def common_perpendicular(p1, d1, p2, d2) -> CommonPerpendicular:
    """Solve ``(L1(s1) − L2(s2))·d1 = 0`` and ``(L1(s1) − L2(s2))·d2 = 0`` (equation 12).

    All inputs broadcast to ``(N, 3)``; vectorized over N line pairs.
    """
    p1, d1, p2, d2 = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (p1, d1, p2, d2)))
    w = p1 - p2
    a = np.einsum("ij,ij->i", d1, d1)
    b = np.einsum("ij,ij->i", d1, d2)
    c = np.einsum("ij,ij->i", d2, d2)
    d = np.einsum("ij,ij->i", d1, w)
    e = np.einsum("ij,ij->i", d2, w)
    denominator = a * c - b * b
    parallel = denominator <= 1e-14 * a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        denominator = np.where(parallel, np.nan, denominator)
        s1 = (b * e - c * d) / denominator
        s2 = (a * e - b * d) / denominator
    foot1 = p1 + s1[:, None] * d1
    foot2 = p2 + s2[:, None] * d2
    return CommonPerpendicular(foot1, foot2, 0.5 * (foot1 + foot2),
                               np.linalg.norm(foot1 - foot2, axis=1), s1, s2)
