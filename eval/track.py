"""``python -m eval track DATASET --out DIR [--pixel-sigma PX] [--gate PX] [--json]``: follow the
known object of a ``synth sequence`` folder through its frames and score the poses against the
true ones.

Per frame: the markers are detected in both views (:func:`measure.detect_targets`); each marker
is given the detection nearest to where the previous frame's pose, moved on by the last
frame-to-frame translation (constant velocity), puts it (the forward model through the port; an
optimal assignment, :func:`scipy.optimize.linear_sum_assignment`, within ``--gate`` px); the
pose comes from both views jointly (:func:`measure.stereo.pose.estimate_pose`, with its
covariance), the detections corrected for the markers' eccentricity at that pose and the pose
estimated again, its covariance then holding the shared radial error the correction leaves
(:func:`radial_bias_covariance`) beside the pixel noise; each camera's pose alone, through its
own port on the same pixels, is scored beside it. The track locks on from the first frame's
detections with no guess (:func:`measure.stereo.lockon.lock_on`: the detections matched across
the views, triangulated and registered to the object's shape; a frame where that fails is
``NOT_LOCKED`` and the next one tries again); an object symmetric under turns (the docking frame
under quarter turns) takes the turn nearest upright. ``--lock-on truth`` starts at the first
frame's true pose instead. The same lock-on runs again whenever the track is lost — in the frame
after one without a pose (a black frame), and in a frame whose prediction finds too few markers
(a jump) — taking the turn nearest the last pose's (:func:`eval.core.sequence.locate_markers`).
Frames changed since ``synth sequence`` wrote them (their SHA-256 is not the manifest's) are
named and tracked as they are; a changed truth file is refused.

Writes to ``--out``: ``poses.csv`` (the estimated poses, the columns of the sequence's
``poses.csv`` plus ``sigma_t_mm`` = sqrt(trace) of the position covariance, ``rms_px``,
``observations``, ``reason``), ``poses_tum.txt`` (TUM format, metres, the frames with a pose) and
``report.json``: per frame the detections' RMS distance from the simulator's pixels
(``pixels.csv``), the position error (mm), the rotation error (rad), the squared
Mahalanobis distance of the position error, and a summary (median and largest errors, the
fraction of positions inside their 95 % ellipsoid; the same per camera alone; poses per
second after detection), and ``track.png`` (:func:`track_figure`). Exit 1 when a frame has no
pose.
"""

from __future__ import annotations

import argparse

import json
import os
import sys
import time

import numpy as np

from eval.cli import CLIError, positive_float
from eval.core.sequence import changed_frames, locate_markers, read_sequence
from synth.infra.cli import add_json_option, add_out_option, add_progress_option
from synth.infra.images import imread

COMMAND = "eval track"
#: Largest distance (px) between a marker's predicted pixel and the detection it is given.
DEFAULT_GATE_PX = 20.0


def add_parser(subparsers):
    p = subparsers.add_parser(
        "track", help="follow a synth sequence's known object with the refractive pose",
        description="Detect the markers of a synth sequence frame by frame, estimate the "
                    "object's pose from both views through the port, and score it against "
                    "the true poses.")
    p.add_argument("dataset", help="a folder written by python -m synth sequence")
    p.add_argument("--pixel-sigma", type=positive_float, default=None, metavar="PX",
                   help="the detections' σ (px) for the covariance (default: from each "
                        "frame's residuals)")
    p.add_argument("--gate", type=positive_float, default=DEFAULT_GATE_PX, metavar="PX",
                   help=f"largest distance of a detection from its marker's predicted pixel "
                        f"(default {DEFAULT_GATE_PX:g})")
    p.add_argument("--eccentricity", action=argparse.BooleanOptionalAction, default=True,
                   help="correct each detection for its disk's eccentricity, predicted from the "
                        "pose (the markers' normal and radius are known; default on); "
                        "--no-eccentricity: the raw centroids")
    p.add_argument("--lock-on", choices=("detect", "truth"), default="detect",
                   help="how the track starts: detect (default) — the object found from the "
                        "first frame's detections by its shape, no guess (a symmetric object "
                        "takes the turn nearest upright); truth — at the first frame's true "
                        "pose")
    p.add_argument("--absorbed", action=argparse.BooleanOptionalAction, default=True,
                   help="the absorbed baseline beside the refractive pose: both views as pinhole "
                        "cameras whose focal length and distortion absorb the port (default on; "
                        "from --absorbed-calib, or calibrated from boards projected through the "
                        "sequence's port); --no-absorbed leaves it out")
    p.add_argument("--absorbed-calib", metavar="FILE", default=None,
                   help="the absorbed calibration (a calib.yaml without a port: eval calibrate "
                        "--model absorbed)")
    add_out_option(p, COMMAND, default="out/track")
    add_json_option(p)
    add_progress_option(p)
    p.set_defaults(_main=main)
    return p



#: The markers' normal in the object frame (the docking frame faces the cameras: −z).
MARKER_NORMAL = np.array([0.0, 0.0, -1.0])


def eccentricity_offsets(rig, obj, pose, radius_mm):
    """``(2, M, 2)`` px: per view the area centroid of each marker disk's image minus its
    centre's pixel (:func:`measure.images.eccentricity.outline_centroid_offsets`) at ``pose``
    — the bias of a detected centroid the two views share, removed before the pose is
    estimated again."""
    from measure.images.eccentricity import outline_centroid_offsets

    centres = obj @ pose.R.T + pose.t
    normal = pose.R @ MARKER_NORMAL
    return np.stack([outline_centroid_offsets(camera, rig.view_port(v), centres, normal,
                                              radius_mm)
                     for v, camera in enumerate(rig.cameras)])


#: What the eccentricity correction leaves: the corrected centroids of a frame's markers share a
#: radial error (about each view's principal point) that the residuals cannot see. Measured on
#: the full-size approach (``synth sequence scenes/paper_plane.xml --approach 5000,500 --frames
#: 50``, 24 detections a frame against the simulator's pixels): per frame the mean radial
#: residual varies beyond its noise by σ² = (κ r)² + β₀² (maximum likelihood over the 50
#: frames), ``r`` the disk image's radius (px, of the equal area): κ = 5.6e-5 (inwards,
#: 0.0028 px at 0.5 m: the 50 px disks) and β₀ = 6.8e-4 px (at every range). One N(0, σ²)
#: scale of the constellation's image goes into the pose's covariance
#: (:func:`measure.stereo.pose.shared_offset_covariance`).
RESIDUAL_RADIAL_FRACTION = 5.6e-5
#: β₀ above (px).
RESIDUAL_RADIAL_FLOOR_PX = 6.8e-4


def radial_bias_covariance(views, obj, pixels, pose, radius_mm,
                           fraction: float = RESIDUAL_RADIAL_FRACTION,
                           floor_px: float = RESIDUAL_RADIAL_FLOOR_PX):
    """``(6, 6)`` (rad, mm): the pose's covariance from the corrected centroids' shared radial
    error (σ = ``hypot(fraction · r, floor_px)`` px for a marker image of radius ``r`` px,
    along the direction from its view's principal point; :data:`RESIDUAL_RADIAL_FRACTION`).
    ``views``: the rig or one ``View``; ``pixels`` ``(V, M, 2)``."""
    from measure.geometry.projection import project
    from measure.images.eccentricity import disk_basis
    from measure.stereo.pose import as_views, shared_offset_covariance

    views = as_views(views)
    pixels = np.asarray(pixels, dtype=np.float64).reshape(len(views), -1, 2)
    centres = obj @ pose.R.T + pose.t
    u, w = disk_basis(np.broadcast_to(pose.R @ MARKER_NORMAL, centres.shape))
    offsets = np.full(pixels.shape, np.nan)
    for v, view in enumerate(views):
        _, d_points = project(view.camera, view.port, centres, jacobian=True)  # (M, 2, 3)
        disk = d_points @ np.stack([u, w], axis=2)  # d pixel / d (disk coordinates), (M, 2, 2)
        image_radius = radius_mm * np.sqrt(np.abs(np.linalg.det(disk)))  # of the equal area
        outward = pixels[v] - view.camera.K[:2, 2]
        length = np.linalg.norm(outward, axis=1, keepdims=True)
        outward = np.divide(outward, length, out=np.zeros_like(outward), where=length > 0)
        offsets[v] = np.hypot(fraction * image_radius, floor_px)[:, None] * outward
    return shared_offset_covariance(views, obj, pixels, pose, offsets)


def with_radial_bias(views, obj, pixels, pose, radius_mm):
    """``pose`` with :func:`radial_bias_covariance` added to its covariance and to its pixel
    part (an error of the pixels: ``covariance = pixel + rig`` still holds); unchanged where it
    has none."""
    from dataclasses import replace

    if not pose.valid:
        return pose
    extra = np.nan_to_num(radial_bias_covariance(views, obj, pixels, pose, radius_mm))
    return replace(pose, covariance=pose.covariance + extra, pixel=pose.pixel + extra)


VIEW_NAMES = ("left", "right")


def _scored(pose, t_true, R_true, distance, rotation_error, mahalanobis_squared) -> dict:
    """One camera's pose of a frame against the truth (NaN where it has none)."""
    from measure.reasons import Reason

    if not pose.valid:
        return {"reason": Reason(pose.reason).name}
    error = pose.t - t_true
    return {"reason": "OK", "position_error_mm": float(np.linalg.norm(error)),
            "position_error_pct": float(100 * np.linalg.norm(error) / distance),
            "rotation_error_rad": float(rotation_error(pose.R, R_true)),
            "mahalanobis2": float(mahalanobis_squared(error, pose.covariance[3:, 3:])[0]),
            "sigma_t_mm": float(np.sqrt(np.trace(pose.covariance[3:, 3:])))}


def _per_camera_summary(valid, chi2_95) -> dict:
    """Per camera alone: frames with a pose, median and largest position error (mm, % of the
    distance), rotation error, and the share of positions inside their 95 % ellipsoid."""
    out = {}
    for name in VIEW_NAMES:
        got = [r["per_camera"][name] for r in valid if r["per_camera"][name]["reason"] == "OK"]
        if not got:
            out[name] = {"posed": 0}
            continue
        dt = np.array([g["position_error_mm"] for g in got])
        pct = np.array([g["position_error_pct"] for g in got])
        dr = np.array([g["rotation_error_rad"] for g in got])
        d2 = np.array([g["mahalanobis2"] for g in got])
        out[name] = {"posed": len(got),
                     "position_error_mm": {"median": float(np.median(dt)), "max": float(dt.max())},
                     "position_error_pct": {"median": float(np.median(pct)),
                                            "max": float(pct.max())},
                     "rotation_error_rad": {"median": float(np.median(dr)),
                                            "max": float(dr.max())},
                     "coverage_95": float(np.mean(d2 <= chi2_95))}
    return out


def _absorbed(args, rig, log):
    """The absorbed calibration the track's absorbed baseline uses (:mod:`eval.core.absorbed`):
    ``--absorbed-calib``'s, or the sequence's cameras calibrated as pinhole cameras from boards
    projected through their port; None with ``--no-absorbed`` or without a port."""
    from eval.core.absorbed import analytic_absorbed_calibration, read_absorbed_calibration

    if not args.absorbed:
        return None
    if not rig.port.refracts:
        if args.absorbed_calib:
            raise CLIError(f"--absorbed-calib does not apply to {args.dataset}: its rig has no "
                           f"port, so there is nothing to absorb")
        return None
    if args.absorbed_calib:
        try:
            return read_absorbed_calibration(args.absorbed_calib, rig.left.size)
        except ValueError as exc:
            raise CLIError(str(exc)) from None
    log("absorbed baseline: the cameras calibrated as pinhole cameras from boards seen through "
        "the port …")
    try:
        return analytic_absorbed_calibration(rig, seed=0)
    except ValueError as exc:
        raise CLIError(f"{args.dataset}: the absorbed calibration cannot be made: {exc} "
                       f"(--no-absorbed leaves the baseline out)") from None


def absorbed_errors(rows, t_true, frames) -> dict:
    """The absorbed baseline's positions against the truth: as they come (its frame is a
    virtual one, the calibration's) and after the one rigid motion that best aligns all of them
    with the true positions (Kabsch: what remains is the model's distortion of the approach),
    each in % of the distance — median and largest — and its reprojection RMS."""
    from measure.stereo.lockon import kabsch

    got = [r for r in rows if r.get("absorbed_t_mm") is not None]
    if not got:
        return {"posed": 0}
    index = {int(f): k for k, f in enumerate(frames)}
    est = np.array([r["absorbed_t_mm"] for r in got])
    true = np.array([t_true[index[r["frame"]]] for r in got])
    distance = np.linalg.norm(true, axis=1)
    raw = 100 * np.linalg.norm(est - true, axis=1) / distance
    out = {"posed": len(got),
           "position_error_pct": {"median": float(np.median(raw)), "max": float(raw.max())},
           "rms_px": {"median": float(np.median([r["absorbed_rms_px"] for r in got]))}}
    if len(got) >= 3:
        R, t = kabsch(est, true)
        aligned = 100 * np.linalg.norm(est @ R.T + t - true, axis=1) / distance
        out["aligned_position_error_pct"] = {"median": float(np.median(aligned)),
                                             "max": float(aligned.max())}
        for r, e in zip(got, aligned):
            r["absorbed_aligned_error_pct"] = float(e)
    for r, e in zip(got, raw):
        r["absorbed_position_error_pct"] = float(e)
    return out


def track_figure(path, rows) -> None:
    """``track.png``: the distance along the approach (true and estimated) and, per frame, the
    position error of the rig, of each camera alone and of the left camera as a pinhole, with
    the rig's 2σ (sqrt of the position covariance's trace) as a band."""
    from eval.core.figures import new_figure, save_figure

    ok = [r for r in rows if r["reason"] == "OK"]
    frame = np.array([r["frame"] for r in ok])
    fig = new_figure(11, 4)
    a, b = fig.subplots(1, 2)
    a.plot(frame, [r["distance_mm"] for r in ok], "k-", label="true")
    a.plot(frame, [r["distance_mm"] + r["error_mm"][2] for r in ok], "C0.", label="rig (z)")
    a.set_xlabel("frame")
    a.set_ylabel("distance (mm)")
    a.set_title("the approach", fontsize=9)
    a.legend(fontsize=8)
    sigma = np.array([r["sigma_t_mm"] for r in ok])
    floor = 0.3 * min(min(r["position_error_mm"] for r in ok), float(sigma.min()))
    b.fill_between(frame, floor, 2 * sigma, color="C0", alpha=0.2, label="rig 2σ")
    b.semilogy(frame, [r["position_error_mm"] for r in ok], "C0o-", label="rig")
    for c, name in zip(("C1", "C2"), VIEW_NAMES):
        b.semilogy(frame, [r["per_camera"][name].get("position_error_mm", np.nan) for r in ok],
                   f"{c}.--", label=f"{name} alone")
    pinhole = [r["pinhole_position_error_pct"] * r["distance_mm"] / 100 for r in ok]
    b.semilogy(frame, pinhole, "C3x:", label="left as a pinhole")
    if any("absorbed_aligned_error_pct" in r for r in ok):
        b.semilogy(frame, [r.get("absorbed_aligned_error_pct", np.nan) * r["distance_mm"] / 100
                           for r in ok], "C4+:", label="absorbed, aligned")
    b.set_xlabel("frame")
    b.set_ylabel("position error (mm)")
    b.set_title("position error against the true pose", fontsize=9)
    b.legend(fontsize=8)
    save_figure(fig, path)


def main(args) -> int:
    import cv2

    from measure import detect_targets
    from measure.reasons import Reason
    from measure.stereo.multiview import View
    from measure.stereo.pose import estimate_pose, pinhole_pose, rotation_error
    from measure.stereo.uncertainty import CHI2_3_95, mahalanobis_squared
    from synth.infra.fileio import OutputDir, atomic_write_json, jsonable
    from synth.products.sequence import write_tum

    log = ((lambda text: None) if args.no_progress
           else (lambda text: print(text, file=sys.stderr, flush=True)))
    start = time.perf_counter()
    if not args.absorbed and args.absorbed_calib:
        raise CLIError("--absorbed-calib does not apply with --no-absorbed")
    manifest, rig, obj, (frames, R_true, t_true), true_pixels = read_sequence(args.dataset)
    radius = float((manifest.get("object") or {}).get("marker_radius_mm") or 0.0)
    if args.eccentricity and radius <= 0:
        raise CLIError(f"{args.dataset}: its manifest gives no marker radius, which the "
                       f"eccentricity correction needs (--no-eccentricity measures the raw "
                       f"centroids)")
    changed = changed_frames(args.dataset, manifest)
    absorbed = _absorbed(args, rig, log)
    output = OutputDir(args.out, COMMAND).claim()
    if changed:
        print(f"note: {len(changed)} file(s) of {args.dataset} changed since synth sequence "
              f"wrote them ({', '.join(changed[:4])}{', …' if len(changed) > 4 else ''}): "
              f"tracked as they are now, scored against the poses they were rendered with",
              file=sys.stderr)
    if args.lock_on == "truth":  # locked on at the first frame's true pose
        track = {"R": R_true[0], "t": t_true[0], "velocity": np.zeros(3), "fresh": True}
    else:  # locked on from the detections (measure.stereo.lockon)
        track = {"R": None, "t": None, "velocity": np.zeros(3), "fresh": False}
    locks = []
    estimates, rows = [], []
    seconds = {"detect": 0.0, "lock_on": 0.0, "pose": 0.0, "pose_per_camera": 0.0}
    for k, frame in enumerate(frames):
        found = []
        for name in VIEW_NAMES:
            path = os.path.join(args.dataset, "frames", f"{int(frame):04d}_{name}.png")
            image = imread(path, cv2.IMREAD_ANYDEPTH)
            if image is None:
                raise CLIError(f"{path}: missing or not an image OpenCV can read")
            t0 = time.perf_counter()
            found.append(detect_targets(image).centers)
            seconds["detect"] += time.perf_counter() - t0
        detected = [int(c.shape[0]) for c in found]
        pixels, expected, associated, lost, attempt = locate_markers(
            rig, obj, found, track, args.gate, int(frame), seconds, log)
        if attempt is not None:
            locks.append({"frame": int(frame), "markers": attempt.assigned,
                          "rms_mm": attempt.rms_mm, "ambiguous": attempt.ambiguous,
                          "position_error_mm": float(np.linalg.norm(attempt.t - t_true[k])),
                          "rotation_error_rad": float(rotation_error(attempt.R, R_true[k]))})
        # the baselines: the left camera's raw detections as a pinhole that ignores the port,
        # and both views' raw detections through the absorbed calibration (pinhole cameras
        # whose focal length and distortion absorb the port, in their own virtual frame)
        _, t_pinhole = pinhole_pose(rig.left, obj, pixels[0])
        absorbed_pose = (estimate_pose(absorbed.rig, obj, pixels, args.pixel_sigma)
                         if absorbed is not None else None)
        t0 = time.perf_counter()
        pose = estimate_pose(rig, obj, pixels, args.pixel_sigma)
        corrected_pixels = False  # whether the pixels hold the eccentricity correction
        if args.eccentricity and pose.valid:
            pixels = pixels - np.nan_to_num(eccentricity_offsets(rig, obj, pose, radius))
            corrected_pixels = True
            corrected = estimate_pose(rig, obj, pixels, args.pixel_sigma)
            if corrected.valid:  # the term is what the correction leaves
                pose = with_radial_bias(rig, obj, pixels, corrected, radius)
        seconds["pose"] += time.perf_counter() - t0
        t0 = time.perf_counter()  # each camera alone, through its port, on the same pixels
        alone = [estimate_pose(View(camera, rig.view_port(v)), obj, pixels[v],
                               args.pixel_sigma) for v, camera in enumerate(rig.cameras)]
        if corrected_pixels:
            alone = [with_radial_bias(View(camera, rig.view_port(v)), obj, pixels[v], p, radius)
                     for v, (camera, p) in enumerate(zip(rig.cameras, alone))]
        seconds["pose_per_camera"] += time.perf_counter() - t0
        estimates.append(pose)
        miss = (pixels - true_pixels[k]).reshape(-1, 2)
        miss = miss[np.all(np.isfinite(miss), axis=1)]
        row = {"frame": int(frame), "detections": detected,
               "detection_rms_px": float(np.sqrt(np.mean(np.sum(miss ** 2, axis=1))))
               if miss.size else None,
               "observations": pose.observations,
               "reason": ("NOT_LOCKED" if track["R"] is None else "LOST") if lost
               else Reason(pose.reason).name, "locked_on": attempt is not None,
               "markers_expected": expected, "markers_associated": associated}
        # constant velocity from the last two frames' poses (none after a lock-on or a loss)
        track["velocity"] = (pose.t - track["t"] if pose.valid and track["fresh"]
                             and attempt is None else np.zeros(3))
        track["fresh"] = bool(pose.valid)
        if pose.valid:
            track["R"], track["t"] = pose.R, pose.t
            error = pose.t - t_true[k]
            distance = float(np.linalg.norm(t_true[k]))
            row.update({"position_error_mm": float(np.linalg.norm(error)),
                        "position_error_pct": float(100 * np.linalg.norm(error) / distance),
                        "distance_mm": distance,
                        "pinhole_position_error_pct": float(
                            100 * np.linalg.norm(t_pinhole - t_true[k]) / distance),
                        "absorbed_t_mm": (absorbed_pose.t.tolist()
                                          if absorbed_pose is not None and absorbed_pose.valid
                                          else None),
                        "absorbed_rms_px": (absorbed_pose.rms_px if absorbed_pose is not None
                                            and absorbed_pose.valid else None),
                        "error_mm": error.tolist(),
                        "rotation_error_rad": float(rotation_error(pose.R, R_true[k])),
                        "mahalanobis2": float(mahalanobis_squared(
                            error, pose.covariance[3:, 3:])[0]),
                        "sigma_t_mm": float(np.sqrt(np.trace(pose.covariance[3:, 3:]))),
                        "rms_px": pose.rms_px})
            row["per_camera"] = {
                name: _scored(p, t_true[k], R_true[k], distance, rotation_error,
                              mahalanobis_squared)
                for name, p in zip(VIEW_NAMES, alone)}
        rows.append(row)
        log(f"frame {int(frame)}: {row['reason']}"
            + (f", |dt| {row['position_error_mm']:.3g} mm, rotation "
               f"{row['rotation_error_rad']:.3g} rad, {pose.observations} pixels"
               if pose.valid else ""))
    valid = [r for r in rows if r["reason"] == "OK"]
    summary = {"frames": len(rows), "tracked": len(valid)}
    if valid:
        dt = np.array([r["position_error_mm"] for r in valid])
        dr = np.array([r["rotation_error_rad"] for r in valid])
        d2 = np.array([r["mahalanobis2"] for r in valid])
        miss = [r["detection_rms_px"] for r in rows if r["detection_rms_px"] is not None]
        pct = np.array([r["position_error_pct"] for r in valid])
        pinhole = np.array([r["pinhole_position_error_pct"] for r in valid])
        if absorbed is not None:
            summary["absorbed"] = {**absorbed_errors(valid, t_true, frames),
                                   "calibration": absorbed.summary}
        summary.update({"detection_rms_px": {"median": float(np.median(miss)),
                                             "max": float(np.max(miss))},
                        "position_error_pct": {"median": float(np.median(pct)),
                                               "max": float(pct.max())},
                        "pinhole_position_error_pct": {"median": float(np.nanmedian(pinhole)),
                                                       "max": float(np.nanmax(pinhole))},
                        "position_error_mm": {"median": float(np.median(dt)),
                                              "max": float(dt.max())},
                        "rotation_error_rad": {"median": float(np.median(dr)),
                                               "max": float(dr.max())},
                        "coverage_95": float(np.mean(d2 <= CHI2_3_95)),
                        "per_camera": _per_camera_summary(valid, CHI2_3_95),
                        "poses_per_s": {
                            "rig": len(rows) / seconds["pose"] if seconds["pose"] else None,
                            "each_camera": 2 * len(rows) / seconds["pose_per_camera"]
                            if seconds["pose_per_camera"] else None,
                            "note": "after detection; rig: both views jointly, with the "
                                    "eccentricity correction's second solve and the shared "
                                    "radial term; each camera: one view, one solve and the "
                                    "term"}})
    detect = args.lock_on == "detect"  # the first lock-on started the track
    report = {"dataset": args.dataset, "sequence": {k: manifest.get(k) for k in (
        "approach_mm", "yaw_deg", "trajectory", "frames", "fps", "object", "image_size")},
        "pixel_sigma_px": args.pixel_sigma, "gate_px": args.gate,
        "changed_since_written": changed, "eccentricity": bool(args.eccentricity),
        # the lock-on that started the track, and those after a lost frame ("again")
        "lock_on": {"mode": args.lock_on, **(locks[0] if locks and detect else {}),
                    "again": locks[1:] if detect else locks},
        "summary": summary,
        "frames": rows}
    ok = np.array([p.valid for p in estimates])
    with output.staged() as tmp:
        from scipy.spatial.transform import Rotation

        # the sequence's own time stamps (a --trajectory sequence's need not be regular)
        times = np.atleast_1d(np.genfromtxt(os.path.join(args.dataset, "poses.csv"),
                                            delimiter=",", names=True)["time_s"]).astype(float)
        with open(os.path.join(tmp, "poses.csv"), "w") as fh:
            fh.write("frame,time_s,tx_mm,ty_mm,tz_mm,qx,qy,qz,qw,sigma_t_mm,rms_px,"
                     "observations,reason\n")
            for k, p in enumerate(estimates):
                q = Rotation.from_matrix(p.R).as_quat() if p.valid else np.full(4, np.nan)
                sigma = np.sqrt(np.trace(p.covariance[3:, 3:]))
                fh.write(",".join([str(int(frames[k])), f"{times[k]:.6f}",
                                   *(repr(float(v)) for v in p.t), *(repr(float(v)) for v in q),
                                   repr(float(sigma)), repr(float(p.rms_px)),
                                   str(p.observations), Reason(p.reason).name]) + "\n")
        if ok.any():
            write_tum(os.path.join(tmp, "poses_tum.txt"), times[ok],
                      np.stack([p.R for p in estimates])[ok], np.stack([p.t for p in estimates])[ok])
        if valid:
            track_figure(os.path.join(tmp, "track.png"), rows)
        report["timings_s"] = {**seconds, "total": time.perf_counter() - start}
        report = jsonable(report)
        atomic_write_json(os.path.join(tmp, "report.json"), report)
    stream = sys.stderr if args.json else sys.stdout
    if valid:
        print(f"tracked {summary['tracked']} of {summary['frames']} frames: position error "
              f"median {summary['position_error_mm']['median']:.3g} mm (max "
              f"{summary['position_error_mm']['max']:.3g}; max {summary['position_error_pct']['max']:.3g} % "
              f"of the distance, the left camera as a pinhole: "
              f"{summary['pinhole_position_error_pct']['max']:.3g} %), rotation median "
              f"{summary['rotation_error_rad']['median']:.3g} rad (max "
              f"{summary['rotation_error_rad']['max']:.3g}); {summary['coverage_95']:.0%} of "
              f"the positions inside their 95 % ellipsoid; detections "
              f"{summary['detection_rms_px']['median']:.3g} px RMS from the simulator's pixels "
              f"(median over frames)", file=stream)
        if summary.get("absorbed", {}).get("posed"):
            a = summary["absorbed"]
            print(f"absorbed baseline (pinhole cameras that absorb the port): position error "
                  f"median {a['position_error_pct']['median']:.3g} %, max "
                  f"{a['position_error_pct']['max']:.3g} % of the distance"
                  + (f"; after the best rigid alignment of the whole track median "
                     f"{a['aligned_position_error_pct']['median']:.3g} %, max "
                     f"{a['aligned_position_error_pct']['max']:.3g} %"
                     if "aligned_position_error_pct" in a else ""), file=stream)
        alone = summary["per_camera"]
        print("each camera alone through its port: " + "; ".join(
            f"{name} {a['posed']} posed, median {a['position_error_mm']['median']:.3g} mm (max "
            f"{a['position_error_pct']['max']:.3g} %), {a['coverage_95']:.0%} inside"
            if a["posed"] else f"{name} 0 posed" for name, a in alone.items())
            + f"; {summary['poses_per_s']['rig']:.0f} rig poses/s, "
              f"{summary['poses_per_s']['each_camera']:.0f} one-camera poses/s after detection",
            file=stream)
    else:
        print(f"tracked 0 of {summary['frames']} frames", file=stream)
    print(f"wrote {output.path}", file=stream)
    if args.json:
        print(json.dumps(report, indent=2))
    return 0 if summary["tracked"] == summary["frames"] else 1
