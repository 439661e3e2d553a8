"""Reason codes for rows of a batch that have no answer (their values are NaN)."""

from enum import IntEnum


class Reason(IntEnum):
    """Why a row of a vectorized result is NaN. ``OK`` rows are valid."""

    OK = 0
    INVALID_INPUT = 1  # NaN or infinite input pixel / point
    MISSES_PORT = 2  # the ray runs parallel to or away from an interface
    TOTAL_INTERNAL_REFLECTION = 3  # no refracted ray at some interface
    PARALLEL_RAYS = 4  # the two rays of a stereo pair are parallel: no common perpendicular
    BEHIND_CAMERA = 5  # the solution lies behind a camera / on the wrong side of the port
    NOT_IN_WATER = 6  # a point to project is not beyond the port's last interface
    NOT_CONVERGED = 7  # an iterative solver did not reach its tolerance
    TOO_FEW_VIEWS = 8  # a target seen (and traced) by fewer than two views: not triangulated
    TOO_FEW_POINTS = 9  # a pose from fewer than four observations or three object points
    DEGENERATE = 10  # the data do not fix the answer (collinear points, a singular normal matrix)
