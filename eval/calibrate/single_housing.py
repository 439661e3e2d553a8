"""``python -m eval calibrate PHOTOS --intrinsics camera.yaml`` where ``PHOTOS`` holds ONE
camera's underwater photos (no ``left/`` and ``right/``): the housing of that camera — its flat
port's distance and normal, or its dome's decentring — by the stereo fit's refractive bundle
adjustment over the one camera's corners
(:func:`measure.calibration.housing.calibrate_camera_housing`).

``--intrinsics``: the camera's in-air calibration, ``camera.yaml`` of ``eval calibrate PHOTOS
--air`` (with its covariance: σ then includes the in-air calibration's, ``--air-uncertainty``),
calibmar's one-camera YAML or a one-camera COLMAP ``cameras.txt``
(:func:`synth.formats.calib_formats.read_single_camera`; those two carry no covariance: σ is
conditional on the intrinsics). Flat port or dome is chosen as for a stereo calibration, by the
design options: ``--dome-radius`` / ``--dome-thickness`` say a dome (start: a dome centred on
the camera), otherwise a flat port (``--start-distance``, ``--glass-thickness``,
``--design-port``); ``--n-glass``, ``--n-water`` and ``--free`` as for a pair (no
``extrinsics``: there is no second camera; behind a dome ``dome_center`` is the camera's
decentring, 3 numbers).

The report compares three reprojection RMS on the same photos (issue 35): the housing fit's,
the in-air calibration's (``rms_px`` of camera.yaml; the other files do not carry it) and a
pinhole fit that absorbs the port — ``cv2.calibrateCamera`` (the lens model chosen as ``--lens
auto`` chooses) on the same underwater corners, what a team that ignores refraction gets. The
pinhole fits its intrinsics to these photos and so nearly always has the lower RMS on them;
the two models are therefore compared on photos each was not fitted to
(:func:`measure.calibration.validation.cross_validate_housing`). The run fails (exit 1, files
written) when the housing RMS exceeds the in-air RMS by more than :data:`RMS_MARGIN_PX`, or the
housing predicts held-out photos significantly worse than the absorbed pinhole: a refractive
model that predicts worse than a model with no refraction has not found the port.

Writes to ``--out``: ``camera.yaml`` (the in-air camera as ``eval calibrate --air`` writes it,
with a ``port`` node — calib.yaml's, in the camera's frame, mm — or a ``dome`` node (``center``,
``radius``, ``thickness``, ``indices``), a ``housing`` map (free parameters, σ, the three RMS)
and the joint ``covariance``), ``calibmar.yaml`` (calibmar's one-camera file with its FLATPORT
or DOMEPORT), ``cameras.txt`` (one line for the refractive COLMAP fork), ``report.json``,
``report.md``, ``residuals.png`` and ``coverage.png``.
"""

from __future__ import annotations

import os

import numpy as np

from eval.calibrate.causes import FIT_ERRORS, housing_failure
from eval.calibrate import photos as trust
from eval.calibrate import photos_report
from eval.calibrate import report as report_lib
from eval.calibrate.report import format_value as _f
from eval.calibrate.single import (VIEW, note_set_aside, photo_lines, photo_rows, read_and_detect,
                                   write_camera_files)
from eval.cli import CLIError

#: Issue 35: the housing fit may leave at most this much more RMS than the in-air calibration.
RMS_MARGIN_PX = 0.15


def read_intrinsics(path):
    """``--intrinsics`` of one camera (:func:`synth.formats.calib_formats.read_single_camera`);
    CLIError naming the option and the file."""
    from synth.formats.calib_formats import CalibFormatError, read_single_camera

    if os.path.isdir(path):
        raise CLIError(f"--intrinsics {path}: a folder; give the camera's in-air calibration "
                       f"file (camera.yaml of eval calibrate PHOTOS --air, calibmar's YAML or a "
                       f"COLMAP cameras.txt)")
    try:
        return read_single_camera(path)
    except CalibFormatError as exc:
        raise CLIError(f"--intrinsics {exc}") from None


def calibrate_single_housing(args, output, log, start, board, intrinsics, start_port, free,
                             dome: bool) -> tuple[dict, str]:
    """The housing of the camera of ``args.dir`` (module docs); ``intrinsics``:
    :func:`read_intrinsics`; ``start_port``: the design port (a rig port whose view 0 is the
    camera's); ``dome``: whether it is a dome (the absorbed pinhole check applies to a flat
    port). Returns ``(report, summary)`` after writing everything into ``output``."""
    import time

    from measure.calibration.air import DEFAULT_LENS_MODEL, CalibrationError, calibrate_camera
    from measure.calibration.housing import calibrate_camera_housing
    from measure.calibration.validation import FOLDS, cross_validate_housing

    from eval.calibrate.dots import views_of_housing, with_eccentricity

    where = f"{args.dir} (one camera's photos)"
    camera = intrinsics["camera"]
    names, images, size, detections, timings, aside = read_and_detect(
        args, board, log, camera.size, f"--intrinsics {args.intrinsics}")

    def fit(dets):
        return calibrate_camera_housing(camera, start_port, board, dets, free,
                                        intrinsics["covariance"], args.air_uncertainty)

    fit = with_eccentricity(fit, board, views_of_housing)

    log(f"refractive bundle adjustment of {', '.join(free)} over "
        f"{len(detections.found(VIEW))} photos …")
    t = time.perf_counter()
    try:
        housing, used_detections, outliers = trust.fit_without_outliers(
            fit, lambda r: r.rms_px_per, detections, lambda r: r.residuals, board,
            lambda r: r.identifiable)
    except FIT_ERRORS as exc:
        raise housing_failure(where, exc, args) from None
    timings["bundle_adjustment"] = time.perf_counter() - t
    if not housing.identifiable:
        raise housing_failure(where, housing.reason, args)
    log("the pinhole fit that absorbs the port (OpenCV calibrateCamera on the same corners) …")
    t = time.perf_counter()
    used = list(housing.pose_ids)
    corners = board.corners().astype(np.float32)
    obj = [corners[used_detections.ids[k][VIEW]] for k in used]
    img = [used_detections.pixels[k][VIEW].astype(np.float32) for k in used]
    absorbed, model, tried, _ = calibrate_camera(obj, img, size, DEFAULT_LENS_MODEL)
    timings["absorbed_pinhole"] = time.perf_counter() - t
    log(f"both models predicting photos they were not fitted to ({min(len(used), FOLDS)} "
        f"groups held out in turn) …")
    t = time.perf_counter()
    try:
        validation = cross_validate_housing(fit, board, used_detections, size, model).to_dict()
    except CalibrationError as exc:
        validation = {"unavailable": str(exc)}
    timings["cross_validation"] = time.perf_counter() - t
    report = _report(args, board, names, size, detections, used_detections, housing, outliers,
                     intrinsics, {"rms_px": float(absorbed[0]), "model": model, "tried": tried,
                                  "cross_validation": validation}, dome)
    report["in_air_dependence"] = in_air_dependence(housing, intrinsics)
    note_set_aside(report, aside, names)
    report["timings_s"] = timings
    log("write the calibration, report and figures …")
    with output.staged() as tmp:
        sigmas = {k: float(v) for k, v in zip(
            ("fx", "fy", "cx", "cy"), np.sqrt(np.diag(intrinsics["covariance"].matrix))[:4])
        } if intrinsics["covariance"] is not None else {}
        write_camera_files(tmp, housing.rig.left, intrinsics["lens_model"], housing.rms_px,
                           sigmas, housing.covariance, housing.rig.port,
                           {"housing": _housing_node(report)})
        report_lib.residual_figure(tmp, used_detections, {VIEW: housing.residuals[VIEW]}, size,
                                   views=("camera",))
        photos_report.coverage_figure(tmp, detections, set(used), size,
                              {"coverage": {"camera": report["coverage"]}}, views=("camera",))
        report = report_lib.write_report(tmp, report, markdown, start)
    return report, summary_lines(report)


#: Housing numbers whose dependence on the in-air calibration the report shows.
DEPENDENCE_NAMES = ("port.distance", "left.dome_center[0]", "left.dome_center[1]",
                    "left.dome_center[2]", "port.index")


def in_air_dependence(housing, intrinsics) -> dict:
    """How the housing's numbers depend on the in-air calibration: ``{name: {sigma_mm,
    per_sigma {intrinsic: change}, sigma_photos}}`` for the port distance and the dome's
    centre (:data:`DEPENDENCE_NAMES`). ``per_sigma``: the change of the estimate when one
    in-air intrinsic moves by its σ of ``--intrinsics`` (``g = C_pθ Σ_air⁻¹``: the estimate's
    derivative by the in-air values, from the joint covariance of the fit — exact for the
    propagated covariance, the posterior's for the prior); ``sigma_photos``: the estimate's σ
    when the in-air intrinsics are as uncertain as their photo-to-photo spread
    (``covariance_photos`` of camera.yaml: ``sqrt(σ_conditional² + g Σ_photos gᵀ)``), None
    without it. Empty without an in-air covariance."""
    joint, prior = housing.covariance, intrinsics["covariance"]
    if joint is None or prior is None:
        return {}
    air = [n for n in prior.names if n in joint.names]
    if not air:
        return {}
    where = [joint.names.index(n) for n in air]
    sigma_air = prior.matrix[np.ix_([prior.names.index(n) for n in air],
                                    [prior.names.index(n) for n in air])]
    photos = intrinsics.get("covariance_photos")
    out = {}
    for name in joint.names:
        if not name.startswith(DEPENDENCE_NAMES) or name in air:
            continue
        i = joint.names.index(name)
        g = np.linalg.solve(sigma_air, joint.matrix[i, where])
        conditional = float(joint.matrix[i, i] - g @ sigma_air @ g)
        entry = {"sigma": float(np.sqrt(joint.matrix[i, i])),
                 "per_sigma": {n.split(".", 1)[1]: float(g[k] * np.sqrt(sigma_air[k, k]))
                               for k, n in enumerate(air)},
                 "sigma_photos": None}
        if photos is not None and all(n in photos.names for n in air):
            order = [photos.names.index(n) for n in air]
            spread = photos.matrix[np.ix_(order, order)]
            entry["sigma_photos"] = float(np.sqrt(max(conditional, 0.0) + g @ spread @ g))
        out[name] = entry
    return out


def _dependence_lines(dependence: dict) -> list:
    """report.md's table of :func:`in_air_dependence`."""
    if not dependence:
        return []
    names = list(next(iter(dependence.values()))["per_sigma"])
    lines = ["## How the housing depends on the in-air calibration", "",
             "The change of each estimate when one in-air intrinsic moves by its σ (of "
             "`--intrinsics`); σ photos: the estimate's σ were the intrinsics as uncertain as "
             "their photo-to-photo spread (camera.yaml's `covariance_photos`, the jackknife "
             "over the in-air photos).", "",
             "| estimate | σ | σ photos | " + " | ".join(names) + " |",
             "|---|---|---|" + "---|" * len(names)]
    for name, e in dependence.items():
        lines.append(f"| {name} | {e['sigma']:.4g} | {_f(e['sigma_photos'], 4)} | "
                     + " | ".join(f"{v:+.3g}" for v in e["per_sigma"].values()) + " |")
    return lines + [""]


def _estimates(housing) -> dict:
    """``{name: {estimate, sigma, sigma_conditional, unit}}`` of the free housing parameters;
    the normal also as its tilt from the camera's optical axis, σ in degrees."""
    out = {}
    axis = housing.rig.left.R[:, 2]
    for name, value in housing.estimates.items():
        sigma, conditional = housing.sigmas[name], housing.sigmas_conditional.get(name)
        if name == "normal":
            out[name] = {"estimate": value, "unit": "unit vector (camera frame)",
                         "tilt_deg": float(np.degrees(np.arccos(np.clip(
                             np.asarray(value) @ axis, -1.0, 1.0)))),
                         "sigma": np.degrees(sigma).tolist(),
                         "sigma_conditional": np.degrees(conditional).tolist(),
                         "sigma_unit": "deg (two tilts about axes ⟂ the normal)"}
        elif name == "dome_center":
            out[name] = {"estimate": value["left"], "unit": "mm (camera frame: the dome "
                                                            "centre relative to the camera)",
                         "sigma": sigma, "sigma_conditional": conditional}
        else:
            out[name] = {"estimate": value, "unit": "" if name == "n_water" else "mm",
                         "sigma": sigma, "sigma_conditional": conditional}
    return out


def _report(args, board, names, size, detections, used, housing, outliers, intrinsics,
            absorbed, dome: bool) -> dict:
    rows = photo_rows(names, detections, outliers, housing.rms_px_per, housing.pose_ids)
    in_air = intrinsics["rms_px"]
    rms = {"housing": housing.rms_px, "in_air": in_air, "absorbed_pinhole": absorbed["rms_px"],
           "absorbed_pinhole_model": absorbed["model"],
           "absorbed_pinhole_tried": absorbed["tried"], "margin_px": RMS_MARGIN_PX,
           "held_out": absorbed["cross_validation"]}
    failures, warnings = [], []
    if in_air is not None and housing.rms_px > in_air + RMS_MARGIN_PX:
        failures.append(f"the housing fit leaves a reprojection RMS of {housing.rms_px:.4f} px, "
                        f"more than the in-air calibration's {in_air:.4f} px + "
                        f"{RMS_MARGIN_PX:g} px: the design port (glass thickness, indices, "
                        f"dome radius) or the in-air calibration does not fit these photos")
    validation = absorbed["cross_validation"]
    if validation.get("housing_worse"):
        failures.append(f"the housing predicts photos it was not fitted to worse than a pinhole "
                        f"camera that absorbs the port (held-out RMS "
                        f"{validation['housing_rms_px']:.4f} against "
                        f"{validation['pinhole_rms_px']:.4f} px, {validation['photos']} photos in "
                        f"{validation['folds']} groups): it has not found the port")
    elif "unavailable" in validation:
        warnings.append(f"the housing could not be compared with the absorbed pinhole on "
                        f"held-out photos: {validation['unavailable']}")
    if in_air is None:
        warnings.append(f"--intrinsics {args.intrinsics} carries no in-air RMS (a "
                        f"{intrinsics['format']} file): the housing RMS is not checked against "
                        f"it")
    used_poses = [k for k in housing.pose_ids]
    if len(used_poses) < trust.RECOMMENDED_POSES:
        warnings.append(f"only {len(used_poses)} photo(s) used; at least "
                        f"{trust.RECOMMENDED_POSES} are recommended")
    coverage = trust.coverage(used, size)["left"]
    if coverage["fraction"] < trust.MIN_COVERAGE:
        warnings.append(f"the corners cover {100 * coverage['fraction']:.0f} % of the image "
                        f"({trust.COVERAGE_CELLS}×{trust.COVERAGE_CELLS} cells)")
    labels = list(housing.labels)
    if len(labels) > 1:
        c = np.abs(np.triu(np.asarray(housing.correlation), 1))
        i, j = np.unravel_index(np.argmax(c), c.shape)
        if c[i, j] >= trust.HIGH_CORRELATION:
            warnings.append(f"{labels[i]} and {labels[j]} are correlated at "
                            f"{housing.correlation[i][j]:+.3f}: these photos barely tell them "
                            f"apart")
    if outliers["left_out"]:
        warnings.append(f"{len(outliers['left_out'])} outlier photo(s) left out of the final "
                        f"fit: {', '.join(names[k] for k in outliers['left_out'])}")
    if trust.corners_warning(outliers):
        warnings.append(trust.corners_warning(outliers))
    edge = trust.unseen_edge(board, detections, (VIEW,))
    if edge:
        warnings.append(edge)
    port = housing.rig.port.describe()
    return {"photos": os.path.abspath(args.dir), "source": "photos", "air": False,
            "cameras": 1, "housing_kind": housing.rig.port.kind,
            "dome": dome, "intrinsics": os.path.abspath(args.intrinsics),
            "intrinsics_format": intrinsics["format"], "board": board.to_dict(),
            "image_size": list(size), "poses": len(names),
            "found": len(detections.found(VIEW)), "used": len(used_poses),
            "outlier_rule": trust.OUTLIER_RULE, "outliers": outliers, "per_pose": rows,
            "coverage": coverage, "free": list(dict.fromkeys(
                label.split("[")[0] for label in labels)), "labels": labels,
            "correlation": np.asarray(housing.correlation).tolist(),
            "estimates": _estimates(housing), "uncertainty": housing.uncertainty,
            "sigma_note": sigma_note(housing.uncertainty), "rms_px": rms,
            "port": port.get("left", port),  # a dome: the camera's (the left of the pair)
            "observations": housing.n_observations, "evaluations": housing.nfev,
            "worst_corners": trust.worst_corners({"camera": housing.residuals[VIEW]}, names),
            "warnings": warnings, "failures": failures}


def sigma_note(mode: str) -> str:
    """What σ covers in a one-camera housing calibration."""
    if mode == "conditional":
        return ("σ is the housing fit's own (its corners' scatter), with the intrinsics held at "
                "the in-air calibration, whose file carried no covariance: the in-air "
                "calibration's errors are not in it.")
    how = ("propagated through the adjustment" if mode == "propagate"
           else "as a prior on the intrinsics, freed in the adjustment")
    return (f"σ includes the in-air calibration's uncertainty (camera.yaml's covariance of fx "
            f"fy cx cy k1 k2 p1 p2) {how}; σ (conditional) holds the intrinsics exact.")


def _housing_node(report: dict) -> dict:
    """camera.yaml's ``housing`` map: free parameters, their σ, the three RMS."""
    node = {"free": report["free"], "uncertainty": report["uncertainty"],
            "rms_px": report["rms_px"]["housing"],
            "absorbed_pinhole_rms_px": report["rms_px"]["absorbed_pinhole"]}
    if report["rms_px"]["in_air"] is not None:
        node["in_air_rms_px"] = report["rms_px"]["in_air"]
    node["sigma"] = {name: e["sigma"] for name, e in report["estimates"].items()}
    return node


def _value(e) -> str:
    value = e["estimate"]
    if isinstance(value, list):
        return "(" + ", ".join(f"{v:.6g}" for v in value) + ")"
    return f"{value:.6g}"


def markdown(report: dict) -> str:
    b, r = report["board"], report["rms_px"]
    lines = [f"# Housing calibration of one camera: `{report['photos']}`", "",
             f"{report['poses']} photos ({report['image_size'][0]}x{report['image_size'][1]} px) "
             f"of one camera underwater, a {b['kind']} of {b['squares'][0]}x{b['squares'][1]} "
             f"squares, {b['square_mm']:g} mm; board found in {report['found']}, "
             f"{report['used']} in the final fit; in-air calibration `{report['intrinsics']}` "
             f"({report['intrinsics_format']}). No truth: every number below comes from the "
             f"photos.", ""]
    lines += trust.verdict_lines(report)
    lines += ["## Housing", "", f"Behind {'a dome' if report['dome'] else 'a flat port'}; free: "
              f"{', '.join(report['free'])}. {report['sigma_note']}", "",
              "| parameter | estimate | σ | σ (conditional) | unit |", "|---|---|---|---|---|"]
    for name, e in report["estimates"].items():
        lines.append(f"| {name} | {_value(e)} | {_f(e['sigma'], 3)} | "
                     f"{_f(e['sigma_conditional'], 3)} | "
                     f"{e.get('sigma_unit', e['unit'])} |")
        if name == "normal":
            lines.append(f"| tilt from the optical axis | {e['tilt_deg']:.4f}° | | | deg |")
    lines += ["", f"Port: `{report['port']}`.", "", "## Reprojection RMS on these photos", "",
              "| fit | RMS (px) |", "|---|---|",
              f"| housing (refractive, this calibration) | {r['housing']:.4f} |",
              f"| in air (--intrinsics) | {_f(r['in_air'])} |",
              f"| pinhole absorbing the port (cv2.calibrateCamera, {r['absorbed_pinhole_model']}) "
              f"| {r['absorbed_pinhole']:.4f} |", "",
              "The pinhole fits its intrinsics to these photos, the housing keeps the in-air "
              "ones: on the photos they were fitted to the pinhole's RMS is lower almost always. "
              "So the two are compared on photos each did not see:", "",
              *_held_out_lines(r["held_out"]), "",
              f"Checks: housing RMS ≤ in-air RMS + {r['margin_px']:g} px; the housing predicts "
              f"held-out photos no worse than the absorbed pinhole (the rule above).", "",
              *_dependence_lines(report.get("in_air_dependence", {})),
              *photo_lines(report)]
    lines += ["", "## Files", "", "- `camera.yaml` (OpenCV FileStorage: the camera, its port or "
              "dome in its frame, mm, the housing's σ and covariance), `calibmar.yaml` "
              "(calibmar, FLATPORT/DOMEPORT), `cameras.txt` (the refractive COLMAP fork)",
              "- `coverage.png`, `residuals.png` (residual vectors per photo)", "",
              "## Timings (s)", "",
              " · ".join(f"{k} {v:.2f}" for k, v in report["timings_s"].items())]
    return "\n".join(lines) + "\n"


def _held_out_lines(validation: dict) -> list:
    """report.md's cross-validation of the housing against the absorbed pinhole."""
    if "unavailable" in validation:
        return [f"Not available: {validation['unavailable']}."]
    verdict = ("worse than the pinhole" if validation["housing_worse"] else
               "not worse than the pinhole")
    return ["| model | RMS on held-out photos (px) |", "|---|---|",
            f"| housing | {validation['housing_rms_px']:.4f} |",
            f"| pinhole absorbing the port | {validation['pinhole_rms_px']:.4f} |", "",
            f"{validation['photos']} photos predicted, {validation['folds']} groups held out in "
            f"turn (each photo's board pose fitted with the model held); per-photo difference "
            f"of the mean squared errors (housing − pinhole) {validation['difference_px2']:+.4f} "
            f"± {validation['standard_error_px2']:.4f} px²: the housing predicts {verdict} "
            f"({validation['rule']})."]


def summary_lines(report: dict) -> str:
    r = report["rms_px"]
    parts = []
    for name, e in report["estimates"].items():
        if name == "normal":
            parts.append(f"normal tilt {e['tilt_deg']:.4f}° (σ of the two tilts "
                         f"{_f(e['sigma'], 2)}°)")
        else:
            parts.append(f"{name} {_value(e)} ± {_f(e['sigma'], 2)}")
    lines = [f"{report['photos']}: one camera behind {'a dome' if report['dome'] else 'a flat port'}"
             f"; board found in {report['found']}/{report['poses']} photos; {report['used']} used",
             "housing: " + "; ".join(parts) + f" ({report['uncertainty']} σ)",
             f"RMS: housing {r['housing']:.4f} px, in air {_f(r['in_air'])} px, pinhole absorbing "
             f"the port {r['absorbed_pinhole']:.4f} px ({r['absorbed_pinhole_model']})"]
    held = r.get("held_out", {})
    if "housing_rms_px" in held:
        lines.append(f"held-out photos: housing {held['housing_rms_px']:.4f} px, pinhole "
                     f"{held['pinhole_rms_px']:.4f} px ({held['photos']} photos, "
                     f"{held['folds']} groups): the housing predicts "
                     f"{'worse' if held['housing_worse'] else 'no worse'}")
    for name, e in report.get("in_air_dependence", {}).items():
        if e["sigma_photos"] is not None:
            lines.append(f"{name}: σ {e['sigma']:.3g}, {e['sigma_photos']:.3g} with the in-air "
                         f"intrinsics' photo-to-photo spread (the report's table says which "
                         f"intrinsic moves it most)")
    lines += [f"warning: {w}" for w in report["warnings"]]
    return "\n".join(lines)


__all__ = ["RMS_MARGIN_PX", "calibrate_single_housing", "markdown", "read_intrinsics",
           "summary_lines"]
