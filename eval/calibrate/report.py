"""What ``python -m eval calibrate`` writes: estimates beside the truth, the files, the figures.

Errors are estimate − truth; "in σ" divides by the estimate's standard deviation. Units mm,
px, degrees where named ``_deg``; the reference frame is the left camera's.
"""

from __future__ import annotations

import os

import numpy as np


def _stats(errors: np.ndarray) -> dict:
    errors = np.asarray(errors, float).reshape(-1, 2)
    if errors.size == 0:
        return {"n": 0, "rms_px": None, "max_px": None}
    length = np.linalg.norm(errors, axis=1)
    return {"n": int(length.size), "rms_px": float(np.sqrt(np.mean(length ** 2))),
            "max_px": float(length.max()), "mean_px": errors.mean(axis=0).tolist()}


def detection_errors(boards, detections, view: int) -> np.ndarray:
    """Rows ``(pose, id, u, v, du, dv)``: detected corner and its offset from the forward
    model's pixel of the true corner (``corners.csv``)."""
    rows = []
    for k in range(detections.n_poses):
        ids, uv = detections.ids[k][view], detections.pixels[k][view]
        if len(ids) == 0:
            continue
        truth = boards.corners[boards.corners[:, 0] == k]
        lookup = {int(i): row for i, row in zip(truth[:, 1], truth)}
        expected = np.array([lookup[int(i)][5 + 2 * view:7 + 2 * view] for i in ids])
        rows.append(np.column_stack([np.full(len(ids), k), ids, uv, uv - expected]))
    return np.concatenate(rows) if rows else np.empty((0, 6))


def detection_accuracy(boards, detections) -> dict:
    """Corner detection against the forward model's pixels, per view and both."""
    per = {name: detection_errors(boards, detections, v) for v, name in enumerate(("left", "right"))}
    out = {name: _stats(rows[:, 4:6]) for name, rows in per.items()}
    out["both"] = _stats(np.concatenate([rows[:, 4:6] for rows in per.values()]))
    out["corners_per_view"] = boards.board.n_corners
    return out


def _with_sigma(estimate, truth, sigma) -> dict:
    error = float(estimate) - float(truth)
    return {"estimate": float(estimate), "truth": float(truth), "error": error,
            "sigma": None if sigma is None else float(sigma),
            "error_in_sigma": (error / sigma) if sigma else None}


def _rotation_deg(Ra, Rb) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))))


def air_summary(air, truth) -> dict:
    """In-air calibration against the true rig: focal lengths, principal points, baseline."""
    out = {"rms_px": air.rms_px, "stereo_rms_px": air.stereo_rms_px, "poses_used": air.poses_used,
           "cameras": {}}
    for name in ("left", "right"):
        est, tru, sig = getattr(air.rig, name), getattr(truth, name), air.sigmas[name]
        cam = {key: _with_sigma(est.K[i, j], tru.K[i, j], sig[key])
               for key, (i, j) in (("fx", (0, 0)), ("fy", (1, 1)), ("cx", (0, 2)), ("cy", (1, 2)))}
        for key in ("fx", "fy"):
            cam[key]["error_percent"] = 100 * cam[key]["error"] / cam[key]["truth"]
        cam["dist"] = None if est.dist is None else est.dist.tolist()
        cam["dist_sigma"] = {key: sig.get(key) for key in ("k1", "k2", "p1", "p2")}
        out["cameras"][name] = cam
    baseline = np.linalg.norm(air.rig.right.t - air.rig.left.t)
    true_baseline = np.linalg.norm(truth.right.t - truth.left.t)
    out["baseline_mm"] = _with_sigma(baseline, true_baseline, None)
    out["right_rotation_error_deg"] = _rotation_deg(air.rig.right.R, truth.right.R)
    out["right_position_error_mm"] = float(np.linalg.norm(air.rig.right.t - truth.right.t))
    out.update(stereo_sigmas(air))
    out["right_position_error_in_sigma"] = [
        float(e / s) for e, s in zip(air.rig.right.t - truth.right.t,
                                     out["right_center_sigma_mm"])]
    return out


def stereo_sigmas(air) -> dict:
    """The stereo pose's σ from the in-air covariance: the right camera's centre (mm, reference
    axes), its rotation (degrees, about reference axes) and the baseline (mm); NaN without a
    covariance (a lens model other than the standard one)."""
    cov = air.covariance
    if cov is None:
        nan = float("nan")
        return {"right_center_sigma_mm": [nan] * 3, "right_rotation_sigma_deg": [nan] * 3,
                "baseline_sigma_mm": nan}
    where = [cov.names.index(f"right.center[{k}]") for k in range(3)]
    centre = cov.matrix[np.ix_(where, where)]
    direction = (air.rig.right.t - air.rig.left.t)
    direction = direction / np.linalg.norm(direction)
    sig = cov.sigmas
    return {"right_center_sigma_mm": np.sqrt(np.diag(centre)).tolist(),
            "right_rotation_sigma_deg": [float(np.degrees(sig[f"right.rotation[{k}]"]))
                                         for k in range(3)],
            "baseline_sigma_mm": float(np.sqrt(direction @ centre @ direction))}


def _adjustment_summary(housing) -> dict:
    """What a housing or dome adjustment reports whatever it estimated: the free parameters,
    their labels and correlation, the reprojection RMS (px; overall, at the start, per pose and
    view), the observations, poses and evaluations; ``parameters`` left to fill."""
    return {"free": list(dict.fromkeys(label.split("[")[0] for label in housing.labels)),
            "labels": list(housing.labels), "correlation": housing.correlation.tolist(),
            "rms_px": housing.rms_px, "rms_px_start": housing.rms_px_start,
            "rms_px_per_pose_view": {f"{k}:{'left' if v == 0 else 'right'}": r
                                     for (k, v), r in sorted(housing.rms_px_per.items())},
            "observations": housing.n_observations, "poses_used": list(housing.pose_ids),
            "evaluations": housing.nfev, "parameters": {}}


def housing_summary(housing, truth, start_rig) -> dict:
    """Every estimated housing parameter beside the truth, with its error in σ. Two housings
    (a port per camera: the estimates are ``{"left": …, "right": …}``): each camera's
    ``distance``, ``normal``, ``thickness`` as ``left_distance`` …, the distance also from the
    camera's centre along the port's normal (``from_camera``: what the scene's
    ``--port-distance`` says)."""
    out = _adjustment_summary(housing)
    out["uncertainty"] = housing.uncertainty
    params = out["parameters"]
    for name in housing.estimates:
        sigma = housing.sigmas[name]
        conditional = housing.sigmas_conditional.get(name, sigma)
        if name == "extrinsics":
            R, t = housing.rig.right.R, housing.rig.right.t
            params[name] = {"rotation_error_deg": _rotation_deg(R, truth.right.R),
                            "position_error_mm": (t - truth.right.t).tolist(),
                            "sigma_rotation_deg": np.degrees(sigma[:3]).tolist(),
                            "sigma_position_mm": list(sigma[3:]),
                            "error_in_sigma": [float(e / s) for e, s in
                                               zip(t - truth.right.t, sigma[3:])],
                            "sigma_conditional": list(conditional)}
            continue
        for key, est, tru, part, axes, view in _estimated_ports(housing, truth, name):
            params[key] = _port_parameter(name, est, tru, np.atleast_1d(sigma)[part],
                                          np.atleast_1d(conditional)[part], axes)
            if view is not None and name == "distance":
                params[key]["from_camera"] = {
                    side: port.distance - float(port.normal @ rig.cameras[view].center)
                    for side, port, rig in (("estimate", est, housing.rig), ("truth", tru, truth))}
                params[key]["from_camera"]["error"] = (params[key]["from_camera"]["estimate"]
                                                       - params[key]["from_camera"]["truth"])
    if housing.uncertainty == "prior":  # the in-air parameters the underwater boards refined
        out["in_air_refined"] = in_air_changes(housing, start_rig)
    ports = {camera: start_rig.view_port(v) for v, camera in enumerate(("left", "right"))}
    out["start"] = ({camera: _port_start(port) for camera, port in ports.items()}
                    if ports["left"] is not ports["right"] else _port_start(start_rig.port))
    zs = [abs(z) for p in params.values()
          for z in np.atleast_1d(p.get("error_in_sigma") if p.get("error_in_sigma") is not None else [])]
    out["max_abs_error_in_sigma"] = max(zs) if zs else None
    return out


def _port_start(port) -> dict:
    return {"distance": port.distance, "normal": port.normal.tolist(),
            "thickness": list(port.thicknesses), "indices": list(port.indices)}


def _estimated_ports(housing, truth, name):
    """``(key, estimated port, true port, slice of the σ, tilt axes, view)`` of the ports free
    parameter ``name`` belongs to: the shared port (``view`` None), or — its estimate
    ``{"left": …, "right": …}`` — each camera's own."""
    estimate = housing.estimates[name]
    if not isinstance(estimate, dict) or name == "extrinsics":
        yield name, housing.rig.port, truth.port, slice(None), housing.normal_axes, None
        return
    width = np.size(housing.sigmas[name]) // len(estimate)
    for i, camera in enumerate(estimate):
        view = ("left", "right").index(camera)
        yield (f"{camera}_{name}", housing.rig.view_port(view), truth.view_port(view),
               slice(i * width, (i + 1) * width), housing.normal_axes[i], view)


def _port_parameter(name, est, tru, sigma, conditional, axes) -> dict:
    """One flat port's estimated ``name`` (``distance``, ``thickness``, ``n_water``, ``normal``)
    beside the truth; the normal's error as its components along the two tilt ``axes``."""
    if name == "normal":
        a, b = (np.asarray(v) for v in axes)
        tilt_error = [float((est.normal - tru.normal) @ a), float((est.normal - tru.normal) @ b)]
        angle = float(np.degrees(np.arccos(np.clip(est.normal @ tru.normal, -1, 1))))
        return {"estimate": est.normal.tolist(), "truth": tru.normal.tolist(),
                "error_deg": angle, "sigma_deg": np.degrees(sigma).tolist(),
                "tilt_error_rad": tilt_error,
                "error_in_sigma": [e / s for e, s in zip(tilt_error, sigma)],
                "sigma_conditional_deg": np.degrees(conditional).tolist(),
                "error_in_sigma_conditional": [e / s for e, s in zip(tilt_error, conditional)]}
    value, true = {"distance": (est.distance, tru.distance),
                   "thickness": (est.thicknesses[0], tru.thicknesses[0]),
                   "n_water": (est.n_water, tru.n_water)}[name]
    out = _with_sigma(value, true, float(sigma[0]))
    out["sigma_conditional"] = float(conditional[0])
    out["error_in_sigma_conditional"] = (value - true) / float(conditional[0])
    return out


def dome_summary(housing, truth, start_rig) -> dict:
    """Every estimated dome parameter beside the truth, with its error in σ: each camera's
    decentring (its dome centre relative to the camera centre, in the camera's frame, mm) and
    the water index."""
    from measure.calibration.dome import dome_offset

    out = _adjustment_summary(housing)
    out["uncertainty"] = housing.uncertainty
    params = out["parameters"]
    for name in housing.estimates:
        sigma = housing.sigmas[name]
        conditional = housing.sigmas_conditional.get(name, sigma)
        if name == "n_water":
            params[name] = _with_sigma(housing.rig.port.n_water, truth.port.n_water, sigma)
            params[name]["sigma_conditional"] = float(conditional)
            params[name]["error_in_sigma_conditional"] = (
                params[name]["error"] / float(conditional))
            continue
        for view, (camera, axes) in enumerate(zip(("left", "right"), ((0, 1, 2), (3, 4, 5)))):
            estimate = dome_offset(housing.rig.cameras[view], housing.rig.port[view])
            true = dome_offset(truth.cameras[view], truth.port[view])
            for axis, k in zip("xyz", axes):
                p = _with_sigma(estimate[k % 3], true[k % 3], sigma[k])
                p["sigma_conditional"] = float(conditional[k])
                p["error_in_sigma_conditional"] = p["error"] / float(conditional[k])
                params[f"{camera}_dome_{axis}"] = p
    if housing.uncertainty == "prior":  # the in-air parameters the underwater boards refined
        out["in_air_refined"] = in_air_changes(housing, start_rig)
    out["start"] = {view: {"offset_mm": dome_offset(c, d).tolist(), "radius": d.radius,
                           "thickness": d.thickness, "indices": list(d.indices)}
                    for view, c, d in zip(("left", "right"), start_rig.cameras,
                                          (start_rig.port.left, start_rig.port.right))}
    zs = [abs(p["error_in_sigma"]) for p in params.values() if p.get("error_in_sigma") is not None]
    out["max_abs_error_in_sigma"] = max(zs) if zs else None
    return out


def in_air_changes(housing, start_rig) -> dict:
    """``{name: {"change", "sigma"}}``: how far the prior fit moved each in-air parameter of the
    covariance from its in-air value (px, unitless, rad about reference axes, mm) and its σ."""
    from scipy.spatial.transform import Rotation

    out, sig = {}, housing.covariance.sigmas
    for name in housing.covariance.names:
        cam, _, key = name.partition(".")
        if cam not in ("left", "right") or key.startswith(("rotation", "center", "dome_center",
                                                           "port.")):
            continue
        new, old = getattr(housing.rig, cam), getattr(start_rig, cam)
        if key in ("fx", "fy", "cx", "cy"):
            i, j = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[key]
            change = new.K[i, j] - old.K[i, j]
        else:
            k = ("k1", "k2", "p1", "p2").index(key)
            change = (0.0 if new.dist is None else new.dist[k]) - (
                0.0 if old.dist is None else old.dist[k])
        out[name] = {"change": float(change), "sigma": sig[name]}
    if "right.rotation[0]" in sig and "extrinsics" not in housing.estimates:
        phi = Rotation.from_matrix(housing.rig.right.R @ start_rig.right.R.T).as_rotvec()
        for k in range(3):
            out[f"right.rotation[{k}]"] = {"change": float(phi[k]),
                                           "sigma": sig[f"right.rotation[{k}]"]}
            out[f"right.center[{k}]"] = {
                "change": float(housing.rig.right.t[k] - start_rig.right.t[k]),
                "sigma": sig[f"right.center[{k}]"]}
    return out


def write_calibration(path, rig, has_port: bool, housing, report, single: bool = False,
                      covariance=None) -> None:
    """``calib.yaml`` and ``flatport.txt`` into directory ``path``; with ``single`` just the
    calib file at ``path``. ``covariance`` (:class:`measure.stereo.rig_covariance.RigCovariance`; the
    housing's own when ``housing`` is given) becomes the file's ``covariance`` node and an
    ``uncertainty`` map: every named parameter's σ (``names``, ``sigmas``), what the σ covers
    (``includes``) and, underwater, the housing's σ conditional on the in-air calibration."""
    from measure.geometry.flatport_format import port_text_files
    from synth.products.dataset import write_calib
    from synth.infra.fileio import atomic_write_text

    if housing is not None:
        covariance = housing.covariance
    extra = {}
    if covariance is not None:
        extra["uncertainty"] = {
            "names": list(covariance.names),
            "sigmas": [float(s) for s in covariance.sigmas.values()],
            "units": "px (intrinsics), unitless (distortion), rad (rotation, port tilts), mm "
                     "(centre, distance, thickness), index units",
            "includes": SIGMA_INCLUDES[housing.uncertainty if housing is not None else "air"]}
    if housing is not None:
        extra["uncertainty"]["housing_labels"] = list(housing.labels)
        extra["uncertainty"]["housing_sigmas_conditional"] = [float(s) for s in np.concatenate(
            [np.atleast_1d(housing.sigmas_conditional[n]) for n in housing.sigmas_conditional])]
        extra["calibration"] = {"rms_px": housing.rms_px, "poses": len(housing.poses)}
    target = path if single else os.path.join(path, "calib.yaml")
    write_calib(target, rig, has_port, extra or None, covariance=covariance)
    if not single and has_port:  # the port's own file (domes: their DOMEPORT is in cameras.txt)
        for name, text in port_text_files(rig.port, {"left": rig.left, "right": rig.right}).items():
            atomic_write_text(os.path.join(path, name), text)
    if not single:
        write_other_formats(path, rig, has_port)


def write_other_formats(directory, rig, has_port: bool) -> list[str]:
    """The calibration in the formats of other tools, into ``directory``: calibmar's stereo
    pair (``calibmar.yaml``, ``calibmar_stereo.yaml``) and the refractive COLMAP fork's
    ``cameras.txt`` with ``rig_config.json`` (:func:`synth.formats.calib_formats.write_calibration_formats`;
    the COLMAP file's header says that upstream COLMAP and pycolmap drop the port). Returns
    the names written."""
    from synth.formats.calib_formats import write_calibration_formats

    return [os.path.basename(p) for p in write_calibration_formats(directory, rig, has_port)]


def figures(directory, boards, detections, housing, rig) -> None:
    """``detections.png`` (detection errors against the forward model, per view),
    ``residuals.png`` (housing: bundle-adjustment residuals per pose and view) and
    ``poses.png`` (the boards in 3D, true and — underwater — estimated)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w, h = boards.calib["size"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 5), constrained_layout=True)
    for view, ax in enumerate(axes):
        rows = detection_errors(boards, detections, view)
        _quiver(ax, rows[:, 0], rows[:, 2:4], rows[:, 4:6], w, h,
                f"{'left' if view == 0 else 'right'}: detected − forward model")
    fig.savefig(os.path.join(directory, "detections.png"), dpi=110)
    plt.close(fig)
    if housing is not None:
        residual_figure(directory, detections, housing.residuals, (w, h))
    fig = plt.figure(figsize=(7, 6), constrained_layout=True)
    ax = fig.add_subplot(projection="3d")
    outline = boards.board.outline()
    for k, pose in enumerate(boards.poses):
        p = pose.apply(np.vstack([outline, outline[:1]]))
        ax.plot(p[:, 0], p[:, 2], -p[:, 1], color="C0", lw=1, label="truth" if k == 0 else None)
    if housing is not None:
        for j, (R, t) in enumerate(housing.poses):
            p = np.vstack([outline, outline[:1]]) @ R.T + t
            ax.plot(p[:, 0], p[:, 2], -p[:, 1], "--", color="C3", lw=1,
                    label="estimated" if j == 0 else None)
    for cam, name in zip(rig.cameras, ("left", "right")):
        ax.scatter([cam.t[0]], [cam.t[2]], [-cam.t[1]], color="k", s=20)
        ax.text(cam.t[0], cam.t[2], -cam.t[1], f" {name}")
    ax.set_xlabel("X (mm)")
    ax.set_ylabel("Z (mm)")
    ax.set_zlabel("−Y (mm)")
    ax.set_title(f"{len(boards.poses)} board poses ({'air' if boards.air else 'behind the port'})")
    ax.legend(loc="upper left")
    fig.savefig(os.path.join(directory, "poses.png"), dpi=110)
    plt.close(fig)


def write_report(directory, report: dict, markdown, start: float) -> dict:
    """``report.json`` and ``report.md`` (``markdown(report)``) into ``directory``, with the total
    time since ``start``; returns the report as written (JSON types)."""
    import time

    from synth.infra.fileio import atomic_write_json, atomic_write_text, jsonable

    report["timings_s"]["total"] = time.perf_counter() - start
    report = jsonable(report)
    atomic_write_json(os.path.join(directory, "report.json"), report)
    atomic_write_text(os.path.join(directory, "report.md"), markdown(report))
    return report


def residual_figure(directory, detections, residuals, size, views=("left", "right")) -> None:
    """``residuals.png``: the residual vectors per pose and view (``residuals`` per view
    ``(pose, id, du, dv)`` rows: the housing's bundle adjustment, or each camera's in-air
    fit)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w, h = size
    fig, axes = plt.subplots(1, len(views), figsize=(6 * len(views), 5), constrained_layout=True,
                             squeeze=False)
    for view, ax in enumerate(axes[0]):
        res = np.asarray(residuals[view]).reshape(-1, 4)
        where = []
        for k, i in res[:, :2].astype(int):
            ids = detections.ids[k][view]
            where.append(detections.pixels[k][view][int(np.flatnonzero(ids == i)[0])])
        _quiver(ax, res[:, 0], np.asarray(where).reshape(-1, 2), -res[:, 2:4], w, h,
                f"{views[view]}: reprojection residual after the fit")
    fig.savefig(os.path.join(directory, "residuals.png"), dpi=110)
    plt.close(fig)


def _quiver(ax, pose, where, vectors, w, h, title) -> None:
    length = np.linalg.norm(vectors, axis=1) if len(vectors) else np.zeros(0)
    scale_px = float(np.percentile(length, 95)) if length.size else 1.0
    gain = 0.04 * w / scale_px if scale_px > 0 else 1.0
    if len(vectors):
        ax.quiver(where[:, 0], where[:, 1], vectors[:, 0] * gain, vectors[:, 1] * gain, pose,
                  angles="xy", scale_units="xy", scale=1, cmap="tab20", width=0.002)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect("equal")
    rms = float(np.sqrt(np.mean(length ** 2))) if length.size else float("nan")
    ax.set_title(f"{title}\nRMS {rms:.4f} px; arrows × {gain:.0f}; colour = pose", fontsize=9)


def format_value(value, digits=4):
    """A number (``digits`` significant), a list of them in parentheses, or – for None."""
    if value is None:
        return "–"
    if isinstance(value, (list, tuple)):
        return "(" + ", ".join(_f(v, digits) for v in value) + ")"
    return f"{value:.{digits}g}" if isinstance(value, float) else str(value)


_f = format_value


def _behind(report: dict) -> str:
    """Where underwater boards were: behind the port, or behind the domes."""
    return "behind the domes" if report.get("dome") else "behind the port"


def markdown(report: dict) -> str:
    d = report["detection"]
    lines = [f"# Calibration report: `{report['boards']}`", "",
             f"{report['poses']} poses of a {report['board']['kind']} "
             f"{report['board']['squares'][0]}x{report['board']['squares'][1]}, "
             f"{report['board']['square_mm']:g} mm squares, "
             f"{'in air' if report['air'] else _behind(report)}; board found in "
             f"{report['found']['left']} left and {report['found']['right']} right images.", "",
             "## Corner detection against the forward model", "",
             "| view | corners | RMS (px) | max (px) |", "|---|---|---|---|"]
    for view in ("left", "right", "both"):
        lines.append(f"| {view} | {d[view]['n']} | {_f(d[view]['rms_px'])} | {_f(d[view]['max_px'])} |")
    if "in_air" in report:
        lines += _in_air_lines(report["in_air"])
    if "housing" in report:
        lines += _housing_lines(report["housing"])
    lines += ["", "## Files", "", "- `calib.yaml`: the calibration in the dataset format"
              + (" (with an `uncertainty` map), `calib_in_air_only.yaml` (the in-air calibration "
                 "with the design port), "
                 + ("`cameras.txt` (DOMEPORT per camera)" if report.get("dome")
                    else "`flatport.txt` (FLATPORT per camera)")
                 if "housing" in report else ""),
              "- `detections.png`, " + ("`residuals.png`, " if "housing" in report else "")
              + "`poses.png`", "", "## Timings (s)", "",
              " · ".join(f"{k} {v:.2f}" for k, v in report["timings_s"].items())]
    return "\n".join(lines) + "\n"


def _in_air_lines(a: dict) -> list:
    """The in-air calibration's section: RMS, each camera's intrinsics against the truth, the
    distortion's σ, the baseline and the right camera's pose errors."""
    lines = []
    lines += ["", "## In-air calibration (OpenCV)", "",
              f"Reprojection RMS: left {a['rms_px']['left']:.4f} px, right "
              f"{a['rms_px']['right']:.4f} px, stereo {a['stereo_rms_px']:.4f} px.", "",
              "| camera | parameter | estimate | truth | error | σ | error / σ |",
              "|---|---|---|---|---|---|---|"]
    for cam, values in a["cameras"].items():
        for key in ("fx", "fy", "cx", "cy"):
            v = values[key]
            lines.append(f"| {cam} | {key} (px) | {v['estimate']:.4f} | {v['truth']:.4f} | "
                         f"{v['error']:+.4f} | {_f(v['sigma'])} | {_f(v['error_in_sigma'], 3)} |")
    for cam, values in a["cameras"].items():
        if values.get("dist_sigma"):
            lines.append(f"| {cam} | k1 k2 p1 p2 | {_f(values['dist'][:4] if values['dist'] else None)} "
                         f"| – | – | {_f(list(values['dist_sigma'].values()), 3)} | – |")
    b = a["baseline_mm"]
    lines += ["", f"Baseline {b['estimate']:.4f} mm (truth {b['truth']:.4f}, error "
              f"{b['error']:+.4f} mm, σ {_f(a.get('baseline_sigma_mm'), 3)} mm); right "
              f"camera rotation error {a['right_rotation_error_deg']:.5f}° (σ "
              f"{_f(a.get('right_rotation_sigma_deg'), 3)}° about x, y, z), position error "
              f"{a['right_position_error_mm']:.4f} mm (σ "
              f"{_f(a.get('right_center_sigma_mm'), 3)} mm; error / σ "
              f"{_f(a.get('right_position_error_in_sigma'), 3)}). Every correlation "
              f"is in calib.yaml's `covariance`."]
    return lines


def _housing_lines(hs: dict) -> list:
    """The housing calibration's section: the fit, each free number against the truth with σ
    (and σ conditional on the in-air calibration), the in-air numbers a prior fit refined, the
    correlations."""
    lines = []
    lines += ["", "## Housing calibration (refractive bundle adjustment)", "",
              f"Free: {', '.join(hs['free'])}; {hs['observations']} corner observations in "
              f"{len(hs['poses_used'])} poses; reprojection RMS {hs['rms_px_start']:.3f} px "
              f"at the start, {hs['rms_px']:.4f} px after ({hs['evaluations']} evaluations).",
              "", sigma_note(hs.get("uncertainty", "conditional")), "",
              "| parameter | estimate | truth | error | σ | error / σ | σ (conditional) |",
              "|---|---|---|---|---|---|---|"]
    for name, p in hs["parameters"].items():
        if name.endswith("normal"):
            lines.append(f"| {name.replace('_', ' ')} | {_f(p['estimate'], 7)} | {_f(p['truth'], 7)} | "
                         f"{p['error_deg'] * 3600:.2f}″ | {_f([s * 3600 for s in p['sigma_deg']], 3)}″ "
                         f"(two tilts) | {_f(p['error_in_sigma'], 3)} | "
                         f"{_f([s * 3600 for s in p['sigma_conditional_deg']], 3)}″ |")
        elif name == "extrinsics":
            lines.append(f"| right camera | rotation error {p['rotation_error_deg']:.5f}° | "
                         f"– | position {_f(p['position_error_mm'])} mm | "
                         f"{_f(p['sigma_position_mm'])} mm, "
                         f"{_f(p['sigma_rotation_deg'], 3)}° | {_f(p['error_in_sigma'], 3)} | "
                         f"{_f(p['sigma_conditional'][3:])} mm |")
        elif name.endswith(("_dome_x", "_dome_y", "_dome_z")):
            lines.append(f"| {name.replace('_', ' ')} (mm, camera frame) | "
                         f"{p['estimate']:.4f} | {p['truth']:.4f} | {p['error']:+.4f} | "
                         f"{_f(p['sigma'])} | {_f(p['error_in_sigma'], 3)} | "
                         f"{_f(p.get('sigma_conditional'))} |")
        else:
            lines.append(f"| {name} | {p['estimate']:.6f} | {p['truth']:.6f} | "
                         f"{p['error']:+.6f} | {_f(p['sigma'])} | {_f(p['error_in_sigma'], 3)} "
                         f"| {_f(p.get('sigma_conditional'))} |")
            if "from_camera" in p:  # two housings: D from the camera's centre
                c = p["from_camera"]
                lines.append(f"| {name} from its camera | {c['estimate']:.6f} | "
                             f"{c['truth']:.6f} | {c['error']:+.6f} | – | – | – |")
    if hs.get("in_air_refined"):
        lines += ["", "In-air parameters refined by the underwater boards (the prior fit; "
                  "change from the in-air value, σ): " + ", ".join(
                      f"{name} {v['change']:+.3g} ({_f(v['sigma'], 2)})"
                      for name, v in hs["in_air_refined"].items()) + "."]
    lines += ["", "Correlations of the free numbers (" + ", ".join(hs["labels"])
              + "; of the housing adjustment alone — the joint ones are in calib.yaml's "
                "covariance):", ""]
    lines += ["    " + " ".join(f"{v:+.3f}" for v in row) for row in hs["correlation"]]
    return lines


#: What the σ of a calibration file covers, by how it was obtained (calib.yaml's
#: ``uncertainty.includes``).
SIGMA_INCLUDES = {
    "air": "the corners' scatter through OpenCV's calibration: both cameras' intrinsics and "
           "the stereo pose, with their correlations",
    "propagate": "the corners' scatter of the housing adjustment and the in-air calibration's "
                 "covariance propagated through it (intrinsics and stereo pose held at the "
                 "in-air values)",
    "prior": "the housing adjustment with the in-air parameters free under their in-air "
             "covariance as a prior",
    "conditional": "the housing adjustment's corners only: conditional on the in-air "
                   "calibration, whose file carried no covariance"}

def sigma_note(mode: str) -> str:
    """What the housing σ covers (said in every report), by ``HousingCalibration.uncertainty``."""
    if mode == "conditional":
        return ("σ is the housing calibration's own: its corners' scatter through the refractive "
                "bundle adjustment, with the intrinsics (and the stereo extrinsics unless free) "
                "held at the in-air calibration, whose file (--intrinsics) carried no "
                "covariance (or was the scene's exact rig). Errors of the in-air calibration "
                "are not in it: on rendered boards of the flat port the chain's error was "
                "4–15 σ where the exact intrinsics gave ≤ 2 σ, on the domes' decentring up to "
                "6 σ (docs/calibration.md).")
    how = ("propagated through the adjustment (σ² = s²(JᵀJ)⁻¹ + G Σ_air Gᵀ)" if mode == "propagate"
           else "as a prior on the intrinsics and stereo pose, freed in the adjustment")
    return (f"σ includes the in-air calibration's uncertainty: its full covariance (both "
            f"cameras' intrinsics and the stereo pose) {how}. σ (conditional) is the housing's "
            f"own, with the in-air calibration taken as exact. calib.yaml's `covariance` node "
            f"holds the joint covariance of every calibrated rig parameter.")


def summary_lines(report: dict) -> str:
    d = report["detection"]["both"]
    lines = [f"{report['boards']}: board found in {report['found']['left']}/{report['poses']} "
             f"left and {report['found']['right']}/{report['poses']} right images; corner "
             f"detection vs forward model RMS {_f(d['rms_px'])} px, max {_f(d['max_px'])} px"]
    if "in_air" in report:
        a = report["in_air"]
        for cam, v in a["cameras"].items():
            lines.append(f"in air {cam}: fx {v['fx']['error_percent']:+.4f} %, fy "
                         f"{v['fy']['error_percent']:+.4f} %, cx {v['cx']['error']:+.3f} px, cy "
                         f"{v['cy']['error']:+.3f} px; RMS {a['rms_px'][cam]:.4f} px")
        lines.append(f"in air baseline error {a['baseline_mm']['error']:+.4f} mm, stereo RMS "
                     f"{a['stereo_rms_px']:.4f} px")
    if "housing" in report:
        hs = report["housing"]
        for name, p in hs["parameters"].items():
            if name.endswith("normal"):
                lines.append(f"housing {name.replace('_', ' ')}: error {p['error_deg'] * 3600:.2f}″ "
                             f"({p['error_deg']:.5f}°), σ {_f([s * 3600 for s in p['sigma_deg']], 3)}″, "
                             f"error/σ {_f(p['error_in_sigma'], 3)}")
            elif name == "extrinsics":
                lines.append(f"housing right camera: rotation error {p['rotation_error_deg']:.5f}°, "
                             f"position error {_f(p['position_error_mm'])} mm, error/σ "
                             f"{_f(p['error_in_sigma'], 3)}")
            else:
                lines.append(f"housing {name}: {p['estimate']:.6f} (truth {p['truth']:.6f}, error "
                             f"{p['error']:+.6f}, σ {_f(p['sigma'])}, error/σ "
                             f"{_f(p['error_in_sigma'], 3)})"
                             + (f"; from its camera {p['from_camera']['estimate']:.6f} (error "
                                f"{p['from_camera']['error']:+.6f})" if "from_camera" in p
                                else ""))
        lines.append(f"housing reprojection RMS {hs['rms_px']:.4f} px ({hs['observations']} "
                     f"corners, {len(hs['poses_used'])} poses, {hs['evaluations']} evaluations, "
                     f"{report['timings_s'].get('bundle_adjustment', 0):.2f} s)")
    return "\n".join(lines)
