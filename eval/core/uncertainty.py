"""Point covariances in the commands' outputs (``eval run``, ``eval measure``, ``eval score``):
the pixel σ of each matched pair (``--pixel-sigma``), the covariances of every method's points
(:mod:`measure.stereo.uncertainty`), their report summaries, the coverage against the truth, and the
files (``uncertainty_<method>.ply`` / ``.csv``).

Units: mm (points, σ), mm² (covariances), px (pixel σ); frame: the reference frame.
"""

from __future__ import annotations

import csv
import io
import os

import numpy as np

from synth.infra.cli import CLIError
from measure.stereo.uncertainty import (MINOR_AXIS_EXPONENT, coverage_summary, detection_sigma,
                                        elongated_pixel_covariance, mahalanobis_squared,
                                        point_covariances, point_covariances_full,
                                        residual_sigma, sigma_summary)
from synth.infra.fileio import atomic_write_bytes, atomic_write_text

#: ``--pixel-sigma``'s default: each detection's σ from the detector (SNR and size) plus what
#: the reprojection residuals show beyond it (:func:`measure.stereo.uncertainty.residual_sigma`).
AUTO = "auto"
#: Columns of ``uncertainty_<method>.csv`` (and properties of the PLY file, in this order);
#: the truth columns only where the truth is known.
COLUMNS = ("x", "y", "z", "sigma_x", "sigma_y", "sigma_z", "cov_xx", "cov_xy", "cov_xz",
           "cov_yy", "cov_yz", "cov_zz")
TRUTH_COLUMNS = ("dx", "dy", "dz", "mahalanobis2")


def parse_pixel_sigma(text) -> str | float:
    """``--pixel-sigma``: ``auto`` or a positive finite number of pixels."""
    if text is None or str(text).strip().lower() == AUTO:
        return AUTO
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (np.isfinite(value) and value > 0):
        raise CLIError(f"--pixel-sigma {text!r}: expected {AUTO} or a positive number of pixels")
    return value


def add_pixel_sigma_option(parser) -> None:
    """``--pixel-sigma`` (``eval run``, ``eval measure``, ``eval score --pixels``)."""
    parser.add_argument("--pixel-sigma", default=AUTO, metavar="auto|PX",
                        help="σ of a detected centre per coordinate (px) for the points' "
                             "covariances: a number, or auto (default): each target's σ from "
                             "the detector (its SNR and size) plus the noise the reprojection "
                             "residuals show beyond it; on a surface scene the right pixel's σ "
                             "along the epipolar curve (auto: each pixel's from its window and "
                             "the images' noise)")


def pair_sigmas(mode, uv_left, uv_right, start, rig, detections=None, matches=None,
                noise_px: float = 0.0):
    """``((N, 2) px: the σ of each pair's left and right centre, info for report.json)``.

    ``mode`` a number: that σ (the stated σ, with ``noise_px`` — noise the run added — in
    quadrature). :data:`AUTO`: the detector's σ of each detection (``detections`` per view and
    ``matches``' indices; none: 0) and, for every pair, the extra σ₀ the reprojection residuals
    of the ``start`` points show beyond it (added noise included), scaled by the pair's flux
    as the residuals show (:func:`measure.stereo.uncertainty.residual_sigma`: faint — small,
    oblique, far — targets' centres scatter more); with the detections' shapes the answer is
    the ``(N, 4, 4)`` px² covariance of each pair's four coordinates instead, that σ along each
    ellipse's major axis and σ · elongation^k across it
    (:func:`measure.stereo.uncertainty.elongated_pixel_covariance`)."""
    n = len(uv_left)
    if mode != AUTO:
        sigma = np.full((n, 2), float(np.hypot(float(mode), noise_px)))
        return sigma, {"source": "stated (--pixel-sigma)", "stated_px": float(mode),
                       "added_noise_px": noise_px, "median_px": float(sigma[0, 0]) if n else None}
    detector = np.zeros((n, 2))
    flux = shape = None
    if detections is not None and matches is not None:
        light = np.ones(n)
        shape = (np.ones((n, 2)), np.zeros((n, 2)))
        for k, (view, index) in enumerate((("left", matches.left), ("right", matches.right))):
            detector[:, k] = detection_sigma(detections[view])[index]
            light = light * np.asarray(detections[view].flux, dtype=np.float64)[index]
            if getattr(detections[view], "orientation", None) is None:
                shape = None
            elif shape is not None:
                shape[0][:, k] = np.asarray(detections[view].elongation)[index]
                shape[1][:, k] = np.asarray(detections[view].orientation)[index]
        flux = np.sqrt(light)
    found = residual_sigma(rig, uv_left, uv_right, start, detector, flux=flux)
    sigma0 = found["sigma0_px"] or 0.0
    weights = found.get("weights")
    weights = np.ones(n) if weights is None else np.where(np.isfinite(weights), weights, 1.0)
    sigma = np.sqrt(detector ** 2 + (sigma0 * weights[:, None]) ** 2)
    if n and not np.all(sigma > 0):  # exact pixels and a noise-free background
        sigma = np.where(sigma > 0, sigma, np.nan)
    finite = sigma[np.isfinite(sigma)]
    anisotropy = None
    if shape is not None and n:
        anisotropy = {"minor_axis_exponent": MINOR_AXIS_EXPONENT,
                      "note": "across each ellipse's minor axis σ · elongation^k",
                      "median_elongation": float(np.median(shape[0]))}
        sigma = elongated_pixel_covariance(sigma, *shape)
    return sigma, {"source": "detector (SNR and size) + reprojection residuals"
                             + (" + the ellipses' elongation" if anisotropy else ""),
                   "anisotropy": anisotropy,
                   "detector_median_px": float(np.median(detector)) if n else None,
                   "residual_sigma0_px": found["sigma0_px"],
                   "flux_exponent": found.get("flux_exponent"),
                   "rms_residual_px": found["rms_residual_px"],
                   "median_px": float(np.median(finite)) if finite.size else None,
                   "max_px": float(finite.max()) if finite.size else None}


def method_covariances(rig, points_by_method: dict, sigma, rig_covariance=None) -> dict:
    """``{method: PointCovariance}`` of each method's points ``(N, 3)`` (NaN rows stay NaN) with
    the pairs' ``sigma`` ``(N, 2)``."""
    if np.ndim(sigma) == 3:  # (N, 4, 4): pair_sigmas' covariance of elongated detections
        return {m: point_covariances_full(rig, points, sigma, rig_covariance)
                for m, points in points_by_method.items()}
    return {m: point_covariances(rig, points, sigma, rig_covariance)
            for m, points in points_by_method.items()}


def rig_covariance_note(rig_covariance, source: str | None) -> str:
    """The report's sentence on the rig part of the covariances."""
    if rig_covariance is not None:
        return (f"pixel noise and the rig covariance of {source} ({len(rig_covariance.names)} "
                f"parameters)")
    if source:
        return f"{source} holds no covariance: the points carry the pixel-noise part only"
    return "the rig is taken as exact (no calibration file): the pixel-noise part only"


def uncertainty_summary(covariance, errors=None, dof: int = 3, rig_differs: dict | None = None
                        ) -> dict:
    """A method's ``report.json`` entry: :func:`measure.stereo.uncertainty.sigma_summary` and, with
    ``errors`` (N, 3) mm (measured − true, the same rows), the coverage and normalized errors
    (:func:`measure.stereo.uncertainty.coverage_summary`, ``dof`` the dimensions the errors span).
    ``rig_differs``: how the measurement's rig differs from the truth (its verdict names it)."""
    out = {"sigma": sigma_summary(covariance)}
    if errors is not None:
        out["coverage"] = coverage_summary(errors, covariance, dof)
        verdict = coverage_verdict(out["coverage"], rig_differs)
        if verdict:
            out["coverage"]["verdict"] = verdict
    return out


#: The range of ``coverage_95`` an honest σ gives (0.95 expected; outside it the report says so)
#: and the fewest points a verdict needs (binomial σ of the fraction ≤ 0.04 from 30 points).
HONEST_COVERAGE, VERDICT_MIN_POINTS = (0.90, 0.98), 30


def coverage_verdict(coverage: dict, rig_differs: dict | None = None) -> str:
    """A sentence when ``coverage_95`` is outside :data:`HONEST_COVERAGE` (with at least
    :data:`VERDICT_MIN_POINTS` points), else ``""``: the σ understated or overstated the error.
    When the measurement's rig differs from the truth (``rig_differs``, e.g. ``--assume``) an
    understated σ is put down to that first: every point shares the rig's error."""
    fraction, n = coverage.get("coverage_95"), coverage.get("n") or 0
    if fraction is None or n < VERDICT_MIN_POINTS:
        return ""
    if fraction < HONEST_COVERAGE[0] and rig_differs:
        return (f"σ understates the errors: {fraction:.3f} of the points inside their 95 % "
                f"ellipsoid (< {HONEST_COVERAGE[0]:.2f}); the measurement's rig differs from "
                f"the truth ({', '.join(sorted(rig_differs))}: --assume or --calib), an error "
                f"every point shares and that σ holds only through a calibration's covariance")
    if fraction < HONEST_COVERAGE[0]:
        return (f"σ understates the errors: {fraction:.3f} of the points inside their 95 % "
                f"ellipsoid (< {HONEST_COVERAGE[0]:.2f}); an error both views share is not in "
                f"it (disk targets: --eccentricity, eval run's default, removes their "
                f"eccentricity)")
    if fraction > HONEST_COVERAGE[1]:
        return (f"σ overstates the errors: {fraction:.3f} of the points inside their 95 % "
                f"ellipsoid (> {HONEST_COVERAGE[1]:.2f}); with a calibration's covariance one "
                f"calibration is one draw of the rig error, shared by every point")
    return ""


def _rows(points, covariance, errors):
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    covariance = np.asarray(covariance, dtype=np.float64).reshape(-1, 3, 3)
    sigma = np.sqrt(np.einsum("nii->ni", covariance))
    upper = covariance[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
    columns = [points, sigma, upper]
    if errors is not None:
        errors = np.asarray(errors, dtype=np.float64).reshape(-1, 3)
        columns += [errors, mahalanobis_squared(errors, covariance)[:, None]]
    return np.concatenate(columns, axis=1)


def write_uncertainty_files(directory, method: str, points, covariance, errors=None) -> dict:
    """``uncertainty_<method>.ply`` (binary little-endian, double properties :data:`COLUMNS`)
    and ``uncertainty_<method>.csv`` (the same columns, and :data:`TRUTH_COLUMNS` with
    ``errors``); returns the report entry."""
    data = _rows(points, covariance, errors)
    names = COLUMNS + (TRUTH_COLUMNS if errors is not None else ())
    header = ("ply\nformat binary_little_endian 1.0\ncomment refractive-stereo point "
              "covariances (mm, mm^2, reference frame)\n"
              f"element vertex {data.shape[0]}\n"
              + "".join(f"property double {c}\n" for c in COLUMNS) + "end_header\n")
    ply = f"uncertainty_{method}.ply"
    atomic_write_bytes(os.path.join(directory, ply), header.encode("ascii") + np.ascontiguousarray(
        data[:, :len(COLUMNS)], dtype="<f8").tobytes())
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(names)
    writer.writerows([[f"{v:.10g}" for v in row] for row in data])
    table = f"uncertainty_{method}.csv"
    atomic_write_text(os.path.join(directory, table), text.getvalue())
    return {"ply": ply, "csv": table, "columns": list(names)}


__all__ = ["AUTO", "COLUMNS", "HONEST_COVERAGE", "TRUTH_COLUMNS", "add_pixel_sigma_option",
           "coverage_verdict", "method_covariances",
           "pair_sigmas", "parse_pixel_sigma", "rig_covariance_note", "uncertainty_summary",
           "write_uncertainty_files"]
