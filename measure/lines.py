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


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def common_perpendicular(p1, d1, p2, d2) -> CommonPerpendicular:
    """Solve ``(L1(s1) − L2(s2))·d1 = 0`` and ``(L1(s1) − L2(s2))·d2 = 0`` (equation 12).

    Written with the cross product ``n = d1 × d2`` (``s1 = ((p2 − p1) × d2)·n / |n|²``,
    ``s2 = ((p2 − p1) × d1)·n / |n|²``), which keeps full precision for nearly parallel rays
    where the textbook ``a c − b²`` loses digits. All inputs broadcast to ``(N, 3)``.
    """
    p1, d1, p2, d2 = (np.asarray(a, dtype=np.float64) for a in (p1, d1, p2, d2))
    n = _cross(d1, d2)
    w = p2 - p1
    denominator = np.einsum("ij,ij->i", n, n)
    parallel = ~(denominator > 1e-28 * np.einsum("ij,ij->i", d1, d1) * np.einsum("ij,ij->i", d2, d2))
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = np.where(parallel, np.nan, 1.0 / denominator)
        s1 = np.einsum("ij,ij->i", _cross(w, d2), n) * inverse
        s2 = np.einsum("ij,ij->i", _cross(w, d1), n) * inverse
    foot1 = p1 + s1[:, None] * d1
    foot2 = p2 + s2[:, None] * d2
    return CommonPerpendicular(foot1, foot2, 0.5 * (foot1 + foot2),
                               np.linalg.norm(foot1 - foot2, axis=1), s1, s2)
