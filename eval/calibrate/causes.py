"""What a housing calibration that found no housing says about why: the likely causes a user
can act on, named beside the adjustment's own reason — the in-air calibration of another
camera or rig (``--intrinsics``), swapped folders, or a design port far from this housing
(water with the index of air, ``--n-water 1.0``, bends no ray at the water)."""

from __future__ import annotations

import numpy as np

from eval.cli import CLIError

#: The errors of an adjustment that found no housing: a port moved behind a camera during the
#: fit (``ValueError`` from the port's check), singular normal equations.
FIT_ERRORS = (ValueError, np.linalg.LinAlgError)


def likely_causes(args) -> str:
    """The causes to check, in the order a user should (the ``--intrinsics`` file first)."""
    causes = []
    if getattr(args, "intrinsics", None):
        causes.append(f"--intrinsics {args.intrinsics} is the in-air calibration of another "
                      f"camera or rig, or of these cameras in another order (swapped folders)")
    n_water = getattr(args, "n_water", None)
    try:
        index = float(n_water) if n_water is not None else None
    except (TypeError, ValueError):
        index = None
    if index is not None and index < 1.05:
        causes.append(f"--n-water {index:g} is no water (the index of air bends no ray at the "
                      f"water, so the port's distance is not determined)")
    else:
        causes.append("the design port (--start-distance, --glass-thickness, --n-glass, "
                      "--n-water) is far from this housing")
    return "; ".join(causes)


def housing_failure(where: str, reason, args, what: str = "photograph") -> CLIError:
    """The one line of a housing calibration that found no housing (exit 2): ``where`` (the
    folder), the adjustment's ``reason`` (text, or the exception it raised) and
    :func:`likely_causes`; nothing is written. Two parameters the boards cannot tell apart
    (a correlation) keep their own cure: free fewer, or ``what`` more varied poses."""
    reason = " ".join(str(reason).split()) or "the adjustment failed"
    cure = f"free fewer parameters with --free, or {what} more varied poses"
    if "correlated at" in reason:
        return CLIError(f"{where}: {reason}; nothing written ({cure})")
    if reason.startswith("Singular matrix"):
        reason = "the boards do not determine the housing (singular normal equations)"
    elif "lies on the water side" in reason:  # the port check of a camera, mid-adjustment
        reason = ("the adjustment moved the port behind a camera: it found no housing that fits "
                  "the corners")
    return CLIError(f"{where}: {reason} — likely: {likely_causes(args)} (or {cure}); "
                    f"nothing written")


__all__ = ["FIT_ERRORS", "housing_failure", "likely_causes"]
