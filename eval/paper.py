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
them. The CLI (``add_parser``/``main``) writes ``report.json``, ``report.md`` and the figures.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from measure import Reason, StereoRig, triangulate
from synth.layouts import paper_plane
from synth.noise import deviate_port, pixel_noise
from synth.project import project
from synth.rig import paper_rig

from eval.paper_settings import (COMPONENTS, DISTANCES_MM, GAP_THRESHOLD_MM,  # noqa: F401
                                 IDEAL_TOLERANCE_MM, INDEX_METHODS, INDEX_RELATIVE, INDEX_SIDES,
                                 NAME, NOISE_METHODS, NOISE_VARIANCE_PX2, PAPER_REFERENCE,
                                 SEM_FACTOR, SHIFT_AGREEMENT_MM)
from eval.results import ErrorStats


# --------------------------------------------------------------------------------------------
# statistics


def error_components(errors: np.ndarray) -> dict[str, np.ndarray]:
    """``{dX, dY, dZ, dP}`` from errors ``(..., 3)`` (measured − true, mm), flattened."""
    flat = np.asarray(errors, dtype=np.float64).reshape(-1, 3)
    return {"dX": flat[:, 0], "dY": flat[:, 1], "dZ": flat[:, 2],
            "dP": np.linalg.norm(flat, axis=1)}


def error_stats(errors: np.ndarray) -> ErrorStats:
    """:class:`eval.results.ErrorStats` of errors ``(..., 3)`` (measured − true, mm): per
    component n, min, max, max_abs, mean, std, sem, rms. ``sem`` = std / sqrt(n) over all rows:
    it counts any deterministic per-target error (Su's model error) as spread; the noise
    yardstick of the claims is ``noise_sem`` instead. NaN rows are left out and counted."""
    return ErrorStats.of(errors)


# --------------------------------------------------------------------------------------------
# experiments


def rig_description(rig: StereoRig, air_rig: StereoRig) -> dict:
    """The rig as plain numbers (mm, px, degrees) for the report."""
    def camera(cam):
        return {"K": cam.K.tolist(), "size_px": list(cam.size), "R": cam.R.tolist(),
                "t_mm": cam.t.tolist(), "center_mm": cam.center.tolist()}
    toe_in = np.degrees(np.arctan2(-rig.right.R[0, 2], rig.right.R[2, 2]))
    port = rig.port
    return {
        "source": "synth.rig.paper_rig() (the paper does not give intrinsics, baseline or size)",
        "left": camera(rig.left), "right": camera(rig.right),
        "baseline_mm": float(np.linalg.norm(rig.right.center - rig.left.center)),
        "right_toe_in_deg": float(toe_in),
        "port": {"normal": port.normal.tolist(), "distance_mm": port.distance,
                 "thicknesses_mm": list(port.thicknesses), "indices": list(port.indices)},
        "air_copy_port_indices": list(air_rig.port.indices),
        "frame": "left camera, OpenCV axes (x right, y down, z forward), mm",
    }


def _project_pair(rig: StereoRig, points: np.ndarray, port=None):
    port = rig.port if port is None else port
    return project(rig.left, port, points), project(rig.right, port, points)


def _errors(rig: StereoRig, uv_left, uv_right, method: str, truth: np.ndarray):
    result = triangulate(rig, uv_left.reshape(-1, 2), uv_right.reshape(-1, 2), method)
    shape = uv_left.shape[:-1] + (3,)
    errors = (result.points - truth.reshape(-1, 3)).reshape(shape)
    return errors, result


def run_gap(rig: StereoRig, z: float = DISTANCES_MM[0]) -> dict:
    """Section 3.2: the gap between rays O_L A1 and O_R B1 for the 496 targets at ``z`` mm."""
    targets = paper_plane(z)
    uv_left, uv_right = _project_pair(rig, targets)
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


def run_ideal(rig: StereoRig, air_rig: StereoRig, distances=DISTANCES_MM) -> dict:
    """Section 3.3.1: errors (496, 3) per method per distance, no noise, exact parameters."""
    out = {}
    for z in distances:
        targets = paper_plane(z)
        uv_left, uv_right = _project_pair(rig, targets)
        air_left, air_right = _project_pair(air_rig, targets)
        errors = {
            "optical_path": _errors(rig, uv_left, uv_right, "optical_path", targets)[0],
            "su": _errors(rig, uv_left, uv_right, "su", targets)[0],
            "regular_in_air": _errors(air_rig, air_left, air_right, "regular", targets)[0],
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


def run_noise(rig: StereoRig, air_rig: StereoRig, trials: int, seed: int,
              variance: float = NOISE_VARIANCE_PX2, index_relative: float = INDEX_RELATIVE,
              z: float = DISTANCES_MM[0], progress: bool = False) -> tuple[dict, dict]:
    """Sections 3.3.2 and 3.3.3: Monte Carlo over ``trials`` draws of pixel noise.

    Errors are ``(trials, 496, 3)`` mm. One vectorized ``triangulate`` call per method and run
    (``trials × 496`` rows). Returns ``(noise, index)``.
    """
    from tqdm import tqdm

    trials = int(trials)
    if trials < 1:
        raise ValueError(f"trials must be >= 1, got {trials}")
    targets = paper_plane(z)
    n = targets.shape[0]
    truth = np.broadcast_to(targets, (trials, n, 3))
    rng = np.random.default_rng(seed)
    # one draw per trial, target and image; the same offsets serve every noisy run
    offset_left = pixel_noise((trials, n, 2), variance, rng)
    offset_right = pixel_noise((trials, n, 2), variance, rng)

    water_left, water_right = _project_pair(rig, targets)
    air_left, air_right = _project_pair(air_rig, targets)
    true_port = {"simulation": deviate_port(rig.port, "n_water", index_relative),
                 "measurement": rig.port}
    assumed_rig = {"simulation": rig,
                   "measurement": rig.with_port(deviate_port(rig.port, "n_water",
                                                             index_relative))}

    bar = tqdm(total=trials * (len(NOISE_METHODS) + len(INDEX_SIDES) * len(INDEX_METHODS)),
               unit="trial", desc="paper Monte Carlo", disable=not progress, file=sys.stderr,
               leave=False)
    with bar:
        noise_errors = {}
        for method in NOISE_METHODS:
            bar.set_postfix_str(f"noise {method}")
            if method == "regular_in_air":
                noise_errors[method] = _errors(air_rig, air_left + offset_left,
                                               air_right + offset_right, "regular", truth)[0]
            else:
                noise_errors[method] = _errors(rig, water_left + offset_left,
                                               water_right + offset_right, method, truth)[0]
            bar.update(trials)
        index_errors = {}
        for side in INDEX_SIDES:
            sim_left, sim_right = _project_pair(rig, targets, true_port[side])
            index_errors[side] = {}
            for method in INDEX_METHODS:
                bar.set_postfix_str(f"index {side} {method}")
                index_errors[side][method] = _errors(assumed_rig[side], sim_left + offset_left,
                                                     sim_right + offset_right, method, truth)[0]
                bar.update(trials)

    noise_stats = {m: error_stats(e) for m, e in noise_errors.items()}
    # The standard error of a mean caused by the pixel noise: the spread of (noisy − noise-free)
    # errors over targets × trials, / sqrt(samples). The per-target noise-free error (Su's model
    # error) is the same in every run and is not noise, so it is left out of this yardstick.
    noise_free = {
        "optical_path": _errors(rig, water_left, water_right, "optical_path", targets)[0],
        "su": _errors(rig, water_left, water_right, "su", targets)[0],
        "regular_in_air": _errors(air_rig, air_left, air_right, "regular", targets)[0]}
    noise_sem = {}
    for method in NOISE_METHODS:
        noisy = error_components(noise_errors[method])
        clean = error_components(np.broadcast_to(noise_free[method], (trials, n, 3)))
        noise_sem[method] = {}
        for c in COMPONENTS:
            part = noisy[c] - clean[c]
            part = part[np.isfinite(part)]
            noise_sem[method][c] = (float(np.std(part, ddof=1) / np.sqrt(part.size))
                                    if part.size > 1 else float("nan"))
    noise = {"z_mm": float(z), "trials": trials, "seed": int(seed), "variance_px2": variance,
             "sigma_px": float(np.sqrt(variance)), "samples": trials * n, "targets": targets,
             "errors": noise_errors, "stats": noise_stats,
             "noise_sem": noise_sem,
             "su_share_dZ_negative": float(np.nanmean(noise_errors["su"][..., 2] < 0)),
             "optical_path_share_abs_dX_within_1mm":
                 float(np.nanmean(np.abs(noise_errors["optical_path"][..., 0]) <= 1.0))}

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
    n_true = {side: true_port[side].n_water for side in INDEX_SIDES}
    n_assumed = {side: assumed_rig[side].port.n_water for side in INDEX_SIDES}
    index = {
        "z_mm": float(z), "relative": index_relative, "chosen_side": chosen, "rule": rule,
        "sides": {side: {
            "description": ("the simulation carries the deviation: pixels simulated with the "
                            "true water index n3 = 1.33·(1 + 0.0015); the measurement assumes "
                            "the calibrated 1.33 (calibrated value 0.15 % too low)"
                            if side == "simulation" else
                            "the measurement carries the deviation: pixels simulated with "
                            "n3 = 1.33; the measurement assumes 1.33·(1 + 0.0015) "
                            "(calibrated value 0.15 % too high)"),
            "n_water_true": n_true[side], "n_water_assumed": n_assumed[side],
            "stats": stats[side], "mean_shift": shifts[side]} for side in INDEX_SIDES},
        "errors": index_errors,
        "noise_sem": sem,
    }
    return noise, index


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
        "targets": {"layout": "synth.layouts.paper_plane: centre + 15 circles (40 … 600 mm) "
                              "x 33 points", "count": int(gap["targets"].shape[0])},
        "gap": gap, "ideal": ideal, "noise": noise, "index": index,
    }
    results["compute_seconds"] = time.perf_counter() - start
    results["claims"] = evaluate_claims(results)
    return results


# --------------------------------------------------------------------------------------------
# claims


def _fmt(x: float, unit: str = "mm") -> str:
    if x is None or not np.isfinite(x):
        return "n/a"
    text = f"{x:.3g}" if 1e-3 <= abs(x) < 1e4 or x == 0 else f"{x:.2e}"
    return f"{text} {unit}".strip()


def _claim(claim_id, section, paper, measured, criterion, holds, **values):
    return {"id": claim_id, "section": section, "paper": paper, "measured": measured,
            "criterion": criterion, "holds": bool(holds),
            "values": {k: (float(v) if isinstance(v, (float, np.floating)) else v)
                       for k, v in values.items()}}


def evaluate_claims(results: dict) -> list[dict]:
    """The paper's claims against the measured numbers; ``holds`` is computed, never set."""
    claims = []
    gap = results["gap"]["stats"]
    claims.append(_claim(
        "gap.share_nonintersecting", "3.2",
        "more than 90 % of the 496 targets have rays O_L A1, O_R B1 with a common perpendicular "
        "> 1e-6 mm (they do not intersect)",
        f"{100 * gap['share_above_threshold']:.1f} % ({gap['count_above_threshold']}/{gap['n']})",
        "share of targets with gap > 1e-6 mm > 0.9",
        gap["share_above_threshold"] > 0.9, share=gap["share_above_threshold"]))
    claims.append(_claim(
        "gap.most_above_0.6mm", "3.2",
        "the common perpendicular of most targets is greater than 0.6 mm",
        f"{100 * gap['share_above_0.6mm']:.1f} % of targets > 0.6 mm "
        f"(median {_fmt(gap['median'])})",
        "share of targets with gap > 0.6 mm > 0.5", gap["share_above_0.6mm"] > 0.5,
        share=gap["share_above_0.6mm"], median_mm=gap["median"]))
    claims.append(_claim(
        "gap.grows_outwards", "3.2",
        "the closer to the centre of the area, the smaller the common perpendicular",
        f"Spearman rho(gap, radius) = {gap['spearman_rho_vs_radius']:.2f}",
        "Spearman rank correlation of gap with the target's radius > 0.5",
        gap["spearman_rho_vs_radius"] > 0.5, rho=gap["spearman_rho_vs_radius"]))

    ideal = results["ideal"]
    for z, paper_words in ((1000.0, "order of 1e-11 mm"), (2000.0, "order of 1e-10 or 1e-11 mm")):
        for method, label in (("optical_path", "optical-path (new) model"),
                              ("regular_in_air", "regular triangulation in air")):
            value = ideal[z]["stats"][method].dp.max_mm
            claims.append(_claim(
                f"ideal.{method}.{z / 1000:g}m.max_dP", "3.3.1",
                f"{label}, no errors, {z / 1000:g} m: deviations of the {paper_words} "
                "(numerical error only)",
                f"max dP = {_fmt(value)}", f"max dP <= {IDEAL_TOLERANCE_MM:g} mm",
                value is not None and value <= IDEAL_TOLERANCE_MM, max_dP_mm=value))
    for z, limit, words in ((1000.0, 50.0, "the maximum dP exceeds 50 mm"),
                            (2000.0, 7.0, "the maximum dP is still more than 7 mm")):
        value = ideal[z]["stats"]["su"].dp.max_mm
        claims.append(_claim(
            f"ideal.su.{z / 1000:g}m.max_dP", "3.3.1", f"Su's method, {z / 1000:g} m: {words}",
            f"max dP = {value:.4f} mm", f"max dP > {limit:g} mm", value > limit,
            max_dP_mm=value))
    rho = ideal[1000.0]["su_spearman_rho_dP_vs_radius"]
    claims.append(_claim(
        "ideal.su.1m.centre_vs_edge", "3.3.1",
        "Su: targets near the centre of the field of view are close to their true value, "
        "targets at the edge deviate by a large margin",
        f"Spearman rho(dP, radius) = {rho:.2f}; centre target dP = "
        f"{_fmt(float(np.linalg.norm(ideal[1000.0]['errors']['su'][0])))}",
        "Spearman rank correlation of Su's dP with the target's radius > 0.5", rho > 0.5,
        rho=rho))
    s1, s2 = ideal[1000.0]["su_share_dP_within_1mm"], ideal[2000.0]["su_share_dP_within_1mm"]
    m1, m2 = ideal[1000.0]["stats"]["su"].dp.max_mm, ideal[2000.0]["stats"]["su"].dp.max_mm
    claims.append(_claim(
        "ideal.su.2m_better", "3.3.1",
        "at 2 m Su's results improve and the area inside the ±1 mm contour becomes larger",
        f"max dP {m1:.3f} -> {m2:.3f} mm; targets with dP <= 1 mm {100 * s1:.0f} % -> "
        f"{100 * s2:.0f} %",
        "max dP(2 m) < max dP(1 m) and share(dP <= 1 mm) larger at 2 m",
        (m2 < m1) and (s2 > s1), share_1m=s1, share_2m=s2))

    noise = results["noise"]
    ns = noise["stats"]
    rms = {m: ns[m].dp.rms_mm for m in NOISE_METHODS}
    claims.append(_claim(
        "noise.optical_path_beats_su", "3.3.2",
        "with pixel noise (variance 0.01 px²) the new model is more accurate than Su's",
        f"RMS dP {rms['optical_path']:.3f} mm vs {rms['su']:.3f} mm",
        "RMS dP(optical_path) < RMS dP(su)", rms["optical_path"] < rms["su"],
        rms_optical_path=rms["optical_path"], rms_su=rms["su"]))
    claims.append(_claim(
        "noise.optical_path_beats_regular_in_air", "3.3.2",
        "our method even outperforms the regular model in the air",
        f"RMS dP {rms['optical_path']:.3f} mm vs {rms['regular_in_air']:.3f} mm",
        "RMS dP(optical_path) < RMS dP(regular in air)",
        rms["optical_path"] < rms["regular_in_air"],
        rms_optical_path=rms["optical_path"], rms_regular_in_air=rms["regular_in_air"]))
    xyz_better = {c: ns["optical_path"].component(c).rms_mm < ns["regular_in_air"].component(c).rms_mm
                  for c in ("dX", "dY", "dP")}
    claims.append(_claim(
        "noise.optical_path_xy_minimal", "3.3.2",
        "the deviations of the X, Y and total coordinates of the new method are minimal "
        "(compared with regular triangulation in air)",
        ", ".join(f"{c} {ns['optical_path'].component(c).rms_mm:.3f} vs {ns['regular_in_air'].component(c).rms_mm:.3f}"
                  for c in ("dX", "dY", "dP")) + " mm RMS",
        "RMS of dX, dY and dP each smaller for optical_path than for regular in air",
        all(xyz_better.values())))
    op = ns["optical_path"]
    within = noise["optical_path_share_abs_dX_within_1mm"]
    claims.append(_claim(
        "noise.optical_path_x_within_1mm", "3.3.2",
        "the deviation in X was minimal, generally within ±1 mm",
        f"{100 * within:.2f} % of |dX| <= 1 mm (σX = {op.dx.std_mm:.3f} mm)",
        "share of |dX| <= 1 mm >= 0.95 (optical_path)", within >= 0.95, share=within))
    z_largest = op.dz.std_mm > max(op.dx.std_mm, op.dy.std_mm)
    claims.append(_claim(
        "noise.optical_path_z_largest", "3.3.2",
        "the deviation in Z was the largest, exceeding ±2 mm",
        f"σ = {op.dx.std_mm:.3f} / {op.dy.std_mm:.3f} / {op.dz.std_mm:.3f} mm (X/Y/Z); "
        f"max |dZ| = {op.dz.max_abs_mm:.2f} mm",
        "σZ > σX, σY and max |dZ| > 2 mm (optical_path)",
        z_largest and op.dz.max_abs_mm > 2.0, max_abs_dZ=op.dz.max_abs_mm))
    nsem = noise["noise_sem"]
    ratios = {c: abs(op.component(c).mean_mm) / nsem["optical_path"][c] for c in ("dX", "dY", "dZ")}
    claims.append(_claim(
        "noise.optical_path_mean_near_zero", "3.3.2",
        "the means of the three coordinate deviations of our model are all close to 0",
        "mean " + " / ".join(f"{op.component(c).mean_mm:+.4f}" for c in ("dX", "dY", "dZ"))
        + " mm = " + " / ".join(f"{ratios[c]:.1f}" for c in ("dX", "dY", "dZ")) + " SEM",
        f"|mean| < {SEM_FACTOR:g} SEM for dX, dY and dZ",
        all(r < SEM_FACTOR for r in ratios.values()),
        **{f"mean_{c}": op.component(c).mean_mm for c in ("dX", "dY", "dZ")},
        **{f"sem_{c}": nsem["optical_path"][c] for c in ("dX", "dY", "dZ")}))
    su = ns["su"]
    claims.append(_claim(
        "noise.su_dZ_negative", "3.3.2",
        "Su's Z coordinate deviations are all negative (systematic)",
        f"mean dZ = {su.dz.mean_mm:.3f} mm ({su.dz.mean_mm / nsem['su']['dZ']:.0f} SEM); "
        f"{100 * noise['su_share_dZ_negative']:.1f} % of dZ < 0",
        f"mean dZ < -{SEM_FACTOR:g} SEM (systematically negative)",
        su.dz.mean_mm < -SEM_FACTOR * nsem["su"]["dZ"],
        mean_dZ=su.dz.mean_mm, share_negative=noise["su_share_dZ_negative"]))
    su_ratios = {c: abs(su.component(c).mean_mm) / nsem["su"][c] for c in ("dX", "dY")}
    claims.append(_claim(
        "noise.su_xy_mean_near_zero", "3.3.2",
        "Su's X and Y coordinate deviations are also close to 0",
        "mean " + " / ".join(f"{su.component(c).mean_mm:+.3f}" for c in ("dX", "dY")) + " mm = "
        + " / ".join(f"{su_ratios[c]:.1f}" for c in ("dX", "dY")) + " SEM",
        f"|mean| < {SEM_FACTOR:g} SEM for dX and dY (su)",
        all(r < SEM_FACTOR for r in su_ratios.values()),
        mean_dX=su.dx.mean_mm, mean_dY=su.dy.mean_mm))
    share = noise["su_model_error_share"]
    claims.append(_claim(
        "noise.su_dominated_by_model_error", "3.3.2",
        "with noise, Su's results are still primarily influenced by model error",
        f"noise-free mean-square dP is {100 * share:.1f} % of the noisy one",
        "mean-square dP without noise / with noise > 0.5", share > 0.5, share=share))

    index = results["index"]
    side = index["chosen_side"]
    shifts = index["sides"][side]["mean_shift"]
    sem = index["noise_sem"]
    side_text = f"[{side} side]"
    for axis in ("dX", "dZ"):
        ok = all(shifts[m][axis] < -SEM_FACTOR * sem[m][axis] for m in INDEX_METHODS)
        claims.append(_claim(
            f"index.{axis}_mean_shift_negative", "3.3.3",
            f"with the 0.15 % water-index deviation the mean {axis} of both models moves in the "
            "negative direction",
            f"{side_text} shift optical_path {shifts['optical_path'][axis]:+.4f} mm, "
            f"su {shifts['su'][axis]:+.4f} mm (SEM {sem['optical_path'][axis]:.4f} mm)",
            f"shift < -{SEM_FACTOR:g} noise SEM, both models", ok,
            shift_optical_path=shifts["optical_path"][axis], shift_su=shifts["su"][axis]))
    systematic = all(abs(shifts[m][a]) > SEM_FACTOR * sem[m][a]
                     for m in INDEX_METHODS for a in ("dX", "dZ"))
    claims.append(_claim(
        "index.xz_shift_systematic", "3.3.3",
        "the water-index deviation gives small systematic errors in X and Z",
        f"{side_text} |shift| / SEM: " + ", ".join(
            f"{m} {a} {abs(shifts[m][a]) / sem[m][a]:.0f}"
            for m in INDEX_METHODS for a in ("dX", "dZ")),
        f"|shift| > {SEM_FACTOR:g} noise SEM (dX and dZ, both models)",
        systematic))
    y_ok = all(abs(shifts[m]["dY"]) < SEM_FACTOR * sem[m]["dY"] for m in INDEX_METHODS)
    claims.append(_claim(
        "index.dY_unchanged", "3.3.3",
        "the distribution of the Y deviation does not change (both models)",
        f"{side_text} shift optical_path {shifts['optical_path']['dY']:+.1e} mm, "
        f"su {shifts['su']['dY']:+.1e} mm (SEM {sem['optical_path']['dY']:.1e} mm)",
        f"|shift dY| < {SEM_FACTOR:g} SEM, both models", y_ok))
    diffs = {a: abs(shifts["su"][a] - shifts["optical_path"][a]) for a in ("dX", "dY", "dZ")}
    claims.append(_claim(
        "index.models_alike", "3.3.3",
        "the magnitude of the change is the same for Su's model as for ours",
        f"{side_text} |shift(su) - shift(optical_path)| = "
        + " / ".join(f"{diffs[a]:.3f}" for a in ("dX", "dY", "dZ")) + " mm (X/Y/Z)",
        f"mean shifts agree within {SHIFT_AGREEMENT_MM:g} mm in X, Y and Z",
        all(d <= SHIFT_AGREEMENT_MM for d in diffs.values()), **diffs))
    op_rms_noise = ns["optical_path"].dp.rms_mm
    op_rms_index = index["sides"][side]["stats"]["optical_path"].dp.rms_mm
    claims.append(_claim(
        "index.optical_path_error_increases", "3.3.3",
        "compared with Figure 7 the deviations of our model have (slightly) increased",
        f"{side_text} RMS dP {op_rms_noise:.3f} -> {op_rms_index:.3f} mm",
        "RMS dP with the deviation > RMS dP without (optical_path)",
        op_rms_index > op_rms_noise, before=op_rms_noise, after=op_rms_index))
    su_rms_noise = ns["su"].dp.rms_mm
    su_rms_index = index["sides"][side]["stats"]["su"].dp.rms_mm
    change = abs(su_rms_index / su_rms_noise - 1.0)
    claims.append(_claim(
        "index.su_basically_unchanged", "3.3.3",
        "compared with Figure 7 the deviation of Su's model is basically unchanged",
        f"{side_text} RMS dP {su_rms_noise:.2f} -> {su_rms_index:.2f} mm "
        f"({100 * change:.1f} % change)",
        "RMS dP of su changes by less than 10 %", change < 0.10, relative_change=change))
    return claims


# --------------------------------------------------------------------------------------------
# CLI


def add_parser(subparsers) -> None:
    """``python -m eval paper [--out DIR] [--trials N] [--seed S] [--no-progress]``."""
    from eval.cli import non_negative_int, positive_int

    parser = subparsers.add_parser(
        NAME, help="reproduce section 3 of Li et al. 2024 on the analytic simulator",
        description="Reproduce section 3 of Li et al. 2024 (ray gap, ideal, pixel noise, "
                    "water-index deviation) on the analytic simulator; writes report.json, "
                    "report.md and figures 4-10 (PNG) into --out.")
    parser.add_argument("--out", default="out/paper", metavar="DIR",
                        help="output directory (default: out/paper)")
    parser.add_argument("--trials", type=positive_int, default=100, metavar="N",
                        help="Monte-Carlo noise trials (default: 100)")
    parser.add_argument("--seed", type=non_negative_int, default=0, metavar="S",
                        help="seed of the pixel noise (default: 0)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def main(args) -> int:
    """Run the experiments and write the report and figures into ``args.out`` (whole or not at
    all; the ``--out`` rule of :class:`synth.fileio.OutputDir` is checked first)."""
    from eval.paper_figures import write_figures  # matplotlib: only when needed
    from eval.paper_report import write_reports
    from synth.fileio import OutputDir

    start = time.perf_counter()
    output = OutputDir(args.out, f"eval {NAME}").claim()
    results = run_experiments(args.trials, args.seed, progress=not args.no_progress)
    with output.staged() as tmp:
        figures = write_figures(results, tmp)
        results["wall_seconds"] = time.perf_counter() - start
        paths = write_reports(results, tmp, figures)
    held = sum(c["holds"] for c in results["claims"])
    print(f"paper: {held}/{len(results['claims'])} claims hold; wrote "
          f"{', '.join(str(Path(p).name) for p in paths)} and {len(figures)} figures to "
          f"{output.path} in {time.perf_counter() - start:.1f} s")
    return 0
