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
    """Row-wise cross product of ``(N, 3)`` arrays (faster than ``np.cross`` for N rows)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def common_perpendicular(p1, d1, p2, d2) -> CommonPerpendicular:
    """Solve ``(L1(s1) − L2(s2))·d1 = 0`` and ``(L1(s1) − L2(s2))·d2 = 0`` (equation 12).

    With ``w = p1 − p2``: ``s1 = (b e − c d) / Δ``, ``s2 = (a e − b d) / Δ`` where ``a = d1·d1``,
    ``b = d1·d2``, ``c = d2·d2``, ``d = d1·w``, ``e = d2·w``. The determinant is computed as
    ``Δ = |d1 × d2|²`` (equal to ``a c − b²`` by Lagrange's identity), which keeps full precision
    for nearly parallel rays where ``a c − b²`` cancels. All inputs broadcast to ``(N, 3)``.
    """
    p1, d1, p2, d2 = (np.asarray(v, dtype=np.float64) for v in (p1, d1, p2, d2))
    n_rows = max(v.shape[0] if v.ndim == 2 else 1 for v in (p1, d1, p2, d2))
    d1 = np.broadcast_to(d1, (n_rows, 3))
    d2 = np.broadcast_to(d2, (n_rows, 3))
    w = np.broadcast_to(p1 - p2, (n_rows, 3))
    n = _cross(d1, d2)
    determinant = _dot(n, n)
    a, b, c = _dot(d1, d1), _dot(d1, d2), _dot(d2, d2)
    d, e = _dot(d1, w), _dot(d2, w)
    parallel = ~(determinant > 1e-28 * a * c)
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = np.where(parallel, np.nan, 1.0 / determinant)
        s1 = (b * e - c * d) * inverse
        s2 = (a * e - b * d) * inverse
    foot1 = p1 + s1[:, None] * d1
    foot2 = p2 + s2[:, None] * d2
    gap = foot1 - foot2
    return CommonPerpendicular(foot1, foot2, 0.5 * (foot1 + foot2), np.sqrt(_dot(gap, gap)), s1, s2)
