"""The rule that says a board view does not belong with the others: its reprojection RMS far
above theirs (a photo turned or mirrored, blurred, of another board, or of another moment).

:func:`outlier_threshold` of the views' RMS: max(:data:`OUTLIER_FACTOR` × median, median +
:data:`OUTLIER_MADS` × 1.4826 × MAD, median + :data:`OUTLIER_FLOOR_PX`) — MAD the median
absolute deviation (1.4826 × MAD is σ for Gaussian scatter); the floor keeps a set of nearly
equal, very small residuals from shedding views. Units: px.
"""

from __future__ import annotations

import numpy as np

#: The outlier rule (module docs).
OUTLIER_FACTOR, OUTLIER_MADS, OUTLIER_FLOOR_PX = 3.0, 5.0, 0.1


def outlier_threshold(rms_values) -> float:
    """The RMS (px) above which a view is an outlier (module docs); inf for no views."""
    values = np.asarray(list(rms_values), dtype=np.float64)
    if values.size == 0:
        return float("inf")
    median = float(np.median(values))
    mad = float(np.median(np.abs(values - median)))
    return max(OUTLIER_FACTOR * median, median + OUTLIER_MADS * 1.4826 * mad,
               median + OUTLIER_FLOOR_PX)


__all__ = ["OUTLIER_FACTOR", "OUTLIER_FLOOR_PX", "OUTLIER_MADS", "outlier_threshold"]
