"""The stages of ``python -m eval run``: images → detections → matches → 3D → scores.

Each stage is one function: :func:`detect_stage`, :func:`match_stage`,
:func:`triangulate_stage`, :func:`score_stage`; :func:`run_pipeline` chains them.
:func:`detect_stage`, :func:`match_stage`, :func:`crosscheck_stage` and :func:`score_method`
take any number of views; the run of N cameras (:mod:`eval.run.multiview`) goes through them.

Frames and units: the reference frame is the left camera's (OpenCV axes), millimetres, pixels
in the OpenCV convention. Ground truth is used only after matching, to score.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from measure import triangulate, triangulate_rig
from measure.images.detect import (FLOOR_FRACTION, MERGE_AREA_RATIO as DEFAULT_MAX_AREA_RATIO,
                            MERGE_ELONGATION as DEFAULT_MAX_ELONGATION)
from measure.images.eccentricity import correct_eccentricity
from measure.stereo.multimatch import Tracks, match_views
from synth.products.crosscheck import ASSOCIATION_GATE_PX, crosscheck_summary, crosscheck_view
from synth.rendering.noise import add_pixel_noise

from eval.core.detection import detect_view
from eval.core.uncertainty import VERDICT_MIN_POINTS
from eval.core.cloud_metrics import cloud_distances, flatness, length_errors, rigid_alignment
from eval.core.results import ErrorStats, MethodScores
from eval.run.config import RunConfig
from eval.core.analytic import visible_targets
from eval.run.inputs import (RunInputs, expose_on_sensor, load_inputs,
                             nothing_matched_message)

#: The default working range around the scene's ``target_z``: ``(near, far)`` factors.
DEPTH_WINDOW_FACTORS = (0.8, 1.25)


class NothingMatched(ValueError):
    """No pair of detections passed the matching: nothing to measure (a user-facing error)."""


def default_depth_window(params: dict, targets=None, port=None):
    """``(near, far)`` along the port normal (mm; for domes along the left optical axis, the
    reference z): the scene's ``target_z`` × (0.8, 1.25) for a plane facing the cameras;
    otherwise the targets' nearest and farthest depths along the port normal × (0.8, 1.25) —
    the working range a user states for a layout in depth (the matcher takes it as given, like
    the plane's distance); no bound without either."""
    try:
        z = float(params["target_z"])
    except (KeyError, TypeError, ValueError):
        if targets is None or port is None or len(targets) == 0:
            return (None, None)
        axis = port.reference_axis
        depth = np.asarray(targets, dtype=float) @ axis  # domes: the left camera's z
        return (DEPTH_WINDOW_FACTORS[0] * float(depth.min()),
                DEPTH_WINDOW_FACTORS[1] * float(depth.max()))
    return (DEPTH_WINDOW_FACTORS[0] * z, DEPTH_WINDOW_FACTORS[1] * z)


def detect_stage(inputs: RunInputs, noise_px: float, threshold_fraction: float | None = None,
                 max_elongation: float = DEFAULT_MAX_ELONGATION,
                 max_area_ratio: float = DEFAULT_MAX_AREA_RATIO, median_filter: int = 0):
    """Detections per view (``{name: …}``, every view of ``inputs.view_images()``) and their
    centres ``(M, 2)`` px, with Gaussian noise of σ ``noise_px`` added (seeded by
    ``inputs.seed``, one generator through the views in order). Blobs more elongated than
    ``max_elongation``, or larger than ``max_area_ratio`` times the median blob, are taken for
    merged targets (raise them for targets seen obliquely, or over a wide range of depths).
    ``median_filter`` 3 or 5: each view is median-filtered first (``cv2.medianBlur``), which
    removes isolated bright pixels — the fireflies of lights seen through scattering water —
    that would otherwise pull the centroids; 0 (default): no filter."""
    def detect(image):
        return detect_view(image, threshold_fraction, max_elongation, max_area_ratio,
                           median_filter, floor_fraction=FLOOR_FRACTION)

    detections = {name: detect(image) for name, image in inputs.view_images().items()}
    centers = {name: np.array(d.centers, dtype=float).reshape(-1, 2)
               for name, d in detections.items()}
    if noise_px > 0:
        rng = np.random.default_rng(inputs.seed)
        for name in centers:
            centers[name] = add_pixel_noise(centers[name], variance=noise_px ** 2, rng=rng)
    return detections, centers


def match_stage(inputs: RunInputs, centers, gate_mm: float, depth_window):
    """``(matches, window)``: the views' detections ``centers`` matched without ground truth
    (refractive epipolar gap, depth window) by the one matcher of every count,
    :func:`measure.stereo.multimatch.match_views`: for two views its one pair's
    :class:`measure.stereo.matching.Matches` (exactly
    :func:`measure.stereo.matching.match_targets` of the rig), for N its
    :class:`measure.stereo.multimatch.Tracks`."""
    port = inputs.true_rig.port if inputs.depth_port is None else inputs.depth_port
    window = (default_depth_window(inputs.params, inputs.targets, port)
              if depth_window is None else tuple(depth_window))
    tracks = match_views(inputs.rig, list(centers.values()), gate_mm=gate_mm,
                         depth_range=window)
    return (tracks.pairs[(0, 1)] if len(centers) == 2 else tracks), window


def triangulate_stage(inputs: RunInputs, centers, matches, methods):
    """``{method: Triangulation}`` of the matched pairs, or of the tracks of N views
    (``matches`` :class:`measure.stereo.multimatch.Tracks`: :func:`measure.triangulate_rig`
    from every view of each track)."""
    if isinstance(matches, Tracks):
        pixels = matches.pixels(list(centers.values()))
        return {m: triangulate_rig(inputs.rig, pixels, m) for m in methods}
    uv_left = centers["left"][matches.left]
    uv_right = centers["right"][matches.right]
    return {m: triangulate_method(inputs, uv_left, uv_right, m) for m in methods}


def triangulate_method(inputs: RunInputs, uv_left, uv_right, method: str):
    """One method on pixel pairs: a port model's method with the measurement's rig, or the
    absorbed baseline (:mod:`eval.core.absorbed`) — the pinhole rays of its own calibration
    (no port), the point nearest to both."""
    from eval.core.absorbed import ABSORBED

    if method == ABSORBED:
        return triangulate(inputs.absorbed.rig, uv_left, uv_right, "optical_path")
    return triangulate(inputs.rig, uv_left, uv_right, method)


#: The methods whose points get a covariance: the maximum-likelihood point (``reprojection``)
#: and the optical-path midpoint, the same to first order (:mod:`measure.stereo.uncertainty`); ``su``
#: and ``regular`` are other estimators (``regular`` ignores the port) and get none.
COVARIANCE_METHODS = ("optical_path", "reprojection")


def covariance_stage(inputs: RunInputs, pixel_sigma, detections, centers, matches, results,
                     noise_px: float = 0.0, uv=None):
    """``({method: PointCovariance}, info)``: the covariance of every pair's point for the
    methods of :data:`COVARIANCE_METHODS` among ``results``, with the pixel σ of ``pixel_sigma``
    (``"auto"`` or px; :func:`eval.core.uncertainty.pair_sigmas`) and the rig covariance of
    ``inputs`` (None: the pixel part only). ``uv``: the pairs' pixels when they are not the
    matched centres (the eccentricity-corrected ones)."""
    from measure import triangulate as triangulate_pixels
    from eval.core.uncertainty import method_covariances, pair_sigmas, rig_covariance_note

    methods = [m for m in COVARIANCE_METHODS if m in results]
    info = {"methods": methods, "rig": rig_covariance_note(inputs.rig_covariance,
                                                           inputs.rig_covariance_source)}
    if not methods:
        info["note"] = f"no covariance: only {', '.join(COVARIANCE_METHODS)} get one"
        return {}, info
    uv_left, uv_right = uv if uv is not None else (centers["left"][matches.left],
                                                   centers["right"][matches.right])
    start = results[methods[0]].points
    if methods[0] != "optical_path":
        start = triangulate_pixels(inputs.rig, uv_left, uv_right, "optical_path").points
    sigma, info["pixel_sigma"] = pair_sigmas(pixel_sigma, uv_left, uv_right, start, inputs.rig,
                                             detections, matches, noise_px)
    covariances = method_covariances(inputs.rig, {m: results[m].points for m in methods}, sigma,
                                     inputs.rig_covariance)
    return covariances, info


def attach_covariances(covariances, results, scored, info, rig_differs=None) -> None:
    """Put each method's covariances beside its points in ``scored["per_method"]`` (the
    correctly matched rows: ``covariance``; every valid row: ``all_covariance``) and the
    report's ``{method: summary}`` (σ, coverage against the truth) into ``info["summaries"]``;
    ``rig_differs`` how the measurement's rig differs from the truth (its verdict says so)."""
    from eval.core.uncertainty import uncertainty_summary

    summaries = {}
    for method, covariance in covariances.items():
        ok = scored["correct"] & results[method].valid
        data = scored["per_method"][method]
        data["covariance"] = covariance.total[ok]
        data["all_covariance"] = covariance.total[results[method].valid]
        summaries[method] = uncertainty_summary(data["covariance"], data["errors"],
                                                rig_differs=rig_differs)
    info["summaries"] = summaries


def crosscheck_stage(inputs: RunInputs, detections):
    """Per view (every view of ``detections``, in camera order): simulator pixels, visibility,
    truth index per detection, cross-check stats (per view and over all).

    The cross-check compares each detected centre with the simulator's pixel of its target's
    centre (``rms_px``, ``max_px``) and with the area centroid of the image of its outline
    (``rms_px_outline``, ``max_px_outline``: what remains is the renderer's noise alone)."""
    simulated, inside, truth_of, distances = {}, {}, {}, {}
    rig = inputs.true_rig  # the simulator predicts what was rendered
    normals = (inputs.target_normals if inputs.target_normals is not None
               else np.array([0.0, 0.0, -1.0]))
    for view, name in enumerate(detections):
        camera, port = rig.cameras[view], rig.view_port(view)
        simulated[name], inside[name] = visible_targets(camera, port, inputs.targets,
                                                        inputs.target_radius)
        centers = np.asarray(detections[name].centers).reshape(-1, 2)
        index, d, d_outline = crosscheck_view(camera, port, (inputs.targets, normals,
                                                              inputs.target_radius),
                                              centers, simulated[name])
        truth_of[name] = index
        distances[name] = (d, d_outline)
    return simulated, inside, truth_of, crosscheck_summary(distances)


def score_stage(inputs: RunInputs, detections, matches, window, results, gate_mm: float):
    """Associate detections with the truth (for scoring only) and score every method."""
    simulated, inside, truth_of, crosscheck = crosscheck_stage(inputs, detections)
    pair_truth_left = truth_of["left"][matches.left]
    pair_truth_right = truth_of["right"][matches.right]
    correct = (pair_truth_left >= 0) & (pair_truth_left == pair_truth_right)
    found_both = np.intersect1d(truth_of["left"][truth_of["left"] >= 0],
                                truth_of["right"][truth_of["right"] >= 0])
    visible_both = np.flatnonzero(inside["left"] & inside["right"])
    matched_ids = pair_truth_left[correct]
    matching = {"pairs": int(len(matches.left)), "correct": int(correct.sum()),
                "wrong": int((~correct).sum()), "ambiguous_dropped": int(matches.n_ambiguous),
                "candidates": int(matches.n_candidates),
                "visible_in_both": int(len(visible_both)),
                "detected_in_both": int(len(found_both)),
                "visible_in_both_matched": int(np.isin(visible_both, matched_ids).sum()),
                "gate_mm": gate_mm,
                "depth_window_mm": [None if v is None else float(v) for v in window]}
    visibility = {"in_both": int(len(visible_both)),
                  "left_only": int((inside["left"] & ~inside["right"]).sum()),
                  "right_only": int((~inside["left"] & inside["right"]).sum()),
                  "in_neither": int((~inside["left"] & ~inside["right"]).sum())}

    truth_visible = inputs.targets[visible_both]
    scores, per_method = {}, {}
    for method, result in results.items():
        scores[method], per_method[method] = score_method(
            result, correct, pair_truth_left, inputs.targets, truth_visible, inputs.seed)
    return {"matching": matching, "visibility": visibility, "crosscheck": crosscheck,
            "scores": scores, "per_method": per_method, "correct": correct,
            "simulated": simulated}


def score_method(result, correct, truth_index, targets, truth_visible, seed):
    """``(MethodScores, arrays)`` of one method's points ``result`` (a triangulation of pairs or
    of N views' tracks: ``points`` (T, 3) mm, ``valid``) against the truth: ``correct`` (T,)
    the rows matched right, ``truth_index`` (T,) their target in ``targets``, ``truth_visible``
    the targets the matching could have found (the cloud's reference), ``seed`` the plane
    fit's; ``arrays`` ``{points, truth, errors, all_points}`` (the correct and valid rows, and
    every valid point)."""
    ok = correct & result.valid
    truth = targets[truth_index[ok]]
    errors = result.points[ok] - truth
    measured_all = result.points[result.valid]
    scores = MethodScores(
        errors=ErrorStats.of(errors), cloud=cloud_distances(measured_all, truth_visible),
        alignment=rigid_alignment(result.points[ok], truth),
        flatness=flatness(measured_all, seed=seed),
        invalid=int((~result.valid).sum()), lengths=length_errors(result.points[ok], truth))
    return scores, {"points": result.points[ok], "truth": truth, "errors": errors,
                    "all_points": measured_all}


def eccentricity_stage(inputs: RunInputs, centers, matches, methods, iterations: int = 2):
    """Each method on detections corrected for the eccentricity of the disk targets (offsets
    predicted with the measurement rig and the optical-path points, normals from neighbouring
    targets, the scene's target radius). Returns ``({method: Triangulation}, summary)``."""
    uv_left = centers["left"][matches.left]
    uv_right = centers["right"][matches.right]
    corr = correct_eccentricity(inputs.rig, uv_left, uv_right, inputs.target_radius,
                                "optical_path", iterations=iterations)
    results = {m: (corr.triangulation if m == "optical_path"
                   else triangulate(inputs.rig, corr.uv_left, corr.uv_right, m)) for m in methods}
    offsets = {}
    for name, offset in (("left", corr.offset_left), ("right", corr.offset_right)):
        length = np.linalg.norm(offset, axis=1)
        offsets[name] = {"rms_px": float(np.sqrt(np.nanmean(length ** 2))) if length.size else None,
                         "max_px": float(np.nanmax(length)) if length.size else None}
    return results, {"iterations": iterations, "offset_px": offsets,
                     "normals": "plane of the 8 nearest triangulated targets",
                     "uv": (corr.uv_left, corr.uv_right)}


def self_calibration_stage(inputs: RunInputs, centers, matches, parameters, methods, log):
    """Estimate port ``parameters`` from the matched pixels
    (:func:`measure.calibration.selfcal.self_calibrate`) and triangulate again with the refined
    rig. Returns ``(summary, {method: Triangulation} or None)``: None when the refinement did not
    converge or the data do not determine the parameters (then nothing is refined, and the
    summary says why). σ includes the ``--calib`` file's covariance of the parameters held fixed
    when it has one (``sigma_includes`` names them; ``sigmas_conditional`` is the σ without)."""
    from measure.calibration.selfcal import self_calibrate

    uv_left = centers["left"][matches.left]
    uv_right = centers["right"][matches.right]
    start = time.perf_counter()
    fit = self_calibrate(inputs.rig, uv_left, uv_right, parameters,
                         rig_covariance=inputs.rig_covariance)
    seconds = time.perf_counter() - start
    truth = {"n_water": inputs.true_rig.port.n_water,
             "port_distance": inputs.true_rig.port.distance,
             "port_normal": inputs.true_rig.port.normal.tolist()}
    assumed = {"n_water": inputs.rig.port.n_water, "port_distance": inputs.rig.port.distance,
               "port_normal": inputs.rig.port.normal.tolist()}
    summary = {"parameters": list(parameters), "targets": fit.n_points, "seconds": seconds,
               "converged": fit.converged, "identifiable": fit.identifiable,
               "reason": fit.reason, "message": fit.message,
               "rms_px_before": fit.rms_px_before, "rms_px_after": fit.rms_px,
               "assumed": {p: assumed[p] for p in parameters},
               "truth": {p: truth[p] for p in parameters},
               "estimates": fit.estimates, "sigmas": fit.sigmas,
               "sigmas_conditional": fit.sigmas_conditional,
               "sigma_includes": list(fit.propagated),
               "correlation": fit.correlation.tolist(), "labels": list(fit.labels)}
    for name in ("n_water", "port_distance"):
        if name in fit.estimates and fit.sigmas.get(name):
            error = fit.estimates[name] - truth[name]
            summary.setdefault("error", {})[name] = error
            summary.setdefault("error_in_sigma", {})[name] = error / fit.sigmas[name]
    if not (fit.converged and fit.identifiable):
        log(f"self-calibration of {', '.join(parameters)} gave no trusted estimate: "
            f"{fit.reason or fit.message}; the unrefined rig is kept")
        return summary, None
    refined = {m: triangulate(fit.rig, uv_left, uv_right, m) for m in methods}
    return summary, refined


def budget_stage(inputs: RunInputs, detections, centers, rigs: dict, methods, gate_mm: float,
                 depth_window):
    """The error budget: the same detections matched, triangulated and scored with each rig of
    ``rigs`` ``{label: Rig}`` (e.g. the exact calibration, the in-air calibration with the
    design port). Returns ``{label: {"matching": …, "methods": {method: stats}}}``."""
    from dataclasses import replace

    budget = {}
    for label, rig in rigs.items():
        variant = replace(inputs, rig=rig, truth_rig=inputs.true_rig)
        matches, window = match_stage(variant, centers, gate_mm, depth_window)
        if len(matches.left) == 0:
            budget[label] = {"matching": {"pairs": 0, "correct": 0, "wrong": 0}, "methods": {}}
            continue
        results = triangulate_stage(variant, centers, matches, methods)
        scored = score_stage(variant, detections, matches, window, results, gate_mm)
        m = scored["matching"]
        budget[label] = {"matching": {k: m[k] for k in ("pairs", "correct", "wrong",
                                                         "visible_in_both")},
                         "methods": {k: v.to_json() for k, v in scored["scores"].items()}}
    return budget


def _rigs_report(inputs: RunInputs, difference: dict) -> dict:
    """The report's ``rigs``: what was rendered, what the measurement assumed, and
    ``difference`` (:func:`eval.core.assumption.rig_difference`, computed once per run)."""
    from eval.core.assumption import describe_rig

    return {"truth": describe_rig(inputs.true_rig), "assumed": describe_rig(inputs.rig),
            "difference": difference}


def methods_with_coverage(scores, uncertainty) -> dict:
    """``report.json``'s ``methods``: each method's scores with ``coverage_95`` (None for a
    method without covariances) — the fraction of its correctly matched points inside their
    95 % ellipsoid."""
    methods = {}
    for method, score in scores.items():
        summary = uncertainty.get("summaries", {}).get(method)
        methods[method] = {**score.to_json(), "coverage_95": (
            summary["coverage"]["coverage_95"] if summary else None)}
    return methods


@dataclass
class RunResult:
    """What a target run measured: ``report`` (the JSON-ready report: see the docs' report
    fields; without ``versions``, ``inputs``, ``ply`` and the ``report`` / ``total`` timings),
    the ``inputs`` it started from, and the arrays the figures and PLY files need:
    ``detections`` and ``centers`` ``{view: (M, 2) px}``, ``matches`` (left/right indices),
    ``correct`` (bool per pair, from the truth), ``per_method`` ``{method: {points, truth,
    errors, all_points}}`` (mm), ``simulated`` ``{view: (N, 2) px}`` (the Fermat simulator's
    pixels of every target) and ``scores`` ``{method: MethodScores}``."""

    report: dict
    inputs: RunInputs
    detections: dict
    centers: dict
    matches: object
    correct: np.ndarray
    per_method: dict
    simulated: dict
    scores: dict = field(default_factory=dict)


def run_pipeline(inputs: RunInputs, config: RunConfig, log=print) -> RunResult:
    """Detection, matching, triangulation and scoring of ``inputs`` as ``config`` says (its
    methods, noise, gate, depth range, detection options, self-calibration, eccentricity;
    the error budget's rigs are ``inputs.budget_rigs``). Raises :class:`NothingMatched` when
    no pair is matched."""
    methods, noise_px, gate_mm = config.target_methods(), config.noise_px, config.gate_mm
    port_methods = config.port_methods
    depth_window, self_calibrate = config.depth_range_mm, config.self_calibrate
    threshold_fraction, median_filter = config.threshold_fraction, config.median_filter
    max_elongation, max_area_ratio = config.max_elongation, config.max_area_ratio
    budget_rigs = inputs.budget_rigs
    timings = {"render": inputs.render_seconds, **inputs.extra.pop("timings", {})}

    log("detect targets in both views …")
    start = time.perf_counter()
    max_elongation = DEFAULT_MAX_ELONGATION if max_elongation is None else max_elongation
    max_area_ratio = DEFAULT_MAX_AREA_RATIO if max_area_ratio is None else max_area_ratio
    detections, centers = detect_stage(inputs, noise_px, threshold_fraction, max_elongation,
                                       max_area_ratio, median_filter)
    timings["detect"] = time.perf_counter() - start

    log("match left and right (refractive epipolar constraint) …")
    start = time.perf_counter()
    matches, window = match_stage(inputs, centers, gate_mm, depth_window)
    timings["match"] = time.perf_counter() - start
    if len(matches.left) == 0:
        raise NothingMatched(nothing_matched_message(inputs, detections, window))

    log(f"triangulate {len(matches.left)} pairs with {', '.join(methods)} …")
    start = time.perf_counter()
    results = triangulate_stage(inputs, centers, matches, methods)
    timings["triangulate"] = time.perf_counter() - start

    log("point covariances …")
    start = time.perf_counter()
    covariances, uncertainty = covariance_stage(inputs, config.pixel_sigma, detections, centers,
                                                matches, results, noise_px)
    timings["covariance"] = time.perf_counter() - start

    calibration, refined = None, None
    if self_calibrate:
        log(f"estimate {', '.join(self_calibrate)} from the matched targets …")
        start = time.perf_counter()
        calibration, refined = self_calibration_stage(inputs, centers, matches, self_calibrate,
                                                      port_methods, log)
        timings["self_calibration"] = time.perf_counter() - start

    corrected = None
    if config.corrects_eccentricity:
        corrected, eccentricity_summary, covariances_corrected, uncertainty_corrected = \
            _corrected_run(inputs, config, detections, centers, matches, results, timings, log)

    budget = _budget(inputs, detections, centers, config, timings, log) if budget_rigs else None

    log("score against the ground truth (Open3D) …")
    start = time.perf_counter()
    scored = score_stage(inputs, detections, matches, window, results, gate_mm)
    from eval.core.assumption import rig_difference

    differs = rig_difference(inputs.true_rig, inputs.rig)
    attach_covariances(covariances, results, scored, uncertainty, differs)
    if corrected is not None:
        scored_corrected = score_stage(inputs, detections, matches, window, corrected, gate_mm)
        attach_covariances(covariances_corrected, corrected, scored_corrected,
                           uncertainty_corrected, differs)
    if refined is not None:
        calibration["methods"] = {m: s.to_json() for m, s in score_stage(
            inputs, detections, matches, window, refined, gate_mm)["scores"].items()}
    timings["evaluate"] = time.perf_counter() - start
    # the headline numbers: the eccentricity corrected (the default), else the raw centroids
    primary, primary_uncertainty = ((scored_corrected, uncertainty_corrected)
                                    if corrected is not None else (scored, uncertainty))
    report = _report(inputs, config, detections, scored, primary, primary_uncertainty,
                     uncertainty, differs, calibration, budget,
                     None if corrected is None else eccentricity_summary, timings)
    return RunResult(report=report, inputs=inputs, detections=detections, centers=centers,
                     matches=matches, correct=scored["correct"],
                     per_method=primary["per_method"], simulated=scored["simulated"],
                     scores=primary["scores"])


def _report(inputs, config, detections, scored, primary, primary_uncertainty, uncertainty,
            differs, calibration, budget, eccentricity_summary, timings) -> dict:
    """The run's report (``report.json``): the headline ``methods`` from ``primary`` (the
    eccentricity corrected, or the raw centroids), the raw ones under ``eccentricity`` when it
    was corrected (``eccentricity_summary`` not None)."""
    noise_px, threshold_fraction = config.noise_px, config.threshold_fraction
    median_filter, port_methods = config.median_filter, config.port_methods
    max_elongation = (DEFAULT_MAX_ELONGATION if config.max_elongation is None
                      else config.max_elongation)
    max_area_ratio = (DEFAULT_MAX_AREA_RATIO if config.max_area_ratio is None
                      else config.max_area_ratio)
    return {
        "scene": inputs.scene, "targets": int(len(inputs.targets)),
        "visibility": scored["visibility"],
        "detection": _detection_report(detections),
        "crosscheck": scored["crosscheck"],
        "matching": scored["matching"],
        "methods": methods_with_coverage(primary["scores"], primary_uncertainty),
        "uncertainty": primary_uncertainty,
        "noise_px": noise_px, "seed": inputs.seed, "threshold_fraction": threshold_fraction,
        "max_elongation": max_elongation, "max_area_ratio": max_area_ratio,
        "median_filter": median_filter,
        "rigs": _rigs_report(inputs, differs),
        "absorbed": None if inputs.absorbed is None else inputs.absorbed.summary,
        "self_calibration": calibration,
        "budget": budget,
        "eccentricity": None if eccentricity_summary is None else {
            **eccentricity_summary,
            # absorbed stays on the raw centroids: its row would repeat itself
            "uncorrected": {"methods": methods_with_coverage(
                {m: v for m, v in scored["scores"].items() if m in port_methods}, uncertainty),
                "uncertainty": uncertainty}},
        "timings_s": timings,
        "variant": inputs.variant, "spp": inputs.spp,
        "spp_rendered": (inputs.extra.get("render") or {}).get(
            "spp_rendered", inputs.extra.get("spp_rendered")),
    }


def _budget(inputs, detections, centers, config, timings, log):
    """The error budget: the same detections measured again with each of the budget's rigs."""
    log(f"error budget: measure again with {', '.join(inputs.budget_rigs)} …")
    start = time.perf_counter()
    budget = budget_stage(inputs, detections, centers, inputs.budget_rigs, config.port_methods,
                          config.gate_mm, config.depth_range_mm)
    timings["budget"] = time.perf_counter() - start
    return budget


def _corrected_run(inputs, config, detections, centers, matches, results, timings, log):
    """The targets' eccentricity corrected and triangulated again (the absorbed baseline,
    which has no port model to correct its centroids with, keeps its raw points), and the
    corrected points' covariances: ``(corrected, summary, covariances, uncertainty)``."""
    log("correct the targets' eccentricity and triangulate again …")
    start = time.perf_counter()
    corrected, summary = eccentricity_stage(inputs, centers, matches, config.port_methods)
    corrected.update({m: results[m] for m in config.target_methods() if m not in corrected})
    timings["eccentricity"] = time.perf_counter() - start
    start = time.perf_counter()
    covariances, uncertainty = covariance_stage(
        inputs, config.pixel_sigma, detections, centers, matches, corrected, config.noise_px,
        uv=summary.pop("uv"))
    timings["covariance_eccentricity"] = time.perf_counter() - start
    return corrected, summary, covariances, uncertainty


def _detection_report(detections) -> dict:
    """The report's ``detection``: per view what was found and rejected, and the threshold."""
    return {name: {"found": int(d.n_found), "rejected": int(d.n_rejected),
                   "rejected_by_reason": {k: int(v) for k, v in d.rejected.items()},
                   "threshold": float(d.threshold), "threshold_rule": d.threshold_rule}
            for name, d in detections.items()}


def measure_scene(config: RunConfig, log=print) -> RunResult:
    """Everything of ``eval run`` on a target scene but the output files: load or render the
    images, expose them on the sensor, detect, match, triangulate, score. ``eval sweep`` runs
    its render cells through this function, in its workers."""
    inputs = load_inputs(config, log)
    sensor_info = expose_on_sensor(inputs, config.sensor, log)
    result = run_pipeline(inputs, config, log)
    result.report["sensor"] = sensor_info
    result.report["rigs"]["source"] = config.rig_source
    failures = run_failures(result.report)
    result.report["verdict"] = {"passed": not failures, "failures": failures}
    return result


#: A method whose points fall inside their 95 % ellipsoids less often than this fails the run
#: (an optimistic σ, 0.84 on the paper plane, is said in the report; one that covers fewer than
#: half of the points does not describe the errors at all: a wrong --assume gave 0.000).
FAILED_COVERAGE = 0.5


def run_failures(report: dict) -> list:
    """What the truth shows went wrong in a target run, one phrase each (empty: nothing):
    wrong matches, no correct match or fewer correct matches than half the targets visible in
    both views, a cross-check with no detection associated in one view
    (its headline would then come from the other view alone), a method whose σ covers fewer
    than :data:`FAILED_COVERAGE` of its points (not with a self-calibration, which is there
    because the assumed rig is off)."""
    failures = []
    m, c = report["matching"], report["crosscheck"]
    if m["wrong"]:
        failures.append(f"{m['wrong']} of {m['pairs']} matched pairs are wrong")
    if m["correct"] == 0:
        failures.append("no pair was matched correctly")
    elif m.get("visible_in_both") and m["correct"] < m["visible_in_both"] / 2:
        failures.append(f"only {m['correct']} of the {m['visible_in_both']} targets visible in "
                        f"both views were matched correctly (less than half)")
    for view in ("left", "right"):
        if c[view]["associated"] == 0:
            failures.append(f"no {view} detection lies within {ASSOCIATION_GATE_PX:g} px of a "
                            f"target's simulated pixel, so the cross-check comes from one view "
                            f"at most")
    # with --self-calibrate the assumed rig is known to be off: its estimate corrects it
    judged = {} if report.get("self_calibration") else report.get("uncertainty", {})
    for method, summary in judged.get("summaries", {}).items():
        coverage = summary.get("coverage") or {}
        fraction, n = coverage.get("coverage_95"), coverage.get("n") or 0
        if fraction is not None and n >= VERDICT_MIN_POINTS and fraction < FAILED_COVERAGE:
            failures.append(f"{method}'s σ does not describe its errors: {fraction:.3f} of its "
                            f"{n} points inside their 95 % ellipsoids (fewer than "
                            f"{FAILED_COVERAGE:g})")
    return failures


__all__ = ["NothingMatched", "RunResult", "budget_stage", "crosscheck_stage",
           "COVARIANCE_METHODS", "attach_covariances", "covariance_stage",
           "default_depth_window", "detect_stage", "eccentricity_stage", "match_stage",
           "measure_scene", "methods_with_coverage", "run_failures", "run_pipeline", "score_method",
           "score_stage", "self_calibration_stage", "triangulate_stage"]
