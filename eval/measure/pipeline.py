"""The measurement of one stereo pair without truth: targets (detect, match, triangulate) or a
speckled surface (dense matching, triangulate).

Frames and units: the left camera's frame (OpenCV axes), millimetres, pixels in the OpenCV
convention. Nothing here knows a truth; what is reported is what the images and the
calibration say (counts, the gap of the two water rays, a plane fit).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from eval.core.detection import detect_view
from synth.infra.cli import option_number

#: The methods whose points get a covariance (:mod:`measure.stereo.uncertainty`; as ``eval run``).
COVARIANCE_METHODS = ("optical_path", "reprojection")


@dataclass(frozen=True)
class TargetOptions:
    """How targets are measured: the detector options (None: the detector's defaults; see
    :func:`eval.core.detection.detect_view`), the matching gate (mm) and the depth window
    ``(near, far)`` along the port normal (mm; ``(None, None)``: no bound); ``floor_fraction``
    the automatic threshold's floor (a fraction of the targets' level); ``pixel_sigma`` the
    σ of a detected centre for the points' covariances (``"auto"`` or px:
    :func:`eval.core.uncertainty.pair_sigmas`)."""

    methods: tuple = ("optical_path",)
    gate_mm: float = 0.5
    depth_range: tuple = (None, None)
    threshold_fraction: float | None = None
    max_elongation: float | None = None
    max_area_ratio: float | None = None
    median_filter: int = 0
    floor_fraction: float = 0.0
    pixel_sigma: object = "auto"


@dataclass(frozen=True)
class DenseOptions:
    """How a speckled surface is measured: ``methods`` (``optical_path``: refractive matching
    and the optical-path triangulation; ``regular``: straight rays, the port ignored),
    ``depth_range`` ``(near, far)`` mm along the port normal, ``median_filter`` 0, 3 or 5."""

    methods: tuple = ("optical_path",)
    depth_range: tuple = (0.0, 0.0)
    median_filter: int = 0


@dataclass
class PairResult:
    """One pair measured. ``name``, ``left`` / ``right`` (the images as read), ``counts`` (the
    report's counts), ``uv_left`` / ``uv_right`` ``(M, 2)`` px of the matched pairs (or
    pixels), ``methods`` ``{method: Triangulation}``; targets only: ``detections``
    ``{view: Detections}`` and ``matches``, ``covariances`` ``{method: PointCovariance}`` (one
    row per pair, NaN where invalid) and ``pixel_sigma`` (how the pixel σ was set); ``problem``:
    why nothing was measured (a multi-pair run reports it and goes on), else None; ``failure``:
    why what was measured is not to be trusted (:func:`pair_mismatch`; the run exits 1), else
    None."""

    name: str
    left: np.ndarray
    right: np.ndarray
    counts: dict
    uv_left: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    uv_right: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    methods: dict = field(default_factory=dict)
    detections: dict | None = None
    matches: object = None
    problem: str | None = None
    timings: dict = field(default_factory=dict)
    covariances: dict = field(default_factory=dict)
    pixel_sigma: dict | None = None
    failure: str | None = None


def nothing_matched(name: str, found: dict, options: TargetOptions) -> str:
    """Why a pair gave no match, in words (what to check)."""
    near, far = options.depth_range
    if min(found.values()) == 0:
        cause = ("no target was detected in "
                 f"{' and '.join(v for v in ('left', 'right') if found[v] == 0)}: check the "
                 f"exposure, the detector options (--threshold-fraction) and that the photos "
                 f"show bright targets on a dark background")
    else:
        window = ("no depth window" if near is None else
                  f"the depth window {option_number(near)}-{option_number(far)} mm")
        cause = (f"check that the calibration belongs to these photos (camera order, port, "
                 f"water index), {window} (--depth-range) and --gate-mm {option_number(options.gate_mm)}")
    return (f"{name}: no target was matched between the views (detected {found['left']} left, "
            f"{found['right']} right): {cause}")


#: Fewest matched pairs, as a fraction of the targets detected in the view that found fewer,
#: of photos that are the pair the calibration describes. A true pair matches nearly all of
#: them (81 of 81 in the tests, 496 of 496 on the paper's plane); photos that are not the pair
#: match by accident only where rows of targets line up with the epipolar curves (swapped: 19
#: of 81, 162 of 496; one photo twice: 19 of 81).
MIN_MATCHED_FRACTION = 0.5


def pair_mismatch(rig, name: str, centers: dict, matched: int, options: TargetOptions,
                  ambiguous: int = 0) -> str | None:
    """Why the photos of a pair are not the pair the calibration describes, or None: fewer
    matches than :data:`MIN_MATCHED_FRACTION` of the targets the sparser view detected. The
    views exchanged are matched too: when that matches at least twice as many (and enough), the
    photos are named as swapped. Where the ``ambiguous`` detections dropped would have made up
    the fraction, or the calibration models no port, those likelier causes come first."""
    from measure.stereo.matching import match_targets

    detected = min(len(centers["left"]), len(centers["right"]))
    if detected == 0 or matched >= MIN_MATCHED_FRACTION * detected:
        return None
    what = (f"{name}: only {matched} targets matched, less than half of the {detected} that "
            f"the sparser view detected")
    swapped = match_targets(rig, centers["right"], centers["left"], gate_mm=options.gate_mm,
                            depth_range=tuple(options.depth_range))
    n_swapped = int(len(swapped.left))
    swap = (f"left and right look swapped ({n_swapped} match with the photos the other way "
            f"round): give the left camera's photo first"
            if n_swapped >= max(2 * matched, MIN_MATCHED_FRACTION * detected) else None)
    causes = []
    if ambiguous and matched + ambiguous >= MIN_MATCHED_FRACTION * detected:
        near, far = options.depth_range
        causes.append(f"{ambiguous} more were dropped as ambiguous (rows of targets along the "
                      f"baseline meet the other view's at several depths): "
                      + ("bound the depth with --depth-range NEAR,FAR" if near is None else
                         f"narrow --depth-range {option_number(near)},{option_number(far)}"))
    elif swap:
        return f"{what}: {swap}"
    if not getattr(rig.port, "refracts", True):
        causes.append(f"the calibration models no port (in air, absorbed or rectified): rays it "
                      f"only approximates may miss by more than --gate-mm "
                      f"{option_number(options.gate_mm)}")
    generic = swap or ("the photos do not look like the pair the calibration describes (left "
                       "and right swapped, not a stereo pair, one photo twice, or another "
                       "calibration)")
    return f"{what}: " + "".join(f"{cause}; or " for cause in causes) + generic


#: Targets dropped as ambiguous, as a fraction of the sparser view's detections, above which a
#: pair measured without a depth window is warned about: where rows of targets meet the other
#: view's at several depths, some of the pairs kept may be a row's shifted partners as well.
AMBIGUOUS_WARNING_FRACTION = 0.1


def ambiguity_warning(result: PairResult, options: TargetOptions) -> str | None:
    """A warning for a pair measured without a depth window whose dropped ambiguous targets
    exceed :data:`AMBIGUOUS_WARNING_FRACTION` (and 2) of the sparser view's detections; None
    otherwise (or where the pair failed: its ``failed:`` line says it)."""
    counts = result.counts
    detected = min(counts["detected"].values())
    ambiguous = counts.get("ambiguous", 0)
    if (options.depth_range[0] is not None or result.problem or result.failure
            or ambiguous <= max(2, AMBIGUOUS_WARNING_FRACTION * detected)):
        return None
    return (f"{result.name}: {ambiguous} of {detected} targets dropped as ambiguous (rows of "
            f"targets along the baseline meet the other view's at several depths, and no "
            f"--depth-range bounds them): some of the {counts['matched']} kept may be a row's "
            f"shifted partners too; bound the depth with --depth-range NEAR,FAR")


def measure_targets(rig, name: str, left, right, options: TargetOptions,
                    rig_covariance=None) -> PairResult:
    """Detect, match (:func:`measure.stereo.matching.match_targets`, the refractive epipolar gap
    within ``options.gate_mm``) and triangulate one pair with each method; the covariances of
    the ``optical_path`` and ``reprojection`` points (the pixel noise, and ``rig_covariance``
    if given)."""
    from measure import triangulate
    from measure.stereo.matching import match_targets

    timings = {}
    t = time.perf_counter()
    detections = {view: detect_view(image, options.threshold_fraction, options.max_elongation,
                                    options.max_area_ratio, options.median_filter,
                                    options.floor_fraction)
                  for view, image in (("left", left), ("right", right))}
    centers = {view: np.asarray(d.centers, dtype=float).reshape(-1, 2)
               for view, d in detections.items()}
    timings["detect"] = time.perf_counter() - t
    found = {view: int(d.n_found) for view, d in detections.items()}
    counts = {"detected": found,
              "rejected": {view: int(d.n_rejected) for view, d in detections.items()},
              "matched": 0, "ambiguous": 0, "candidates": 0,
              "unmatched": dict(found)}
    result = PairResult(name, left, right, counts, detections=detections, timings=timings)
    if min(found.values()) == 0:
        result.problem = nothing_matched(name, found, options)
        return result
    t = time.perf_counter()
    matches = match_targets(rig, centers["left"], centers["right"], gate_mm=options.gate_mm,
                            depth_range=tuple(options.depth_range))
    timings["match"] = time.perf_counter() - t
    result.matches = matches
    counts.update(matched=int(len(matches.left)), ambiguous=int(matches.n_ambiguous),
                  candidates=int(matches.n_candidates),
                  unmatched={"left": int(len(matches.unmatched_left)),
                             "right": int(len(matches.unmatched_right))})
    if len(matches.left) == 0:
        result.problem = nothing_matched(name, found, options)
        return result
    result.failure = pair_mismatch(rig, name, centers, len(matches.left), options,
                                   matches.n_ambiguous)
    result.uv_left = centers["left"][matches.left]
    result.uv_right = centers["right"][matches.right]
    t = time.perf_counter()
    result.methods = {m: triangulate(rig, result.uv_left, result.uv_right, m)
                      for m in options.methods}
    timings["triangulate"] = time.perf_counter() - t
    t = time.perf_counter()
    covariance_methods = [m for m in COVARIANCE_METHODS if m in result.methods]
    if covariance_methods:
        from eval.core.uncertainty import method_covariances, pair_sigmas

        start = (result.methods["optical_path"].points if "optical_path" in result.methods
                 else triangulate(rig, result.uv_left, result.uv_right).points)
        sigma, result.pixel_sigma = pair_sigmas(options.pixel_sigma, result.uv_left,
                                                result.uv_right, start, rig, detections,
                                                matches)
        result.covariances = method_covariances(
            rig, {m: result.methods[m].points for m in covariance_methods}, sigma,
            rig_covariance)
    timings["covariance"] = time.perf_counter() - t
    return result


def measure_dense(rig, name: str, left, right, options: DenseOptions, progress=None) -> PairResult:
    """Dense matching (:func:`measure.dense.match.match_dense`) and triangulation of one pair, per
    method: one point per matched left pixel. ``progress(method)`` gives the matcher's
    ``(done, total)`` callback (or None)."""
    from measure.dense.match import match_dense
    from measure.stereo.triangulate import triangulate

    from eval.core.detection import median_filtered
    from eval.run.dense import DENSE_METHODS, pinhole_depth_range

    left_seen, right_seen = (median_filtered(image, options.median_filter)
                             for image in (left, right))
    counts = {"pixels": int(left.size), "matched": {}, "depth_range_mm": {}}
    result = PairResult(name, left, right, counts)
    uv = {}
    for method in options.methods:
        model, triangulation = DENSE_METHODS[method]
        search = (tuple(options.depth_range) if model == "refractive"
                  else pinhole_depth_range(rig, options.depth_range))
        t = time.perf_counter()
        matches = match_dense(rig, left_seen, right_seen, search, model=model,
                              progress=progress(method) if progress else None)
        result.timings[f"match_{method}"] = time.perf_counter() - t
        t = time.perf_counter()
        result.methods[method] = triangulate(rig, matches.uv_left, matches.uv_right,
                                             triangulation)
        result.timings[f"triangulate_{method}"] = time.perf_counter() - t
        counts["matched"][method] = int(len(matches.uv_left))
        counts["depth_range_mm"][method] = [float(v) for v in search]
        uv[method] = (matches.uv_left, matches.uv_right)
    result.uv_left = {m: v[0] for m, v in uv.items()}
    result.uv_right = {m: v[1] for m, v in uv.items()}
    if not any(counts["matched"].values()):
        result.problem = (f"{name}: no pixel was matched between the views in the depth range "
                          f"{options.depth_range[0]:g}-{options.depth_range[1]:g} mm: check "
                          f"--depth-range, the calibration and that the surface is speckled")
    return result


def pair_pixels(result: PairResult, method: str):
    """``(uv_left, uv_right)`` of ``method``'s points: shared by the methods of a target pair,
    the method's own matches in a dense pair."""
    if isinstance(result.uv_left, dict):
        return result.uv_left[method], result.uv_right[method]
    return result.uv_left, result.uv_right


__all__ = ["AMBIGUOUS_WARNING_FRACTION", "COVARIANCE_METHODS", "DenseOptions",
           "MIN_MATCHED_FRACTION", "PairResult", "TargetOptions", "ambiguity_warning",
           "measure_dense", "measure_targets", "nothing_matched", "pair_mismatch", "pair_pixels"]
