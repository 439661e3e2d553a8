"""Section 3 of Li et al. 2024 on the analytic simulator: ``python -m eval paper``.

The experiments (pure computation, numpy in, numpy/dicts out):

* 3.2 — the gap (common-perpendicular length, mm) between the camera rays ``O_L A1`` and
  ``O_R B1`` of the 496 targets at 1 m: ``triangulate(..., "regular").gap`` on the pixels
  projected through the paper's port.
* 3.3.1 — ideal conditions: errors ``d = measured − true`` (mm) of ``optical_path`` and ``su`` on
  the pixels projected through the port, and of ``regular`` in the all-air copy of the rig
  (``paper_rig(in_air=True)``), at 1 m and 2 m.
* 3.3.2 — Gaussian pixel noise of variance 0.01 px² (σ = 0.1 px), independent on u and v of the
  left and right pixels, ``trials`` Monte-Carlo draws, every method triangulated on all
  ``trials × 496`` rows in one call.
* 3.3.3 — the same noise plus a 0.15 % deviation of the water index, carried either by the
  simulation (true index 1.33·1.0015, the measurement assumes 1.33) or by the measurement
  (true 1.33, assumed 1.33·1.0015). Both are run; the side that reproduces the paper's signs
  is chosen by a stated rule (:func:`choose_index_side`).

The same noise offsets (one draw per trial, target and image) are used for every noisy run
(water, air, both index sides): common random numbers, so the index-deviation shifts are
differences of means over the same draws.

:func:`run_experiments` returns everything as a dict; :func:`evaluate_claims` turns the numbers
into the paper's claims, each with its threshold, the measured value and ``holds`` computed from
them. The command (:mod:`eval.paper.command`) writes ``report.json``, ``report.md`` and the figures.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from scipy.stats import spearmanr

from measure import Rig, triangulate
from synth.scene.layouts import paper_plane
from synth.rendering.noise import deviate_port, pixel_noise
from synth.scene.rig import paper_rig

from eval.paper.settings import (COMPONENTS, DISTANCES_MM, GAP_THRESHOLD_MM,  # noqa: F401
                                 IDEAL_TOLERANCE_MM, INDEX_METHODS, INDEX_RELATIVE, INDEX_SIDES,
                                 NAME, NOISE_METHODS, NOISE_VARIANCE_PX2, PAPER_REFERENCE,
                                 SEM_FACTOR, SHIFT_AGREEMENT_MM)
from eval.paper.claims import evaluate_claims
from eval.core.analytic import project_pair, triangulation_errors
from eval.core.results import ErrorStats


# --------------------------------------------------------------------------------------------
# statistics


def error_components(errors: np.ndarray) -> dict[str, np.ndarray]:
    """``{dX, dY, dZ, dP}`` from errors ``(..., 3)`` (measured − true, mm), flattened."""
    flat = np.asarray(errors, dtype=np.float64).reshape(-1, 3)
    return {"dX": flat[:, 0], "dY": flat[:, 1], "dZ": flat[:, 2],
            "dP": np.linalg.norm(flat, axis=1)}


def error_stats(errors: np.ndarray) -> ErrorStats:
    """:class:`eval.core.results.ErrorStats` of errors ``(..., 3)`` (measured − true, mm): per
    component n, min, max, max_abs, mean, std, sem, rms. ``sem`` = std / sqrt(n) over all rows:
    it counts any deterministic per-target error (Su's model error) as spread; the noise
    yardstick of the claims is ``noise_sem`` instead. NaN rows are left out and counted."""
    return ErrorStats.of(errors)


# --------------------------------------------------------------------------------------------
# experiments


def rig_description(rig: Rig, air_rig: Rig) -> dict:
    """The rig as plain numbers (mm, px, degrees) for the report."""
    def camera(cam):
        return {"K": cam.K.tolist(), "size_px": list(cam.size), "R": cam.R.tolist(),
                "t_mm": cam.t.tolist(), "center_mm": cam.center.tolist()}
    toe_in = np.degrees(np.arctan2(-rig.right.R[0, 2], rig.right.R[2, 2]))
    port = rig.port
    return {
        "source": "synth.scene.rig.paper_rig() (the paper does not give intrinsics, baseline or size)",
        "left": camera(rig.left), "right": camera(rig.right),
        "baseline_mm": float(np.linalg.norm(rig.right.center - rig.left.center)),
        "right_toe_in_deg": float(toe_in),
        "port": {"normal": port.normal.tolist(), "distance_mm": port.distance,
                 "thicknesses_mm": list(port.thicknesses), "indices": list(port.indices)},
        "air_copy_port_indices": list(air_rig.port.indices),
        "frame": "left camera, OpenCV axes (x right, y down, z forward), mm",
    }


def run_gap(rig: Rig, z: float = DISTANCES_MM[0]) -> dict:
    """Section 3.2: the gap between rays O_L A1 and O_R B1 for the 496 targets at ``z`` mm."""
    targets = paper_plane(z)
    uv_left, uv_right = project_pair(rig, targets)
    result = triangulate(rig, uv_left, uv_right, "regular")
    gap = result.gap
    radius = np.hypot(targets[:, 0], targets[:, 1])
    finite = np.isfinite(gap)
    rho = float(spearmanr(gap[finite], radius[finite]).statistic)
    return {
        "z_mm": float(z), "targets": targets, "gap": gap,
        "stats": {
            "n": int(gap.size), "n_invalid": int((~finite).sum()),
            "threshold_mm": GAP_THRESHOLD_MM,
            "count_above_threshold": int((gap > GAP_THRESHOLD_MM).sum()),
            "share_above_threshold": float(np.mean(gap > GAP_THRESHOLD_MM)),
            "share_above_0.6mm": float(np.mean(gap > 0.6)),
            "min": float(np.nanmin(gap)), "median": float(np.nanmedian(gap)),
            "mean": float(np.nanmean(gap)), "max": float(np.nanmax(gap)),
            "spearman_rho_vs_radius": rho,
        },
    }


def run_ideal(rig: Rig, air_rig: Rig, distances=DISTANCES_MM) -> dict:
    """Section 3.3.1: errors (496, 3) per method per distance, no noise, exact parameters."""
    out = {}
    for z in distances:
        targets = paper_plane(z)
        uv_left, uv_right = project_pair(rig, targets)
        air_left, air_right = project_pair(air_rig, targets)
        errors = {
            "optical_path": triangulation_errors(rig, uv_left, uv_right, "optical_path",
                                                 targets)[0],
            "su": triangulation_errors(rig, uv_left, uv_right, "su", targets)[0],
            "regular_in_air": triangulation_errors(air_rig, air_left, air_right, "regular",
                                                   targets)[0],
        }
        radius = np.hypot(targets[:, 0], targets[:, 1])
        su_dp = np.linalg.norm(errors["su"], axis=1)
        out[float(z)] = {
            "targets": targets, "errors": errors,
            "stats": {m: error_stats(e) for m, e in errors.items()},
            "su_share_dP_within_1mm": float(np.mean(su_dp <= 1.0)),
            "su_spearman_rho_dP_vs_radius": float(spearmanr(su_dp, radius).statistic),
            "su_share_dZ_nonpositive": float(np.mean(errors["su"][:, 2] <= 1e-9)),
        }
    return out


def _mean_vector(errors: np.ndarray) -> np.ndarray:
    return np.nanmean(errors.reshape(-1, 3), axis=0)


def choose_index_side(shifts: dict, sem: dict) -> tuple[str, str]:
    """Which side of the index deviation reproduces the paper's signs (section 3.3.3).

    The paper: the mean dX and dZ of both models move in the negative direction. Each side
    scores the number of these four statements it reproduces (shift < −3 SEM of the noise-only
    mean); a tie goes to the side whose reproduced shifts are larger in total (mm).
    Returns ``(side, rule)``.
    """
    rule = ("paper: mean dX and dZ of optical_path and su move negative; score = number of the "
            "4 statements reproduced (shift < -3 noise SEM), tie -> larger "
            "total |shift| (mm) of the reproduced statements")
    scores = {}
    for side in INDEX_SIDES:
        count, size = 0, 0.0
        for method in INDEX_METHODS:
            for axis in ("dX", "dZ"):
                shift = shifts[side][method][axis]
                if shift < -SEM_FACTOR * sem[method][axis]:
                    count += 1
                    size += abs(shift)
        scores[side] = (count, size)
    side = max(INDEX_SIDES, key=lambda s: scores[s])
    return side, rule


def run_noise(rig: Rig, air_rig: Rig, trials: int, seed: int,
              variance: float = NOISE_VARIANCE_PX2, index_relative: float = INDEX_RELATIVE,
              z: float = DISTANCES_MM[0], progress: bool = False) -> tuple[dict, dict]:
    """Sections 3.3.2 and 3.3.3: Monte Carlo over ``trials`` draws of pixel noise.

    Errors are ``(trials, 496, 3)`` mm. One vectorized ``triangulate`` call per method and run
    (``trials × 496`` rows). Returns ``(noise, index)``.
    """
    trials = int(trials)
    if trials < 1:
        raise ValueError(f"trials must be >= 1, got {trials}")
    targets = paper_plane(z)
    n = targets.shape[0]
    rng = np.random.default_rng(seed)
    # one draw per trial, target and image; the same offsets serve every noisy run
    offsets = (pixel_noise((trials, n, 2), variance, rng), pixel_noise((trials, n, 2), variance, rng))
    true_port = {"simulation": deviate_port(rig.port, "n_water", index_relative),
                 "measurement": rig.port}
    assumed_rig = {"simulation": rig,
                   "measurement": rig.with_port(deviate_port(rig.port, "n_water",
                                                             index_relative))}
    exact = {"water": project_pair(rig, targets), "air": project_pair(air_rig, targets)}
    noise_errors, index_errors = _monte_carlo(rig, air_rig, targets, exact, offsets, true_port,
                                              assumed_rig, progress)
    noise_stats = {m: error_stats(e) for m, e in noise_errors.items()}
    noise_sem = _noise_sem(rig, air_rig, targets, exact, noise_errors)
    noise = {"z_mm": float(z), "trials": trials, "seed": int(seed), "variance_px2": variance,
             "sigma_px": float(np.sqrt(variance)), "samples": trials * n, "targets": targets,
             "errors": noise_errors, "stats": noise_stats,
             "noise_sem": noise_sem,
             "su_share_dZ_negative": float(np.nanmean(noise_errors["su"][..., 2] < 0)),
             "optical_path_share_abs_dX_within_1mm":
                 float(np.nanmean(np.abs(noise_errors["optical_path"][..., 0]) <= 1.0))}
    index = _index_result(z, index_relative, index_errors, noise_errors, noise_stats, noise_sem,
                          true_port, assumed_rig)
    return noise, index


def _monte_carlo(rig, air_rig, targets, exact, offsets, true_port, assumed_rig,
                 progress) -> tuple[dict, dict]:
    """The errors ``(trials, N, 3)`` mm of every noisy run: ``{method: errors}`` of
    :data:`NOISE_METHODS` and ``{side: {method: errors}}`` of the water index's deviation
    (:data:`INDEX_SIDES` × :data:`INDEX_METHODS`), the same pixel ``offsets`` (left, right;
    ``(trials, N, 2)`` px) added to every run's exact projections (``exact``: the water rig's
    and the air rig's pixel pairs of ``targets``)."""
    from tqdm import tqdm

    offset_left, offset_right = offsets
    trials = offset_left.shape[0]
    truth = np.broadcast_to(targets, (trials, targets.shape[0], 3))
    (water_left, water_right), (air_left, air_right) = exact["water"], exact["air"]
    bar = tqdm(total=trials * (len(NOISE_METHODS) + len(INDEX_SIDES) * len(INDEX_METHODS)),
               unit="trial", desc="paper Monte Carlo", disable=not progress, file=sys.stderr,
               leave=False)
    with bar:
        noise_errors = {}
        for method in NOISE_METHODS:
            bar.set_postfix_str(f"noise {method}")
            if method == "regular_in_air":
                noise_errors[method] = triangulation_errors(
                    air_rig, air_left + offset_left, air_right + offset_right, "regular",
                    truth)[0]
            else:
                noise_errors[method] = triangulation_errors(
                    rig, water_left + offset_left, water_right + offset_right, method, truth)[0]
            bar.update(trials)
        index_errors = {}
        for side in INDEX_SIDES:
            sim_left, sim_right = project_pair(rig, targets, true_port[side])
            index_errors[side] = {}
            for method in INDEX_METHODS:
                bar.set_postfix_str(f"index {side} {method}")
                index_errors[side][method] = triangulation_errors(
                    assumed_rig[side], sim_left + offset_left, sim_right + offset_right, method,
                    truth)[0]
                bar.update(trials)
    return noise_errors, index_errors


def _noise_sem(rig, air_rig, targets, exact, noise_errors) -> dict:
    """``{method: {component: mm}}``: the standard error of a mean caused by the pixel noise —
    the spread of (noisy − noise-free) errors over targets × trials, / sqrt(samples). The
    per-target noise-free error (Su's model error) is the same in every run and is not noise,
    so it is left out of this yardstick."""
    (water_left, water_right), (air_left, air_right) = exact["water"], exact["air"]
    trials = noise_errors[NOISE_METHODS[0]].shape[0]
    noise_free = {
        "optical_path": triangulation_errors(rig, water_left, water_right, "optical_path",
                                             targets)[0],
        "su": triangulation_errors(rig, water_left, water_right, "su", targets)[0],
        "regular_in_air": triangulation_errors(air_rig, air_left, air_right, "regular",
                                               targets)[0]}
    noise_sem = {}
    for method in NOISE_METHODS:
        noisy = error_components(noise_errors[method])
        clean = error_components(np.broadcast_to(noise_free[method], (trials, len(targets), 3)))
        noise_sem[method] = {}
        for c in COMPONENTS:
            part = noisy[c] - clean[c]
            part = part[np.isfinite(part)]
            noise_sem[method][c] = (float(np.std(part, ddof=1) / np.sqrt(part.size))
                                    if part.size > 1 else float("nan"))
    return noise_sem


def _index_result(z, index_relative, index_errors, noise_errors, noise_stats, noise_sem,
                  true_port, assumed_rig) -> dict:
    """Section 3.3.3's result: per side of the deviation the statistics and the mean shift
    against the noise-only run (mm), the side chosen (:func:`choose_index_side`) and why."""
    sem = {m: noise_sem[m] for m in INDEX_METHODS}
    shifts, stats = {}, {}
    for side in INDEX_SIDES:
        shifts[side], stats[side] = {}, {}
        for method in INDEX_METHODS:
            errors = index_errors[side][method]
            stats[side][method] = error_stats(errors)
            delta = _mean_vector(errors) - _mean_vector(noise_errors[method])
            mean_dp_shift = (stats[side][method].dp.mean_mm
                             - noise_stats[method].dp.mean_mm)
            shifts[side][method] = {"dX": float(delta[0]), "dY": float(delta[1]),
                                    "dZ": float(delta[2]), "dP": float(mean_dp_shift)}
    chosen, rule = choose_index_side(shifts, sem)
    return {
        "z_mm": float(z), "relative": index_relative, "chosen_side": chosen, "rule": rule,
        "sides": {side: {
            "description": INDEX_SIDE_WORDS[side],
            "n_water_true": true_port[side].n_water,
            "n_water_assumed": assumed_rig[side].port.n_water,
            "stats": stats[side], "mean_shift": shifts[side]} for side in INDEX_SIDES},
        "errors": index_errors,
        "noise_sem": sem,
    }


#: What each side of the water index's deviation means (section 3.3.3).
INDEX_SIDE_WORDS = {
    "simulation": "the simulation carries the deviation: pixels simulated with the true water "
                  "index n3 = 1.33·(1 + 0.0015); the measurement assumes the calibrated 1.33 "
                  "(calibrated value 0.15 % too low)",
    "measurement": "the measurement carries the deviation: pixels simulated with n3 = 1.33; the "
                   "measurement assumes 1.33·(1 + 0.0015) (calibrated value 0.15 % too high)",
}


def run_index_in_situ(rig: Rig, trials: int, seed: int,
                      variance: float = NOISE_VARIANCE_PX2,
                      index_relative: float = INDEX_RELATIVE, z: float = DISTANCES_MM[0],
                      progress: bool = False) -> dict:
    """The paper's future work: the water index estimated from the measurement itself.

    Truth ``n_water · (1 + index_relative)``, the measurement assumes ``n_water``; each trial
    draws Gaussian pixel noise (``numpy.random.default_rng([seed, 1])``: its own stream of the
    one seed), estimates the index with :func:`measure.calibration.selfcal.self_calibrate` and measures
    again. Also the profile of the reprojection RMS against the assumed index (trial 0's pixels,
    every point at its reprojection optimum) for the figure."""
    from tqdm import tqdm

    from measure.stereo.reprojection import reprojection_points
    from measure.calibration.selfcal import self_calibrate

    truth = paper_plane(z)
    true_port = deviate_port(rig.port, "n_water", index_relative)
    clean = project_pair(rig, truth, true_port)
    rng = np.random.default_rng([seed, 1])
    sigma = float(np.sqrt(variance))
    estimates, sigmas, dz_before, dz_after, first = [], [], [], [], None
    for _ in tqdm(range(trials), desc="index in situ", disable=not progress, leave=False):
        uv = [c + rng.normal(0.0, sigma, c.shape) for c in clean]
        first = uv if first is None else first
        fit = self_calibrate(rig, uv[0], uv[1])
        estimates.append(fit.estimates.get("n_water", np.nan))
        sigmas.append(fit.sigmas.get("n_water", np.nan))
        dz_before.append(float(np.mean(triangulate(rig, uv[0], uv[1]).points[:, 2] - truth[:, 2])))
        dz_after.append(float(np.mean(triangulate(fit.rig, uv[0], uv[1]).points[:, 2] - truth[:, 2])))
    n_true = true_port.n_water
    errors = np.array(estimates) - n_true
    spread = float(np.std(errors, ddof=1)) if trials > 1 else float("nan")
    half = max(6.0 * float(np.nanmean(sigmas)), 5e-4)
    grid = np.linspace(n_true - half, n_true + half, 25)
    profile = []
    for n in grid:
        trial_rig = rig.with_port(rig.port.replace(indices=rig.port.indices[:-1] + (float(n),)))
        start = triangulate(trial_rig, first[0], first[1]).points
        _, rms, _ = reprojection_points(trial_rig, first[0], first[1], start)
        profile.append(float(np.sqrt(np.nanmean(rms ** 2))))
    return {"z_mm": z, "trials": trials, "sigma_px": sigma, "n_true": n_true,
            "n_assumed": rig.port.n_water, "estimates": estimates, "sigmas": sigmas,
            "bias": float(np.mean(errors)), "spread": spread,
            "bias_sem": spread / np.sqrt(trials) if trials > 1 else float("nan"),
            "mean_sigma": float(np.nanmean(sigmas)),
            "mean_dz_before_mm": float(np.mean(dz_before)),
            "mean_dz_after_mm": float(np.mean(dz_after)),
            "profile": {"n": grid.tolist(), "rms_px": profile, "trial": 0}}


def run_experiments(trials: int = 100, seed: int = 0, *, variance: float = NOISE_VARIANCE_PX2,
                    index_relative: float = INDEX_RELATIVE, progress: bool = False) -> dict:
    """All of section 3. Returns a dict with arrays (for figures) and stats (for the report)."""
    start = time.perf_counter()
    rig = paper_rig()
    air_rig = paper_rig(in_air=True)
    gap = run_gap(rig)
    ideal = run_ideal(rig, air_rig)
    noise, index = run_noise(rig, air_rig, trials, seed, variance, index_relative,
                             progress=progress)
    in_situ = run_index_in_situ(rig, trials, seed, variance, index_relative, progress=progress)
    su_ideal = error_components(ideal[noise["z_mm"]]["errors"]["su"])["dP"]
    noise["su_ideal_mean_square_dP"] = float(np.mean(su_ideal ** 2))
    noise["su_model_error_share"] = float(
        noise["su_ideal_mean_square_dP"] / noise["stats"]["su"].dp.rms_mm ** 2)
    results = {
        "settings": {"trials": int(trials), "seed": int(seed), "pixel_noise_variance_px2": variance,
                     "pixel_noise_sigma_px": float(np.sqrt(variance)),
                     "index_deviation_relative": index_relative,
                     "distances_mm": list(DISTANCES_MM), "gap_threshold_mm": GAP_THRESHOLD_MM,
                     "near_zero_rule": f"|mean| < {SEM_FACTOR:g} noise standard errors of the "
                                       "mean (SEM = std of (noisy - noise-free error) over "
                                       "trials x 496 / sqrt(trials x 496)); index shifts are "
                                       "'beyond the noise' when |shift| > 3 SEM",
                     "noise_draws": "one Gaussian draw per trial, target, image and axis; the "
                                    "same offsets are used for every noisy run (water, air, both "
                                    "index sides)"},
        "rig": rig_description(rig, air_rig),
        "targets": {"layout": "synth.scene.layouts.paper_plane: centre + 15 circles (40 … 600 mm) "
                              "x 33 points", "count": int(gap["targets"].shape[0])},
        "gap": gap, "ideal": ideal, "noise": noise, "index": index, "in_situ": in_situ,
    }
    results["compute_seconds"] = time.perf_counter() - start
    results["claims"] = evaluate_claims(results)
    return results


# --------------------------------------------------------------------------------------------
# claims
