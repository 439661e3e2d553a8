"""Typed results shared by every ``eval`` command (a leaf module: it imports nothing of ``eval``).

Conventions, once for every field below: errors are *measured − true*, in millimetres, in the
reference frame (the left camera's, OpenCV axes: x right, y down, z forward); ``dP`` is the
length of the error vector. Statistics leave out rows with no answer (NaN) and count them.

In JSON every statistic is one flat key with its unit: ``n``, ``n_invalid`` and, for each
component ``c`` in ``dx, dy, dz, dp``, ``mean_c_mm``, ``std_c_mm``, ``sem_c_mm``, ``rms_c_mm``,
``min_c_mm``, ``max_c_mm``, ``max_abs_c_mm`` — the same schema in ``eval run`` and ``eval paper``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from synth.infra.fileio import jsonable

#: How people read the method names, in tables and figures.
METHOD_LABELS = {"optical_path": "optical_path (Li et al.)", "su": "su (Su et al.)",
                 "regular": "regular (port ignored)", "regular_in_air": "regular, all-air rig"}
#: Error components, in order: their JSON key part and their label.
COMPONENTS = (("dx", "dX"), ("dy", "dY"), ("dz", "dZ"), ("dp", "dP"))


def method_label(method: str) -> str:
    return METHOD_LABELS.get(method, method)


@dataclass(frozen=True)
class ComponentStats:
    """One error component over the finite rows. Every ``*_mm`` field is in millimetres; NaN
    when there is no finite row. ``sem_mm`` = ``std_mm / sqrt(n)`` (sample std, ddof 1)."""

    n: int
    n_invalid: int
    mean_mm: float
    std_mm: float
    sem_mm: float
    rms_mm: float
    min_mm: float
    max_mm: float
    max_abs_mm: float

    @classmethod
    def of(cls, values) -> ComponentStats:
        values = np.asarray(values, dtype=np.float64).ravel()
        finite = values[np.isfinite(values)]
        n = int(finite.size)
        if n == 0:
            nan = float("nan")
            return cls(0, int(values.size), nan, nan, nan, nan, nan, nan, nan)
        std = float(np.std(finite, ddof=1)) if n > 1 else 0.0
        return cls(n, int(values.size - n), float(finite.mean()), std, std / float(np.sqrt(n)),
                   float(np.sqrt(np.mean(finite ** 2))), float(finite.min()), float(finite.max()),
                   float(np.abs(finite).max()))


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of 3D errors ``(..., 3)`` mm: ``dx``, ``dy``, ``dz`` and ``dp`` (length).

    ``n`` rows with an answer, ``n_invalid`` rows that are NaN (no answer)."""

    n: int
    n_invalid: int
    dx: ComponentStats
    dy: ComponentStats
    dz: ComponentStats
    dp: ComponentStats

    @classmethod
    def of(cls, errors) -> ErrorStats:
        flat = np.asarray(errors, dtype=np.float64).reshape(-1, 3)
        valid = np.all(np.isfinite(flat), axis=1)
        parts = [ComponentStats.of(flat[valid, k]) for k in range(3)]
        parts.append(ComponentStats.of(np.linalg.norm(flat[valid], axis=1)))
        return cls(int(valid.sum()), int((~valid).sum()), *parts)

    def component(self, name: str) -> ComponentStats:
        """``"dX"``/``"dx"`` … ``"dP"``/``"dp"`` → its statistics."""
        return getattr(self, name.lower())

    def to_json(self) -> dict:
        """The flat JSON schema (see module docs); NaN stays NaN (``jsonable`` makes it null)."""
        out = {"n": self.n, "n_invalid": self.n_invalid}
        for key, _ in COMPONENTS:
            stats = asdict(getattr(self, key))
            for field_name in ("mean", "std", "sem", "rms", "min", "max", "max_abs"):
                out[f"{field_name}_{key}_mm"] = stats[f"{field_name}_mm"]
        return out


@dataclass(frozen=True)
class MethodScores:
    """How one triangulation method did. ``errors``: per-target error statistics over the
    correctly matched targets (mm); ``cloud``: Open3D cloud distances (Chamfer mm, precision /
    recall / F-score at 1 and 5 mm); ``alignment``: the errors left after the best rigid
    alignment (mm, degrees); ``flatness``: RMS and peak-to-valley distance to the fitted plane
    (mm); ``invalid``: matched pairs with no triangulation; ``lengths``: the relative errors of
    the distances between target pairs (:func:`eval.core.cloud_metrics.length_errors`)."""

    errors: ErrorStats
    cloud: dict
    alignment: dict
    flatness: dict
    invalid: int
    lengths: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        flat = {k: v for k, v in self.flatness.items() if k != "plane"}
        return {**self.errors.to_json(), **self.cloud, **self.alignment, **flat,
                "plane": self.flatness.get("plane"), "invalid": self.invalid, **self.lengths}


__all__ = ["COMPONENTS", "ComponentStats", "ErrorStats", "METHOD_LABELS", "MethodScores",
           "jsonable",
           "method_label"]
