"""Point covariances of N cameras' tracks (``eval run`` of a scene of N cameras, ``eval measure``
of one capture of N): the σ of every detection of every track (``--pixel-sigma``), each track's
point covariance (:func:`measure.stereo.multiview_uncertainty.view_point_covariances`), and the
report's ``uncertainty`` entry in the two-camera commands' schema — ``methods``, ``rig``,
``pixel_sigma``, ``summaries.<method>`` (``sigma``; against the truth, where it is known,
``coverage``) and ``files``.

``--pixel-sigma auto`` (default): each detection's σ from the detector (its SNR and size,
:func:`measure.stereo.uncertainty.detection_sigma`) and, for all, the extra σ₀ the tracks'
reprojection residuals show beyond it (:func:`measure.stereo.multiview_uncertainty.
view_residual_sigma`: added noise, render noise on a black background, no truth needed); a
number: that σ, with ``--noise-px`` in quadrature. The rig is taken as exact: a calibration's
covariance of N cameras is not read (the pixels' part only).

Units: px (σ), mm and mm² (points, covariances); frame: the first camera's.
"""

from __future__ import annotations

import numpy as np

#: What the report says of the rig's part of the covariances.
RIG_NOTE = "none: the rig is taken as exact (the pixels' part only)"


def track_sigmas(mode, detections, tracks, noise_px: float = 0.0) -> tuple[np.ndarray, dict]:
    """``((T, V) px, info)``: the σ per coordinate of each track's detection in each view (NaN
    where the view has none) — ``mode`` a number: that σ and ``noise_px`` in quadrature;
    ``auto``: the detector's σ of each detection (the residuals' part is added by
    :func:`views_uncertainty`)."""
    from measure.stereo.uncertainty import detection_sigma

    from eval.core.uncertainty import AUTO

    index = np.asarray(tracks.detections)
    seen = index >= 0
    sigma = np.full(index.shape, np.nan)
    if mode != AUTO:
        sigma[seen] = float(np.hypot(float(mode), noise_px))
        return sigma, {"source": "stated (--pixel-sigma)", "stated_px": float(mode),
                       "added_noise_px": noise_px}
    for v, found in enumerate(detections):
        rows = seen[:, v]
        sigma[rows, v] = detection_sigma(found)[index[rows, v]]
    finite = sigma[np.isfinite(sigma)]
    return sigma, {"source": "detector (SNR and size) + reprojection residuals",
                   "detector_median_px": float(np.median(finite)) if finite.size else None}


def views_uncertainty(mode, noise_px, rig, detections, tracks, pixels, result, method: str,
                      scored=None, rig_differs=None) -> tuple[np.ndarray, dict]:
    """``(covariances (T, 3, 3) mm², report entry)`` of the tracks' points ``result``
    (:class:`measure.stereo.multiview.MultiViewTriangulation`) triangulated from ``pixels``
    ``(T, V, 2)``; ``scored`` the tracks against the truth (``ok``, ``errors``) for the
    coverage, None without truth (every valid point summarized); ``rig_differs`` what of the
    measurement's rig differs from the truth (names; an understated σ's verdict puts it down to
    that first, as the pair's does). Module docs for σ."""
    from measure.stereo.multiview_uncertainty import view_point_covariances, view_residual_sigma

    from eval.core.uncertainty import AUTO

    views = rig.views()
    sigma, info = track_sigmas(mode, detections, tracks, noise_px)
    if mode == AUTO:
        ok = result.valid
        found = view_residual_sigma(views, pixels[ok], result.points[ok],
                                    np.nan_to_num(sigma[ok]))
        sigma0 = found["sigma0_px"] or 0.0
        sigma = np.sqrt(np.nan_to_num(sigma) ** 2 + sigma0 ** 2)
        sigma[~np.all(np.isfinite(pixels), axis=2)] = np.nan
        sigma[sigma == 0] = np.nan  # exact pixels and a noise-free background: no σ
        info.update(residual_sigma0_px=found["sigma0_px"],
                    rms_residual_px=found["rms_residual_px"])
    finite = sigma[np.isfinite(sigma)]
    info.update(median_px=float(np.median(finite)) if finite.size else None,
                max_px=float(finite.max()) if finite.size else None)
    _, covariance = view_point_covariances(views, pixels, sigma)
    return covariance, {"methods": [method], "rig": RIG_NOTE, "pixel_sigma": info,
                        "summaries": {method: _summary(covariance, result, scored, rig_differs)}}


def add_method(entry, method: str, covariance, result, scored=None, rig_differs=None) -> None:
    """Another method's points ``result`` of the same tracks into ``entry``
    (:func:`views_uncertainty`'s): the same covariances — they hold the pixels and their σ
    only, to first order those of every consistent estimator of the point (the optical path
    and the reprojection-optimal point, as for two views) — summarized against its own
    errors (``scored``)."""
    entry["methods"].append(method)
    entry["summaries"][method] = _summary(covariance, result, scored, rig_differs)


def _summary(covariance, result, scored, rig_differs) -> dict:
    """One method's ``summaries`` entry: σ of its reported points and, with ``scored``, the
    coverage and its verdict."""
    from eval.core.uncertainty import uncertainty_summary

    ok = _reported(result, covariance, scored)
    summary = uncertainty_summary(covariance[ok],
                                  None if scored is None else scored["errors"][ok],
                                  rig_differs=rig_differs)
    if not rig_differs:
        _name_what_n_views_miss(summary.get("coverage") or {})
    return summary


def _reported(result, covariance, scored) -> np.ndarray:
    """The tracks the report and the files hold: triangulated (with ``scored``: correctly
    matched) and with a finite covariance."""
    ok = result.valid if scored is None else scored["ok"]
    return ok & np.all(np.isfinite(covariance), axis=(1, 2))


def _name_what_n_views_miss(coverage: dict) -> None:
    """An understated σ's verdict (:func:`eval.core.uncertainty.coverage_verdict`) in the words
    of N views: what the pixels' covariance cannot hold."""
    from eval.core.uncertainty import HONEST_COVERAGE

    fraction = coverage.get("coverage_95")
    if not coverage.get("verdict") or fraction is None or fraction >= HONEST_COVERAGE[0]:
        return
    coverage["verdict"] = (
        f"σ understates the errors: {fraction:.3f} of the points inside their 95 % ellipsoid "
        f"(< {HONEST_COVERAGE[0]:.2f}); not in it: an error every view of a target shares (the "
        f"disks' eccentricity with --no-eccentricity, the rig's error with --calib) and the "
        f"noise of the tracks the matcher left out (a --gate-mm tight against the noise keeps "
        f"the tracks whose rays it left close, whose residuals then understate it)")


def write_views_uncertainty(directory, method, result, covariance, scored, entry) -> None:
    """``uncertainty_<method>.ply`` / ``.csv`` of the triangulated tracks — with ``scored``
    the correctly matched ones and their errors —
    (:func:`eval.core.uncertainty.write_uncertainty_files`), their names into
    ``entry["files"][method]``."""
    from eval.core.uncertainty import write_uncertainty_files

    ok = _reported(result, covariance, scored)
    errors = None if scored is None else scored["errors"][ok]
    entry.setdefault("files", {})[method] = write_uncertainty_files(
        directory, method, result.points[ok], covariance[ok], errors)


def uncertainty_lines(report: dict) -> list:
    """The report's covariances in a sentence (report.md and the printed summary); empty
    for a report without them (one from before they were computed)."""
    entry = report.get("uncertainty") or {}
    lines = []
    for method, summary in (entry.get("summaries") or {}).items():
        sigma = summary.get("sigma") or {}
        coverage = summary.get("coverage") or {}
        if not sigma.get("n"):
            continue
        text = (f"{method}: point σ_P median {sigma['median_sigma_p_mm']:.4f} mm, largest "
                f"{sigma['max_sigma_p_mm']:.4f} mm (pixel σ median "
                f"{entry['pixel_sigma']['median_px']:.3f} px; {entry['rig']})")
        if coverage.get("coverage_95") is not None:
            text += (f"; {100 * coverage['coverage_95']:.1f} % of {coverage['n']} correct "
                     f"points inside their 95 % ellipsoid")
        if coverage.get("verdict"):
            text += f" — {coverage['verdict']}"
        lines.append(text)
    return ["", *lines] if lines else []


__all__ = ["RIG_NOTE", "add_method", "track_sigmas", "uncertainty_lines", "views_uncertainty",
           "write_views_uncertainty"]
