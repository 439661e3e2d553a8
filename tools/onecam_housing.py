"""One camera's housing: does its σ cover its error? And how near the truth is a rendered chain?

``coverage``: for each seed S, analytic corners (the Fermat forward model,
:func:`measure.geometry.projection.project`, plus Gaussian pixel noise — no render) of one
camera (the paper's left camera, 2448 × 2048, f = 1100 px) and an 11 × 8 board of 40 mm squares:

* in air, 15 poses (seed S, 0.35–0.8 m), noise ``--air-noise`` px per axis, calibrated by OpenCV
  (``calibrate_camera``, standard lens model) with its intrinsics' covariance
  (:func:`eval.calibrate.single.camera_covariance`, what ``camera.yaml`` carries);
* underwater, 15 poses (seed 1000 + S, ``--distance``), noise ``--noise`` px per axis, behind a
  flat port tilted 1° (D = 100 mm, 5 mm glass, 1.0/1.54/1.33) and behind a dome decentred
  (2, 0, 0) mm (radius 50, thickness 8 mm);

and fits each housing (:func:`measure.calibration.housing.calibrate_camera_housing`) two ways:
``exact`` — the true camera, σ conditional — and ``chain`` — the in-air estimate with its
covariance (``--air-uncertainty prior``, the default). Printed per kind, mode and component:
the fraction of seeds with |error| ≤ 2σ, the largest |error / σ|, the RMS error and RMS σ.

``compare BOARDS CAL``: a ``synth boards`` folder's truth (its left camera's port) beside the
``report.json`` of ``eval calibrate BOARDS_LEFT --intrinsics …`` (one camera): the error of D,
of the normal (deg) or of the dome centre (mm), and the three RMS.

    python tools/onecam_housing.py coverage [--seeds 20] [--noise 0.02] [--air-noise 0.01]
    python tools/onecam_housing.py compare out/boards_tilt out/cal_tilt
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

BOARD_SQUARES, SQUARE_MM, POSES = (11, 8), 40.0, 15
INDICES = (1.0, 1.54, 1.33)
TILT_DEG, DISTANCE_MM, GLASS_MM = 1.0, 100.0, 5.0
DOME_OFFSET_MM, DOME_RADIUS_MM, DOME_THICKNESS_MM = (2.0, 0.0, 0.0), 50.0, 8.0


def _setup():
    from measure import FlatPort, StereoRig
    from synth.scene.dome import dome_pair
    from synth.scene.rig import paper_cameras

    camera = paper_cameras()[0]
    t = np.radians(TILT_DEG)
    ports = {"flat": (FlatPort((np.sin(t), 0.0, np.cos(t)), DISTANCE_MM, (GLASS_MM,), INDICES),
                      lambda cam: FlatPort((0.0, 0.0, 1.0), DISTANCE_MM, (GLASS_MM,), INDICES)),
             "dome": (dome_pair((camera, camera), DOME_RADIUS_MM, DOME_THICKNESS_MM,
                                DOME_OFFSET_MM, INDICES),
                      lambda cam: dome_pair((cam, cam), DOME_RADIUS_MM, DOME_THICKNESS_MM,
                                            (0.0, 0.0, 0.0), INDICES))}
    return camera, ports, StereoRig


def _corners(camera, port, board, seed, water, distance, noise, rng):
    from measure import StereoRig
    from measure.calibration.air import Detections
    from measure.geometry.projection import project
    from synth.products.boards import sample_poses

    rig = StereoRig(camera, camera, port)
    ids, pixels = [], []
    for pose in sample_poses(rig, board, POSES, seed, water, distance):
        world = pose.apply(board.corners())
        uv = project(camera, rig.view_port(0) if water else None, world)
        ids.append([np.arange(len(world)), np.empty(0, int)])
        pixels.append([uv + rng.normal(0.0, noise, uv.shape), np.empty((0, 2))])
    return Detections(ids, pixels)


def _in_air(camera, board, seed, noise):
    """OpenCV's calibration of analytic in-air corners and its covariance (camera.yaml's)."""
    from measure import Camera
    from measure.calibration.air import calibrate_camera

    from eval.calibrate.single import camera_covariance

    rng = np.random.default_rng(seed)
    dets = _corners(camera, None, board, seed, False, (350.0, 800.0), noise, rng)
    corners = board.corners().astype(np.float32)
    obj = [corners[dets.ids[k][0]] for k in range(dets.n_poses)]
    img = [dets.pixels[k][0].astype(np.float32) for k in range(dets.n_poses)]
    out, _, _, _ = calibrate_camera(obj, img, camera.size, "standard")
    return Camera(out[1], camera.size, dist=out[2].ravel()[:5]), camera_covariance(obj, out)


def _errors(kind, cal, truth, camera):
    """``(labels, error, sigma)`` of the free housing numbers against the truth."""
    from measure.calibration.dome import dome_offset

    if kind == "flat":
        port = cal.rig.view_port(0)
        axes = np.asarray(cal.normal_axes)
        error = np.r_[port.distance - truth.distance, axes @ (port.normal - truth.normal)]
        sigma = np.r_[cal.sigmas["distance"], cal.sigmas["normal"]]
        return ("D (mm)", "tilt a (rad)", "tilt b (rad)"), error, sigma
    error = np.asarray(cal.estimates["dome_center"]["left"]) - dome_offset(camera, truth.left)
    return ("centre x (mm)", "centre y (mm)", "centre z (mm)"), error, np.asarray(
        cal.sigmas["dome_center"])


def coverage(args) -> int:
    from measure.calibration.board import Board
    from measure.calibration.housing import calibrate_camera_housing

    camera, ports, _ = _setup()
    board = Board("chessboard", BOARD_SQUARES, SQUARE_MM)
    rows = {}
    for seed in range(1, args.seeds + 1):
        air_camera, air_cov = _in_air(camera, board, seed, args.air_noise)
        for kind, (truth, start) in ports.items():
            rng = np.random.default_rng(10_000 + seed)
            dets = _corners(camera, truth, board, 1000 + seed, True, tuple(args.distance),
                            args.noise, rng)
            for mode, cam, cov in (("exact", camera, None), ("chain", air_camera, air_cov)):
                cal = calibrate_camera_housing(cam, start(cam), board, dets, air_covariance=cov)
                if not cal.identifiable:
                    print(f"seed {seed} {kind} {mode}: {cal.reason}", file=sys.stderr)
                    continue
                labels, error, sigma = _errors(kind, cal, truth, camera)
                rows.setdefault((kind, mode), []).append((error, sigma, cal.rms_px))
        print(f"seed {seed} done", file=sys.stderr, flush=True)
    result = {}
    for (kind, mode), values in rows.items():
        errors = np.array([v[0] for v in values])
        sigmas = np.array([v[1] for v in values])
        z = errors / sigmas
        labels = (("D (mm)", "tilt a (rad)", "tilt b (rad)") if kind == "flat"
                  else ("centre x (mm)", "centre y (mm)", "centre z (mm)"))
        print(f"\n{kind}, {mode} ({len(values)} seeds; corner RMS of the fits "
              f"{np.mean([v[2] for v in values]):.4f} px):")
        print(f"{'component':16s} {'within 2σ':>9s} {'max |z|':>8s} {'RMS error':>10s} "
              f"{'RMS σ':>10s} {'max |error|':>11s}")
        for j, label in enumerate(labels):
            scale = np.degrees(1.0) if "rad" in label else 1.0
            name = label.replace("(rad)", "(deg)")
            within = float(np.mean(np.abs(z[:, j]) <= 2))
            print(f"{name:16s} {100 * within:8.0f}% {np.abs(z[:, j]).max():8.2f} "
                  f"{scale * np.sqrt(np.mean(errors[:, j] ** 2)):10.4g} "
                  f"{scale * np.sqrt(np.mean(sigmas[:, j] ** 2)):10.4g} "
                  f"{scale * np.abs(errors[:, j]).max():11.4g}")
        angle = (np.degrees(np.linalg.norm(errors[:, 1:], axis=1)) if kind == "flat"
                 else np.linalg.norm(errors, axis=1))
        what = "normal angle (deg)" if kind == "flat" else "centre distance (mm)"
        print(f"{what}: max {angle.max():.4g}, median {np.median(angle):.4g}; all values "
              f"within 2σ: {100 * float(np.mean(np.abs(z) <= 2)):.0f}%")
        result[f"{kind}_{mode}"] = {"labels": list(labels), "errors": errors.tolist(),
                                    "sigmas": sigmas.tolist()}
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=1)
    return 0


def compare(args) -> int:
    from measure.calibration.dome import dome_offset
    from synth.products.dataset import read_calib

    truth = read_calib(os.path.join(args.boards, "calib.yaml"))["rig"]
    with open(os.path.join(args.cal, "report.json")) as fh:
        report = json.load(fh)
    e = report["estimates"]
    if "dome_center" in e:
        true = dome_offset(truth.left, truth.port.left)
        error = np.asarray(e["dome_center"]["estimate"]) - true
        print(f"dome centre: estimate {np.round(e['dome_center']['estimate'], 4).tolist()} mm, "
              f"truth {np.round(true, 4).tolist()}, error {np.round(error, 4).tolist()} mm "
              f"(|error| {np.linalg.norm(error):.4f} mm), σ "
              f"{np.round(e['dome_center']['sigma'], 4).tolist()} mm")
    else:
        port = truth.view_port(0)
        n = np.asarray(e["normal"]["estimate"])
        angle = np.degrees(np.arccos(np.clip(n @ port.normal, -1, 1)))
        print(f"D: estimate {e['distance']['estimate']:.4f} mm, truth {port.distance:.4f}, "
              f"error {e['distance']['estimate'] - port.distance:+.4f} mm, σ "
              f"{e['distance']['sigma']:.4f} mm")
        print(f"normal: tilt {e['normal']['tilt_deg']:.4f}° (truth "
              f"{np.degrees(np.arccos(port.normal[2])):.4f}°), angle to the truth "
              f"{angle:.4f}°, σ {np.round(e['normal']['sigma'], 4).tolist()}°")
    r = report["rms_px"]
    print(f"RMS: housing {r['housing']:.4f} px, in air {r['in_air']} px, pinhole absorbing the "
          f"port {r['absorbed_pinhole']:.4f} px ({r['absorbed_pinhole_model']})")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    c = sub.add_parser("coverage")
    c.add_argument("--seeds", type=int, default=20)
    c.add_argument("--noise", type=float, default=0.02, help="underwater px per axis")
    c.add_argument("--air-noise", type=float, default=0.01, help="in-air px per axis")
    c.add_argument("--distance", type=float, nargs=2, default=(350.0, 800.0))
    c.add_argument("--json", help="write every error and σ here")
    m = sub.add_parser("compare")
    m.add_argument("boards")
    m.add_argument("cal")
    args = parser.parse_args(argv)
    return coverage(args) if args.what == "coverage" else compare(args)


if __name__ == "__main__":
    sys.exit(main())
