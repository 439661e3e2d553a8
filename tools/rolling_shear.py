"""The shear a rolling shutter puts on a moving board, measured on the rendered images of a
``synth boards --readout-ms T --board-velocity V`` folder.

    python tools/rolling_shear.py BOARDS_FOLDER

Per pose and view: OpenCV's corners (:meth:`measure.calibration.board.Board.detect`) minus the
forward model's pixels of the board standing still at its pose (the middle of the readout),
``du`` regressed on the row ``v``: the measured shear, px per 1000 rows. Beside it, motion ×
readout time: the board's image velocity at each corner (px/s, the forward model's pixels at
t = ±1 ms) times the instant of its row, ``t(v) = T · (v / (H − 1) − ½)``, regressed the same
way; and the RMS of the detected corners against ``corners.csv`` (the truth that follows the
rows). Prints one line per view and exits 0.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def view_shear(image, camera, port, board, pose, effects, truth_uv):
    """``(measured, expected, rms)``: the shear in px per 1000 rows of the detected corners and
    of motion × readout time, and the detected corners' RMS against ``truth_uv`` (px); None
    where the board is not found."""
    from measure.geometry.projection import project

    from measure.calibration.board import MIN_CORNERS

    corners = board.corners()
    ids, uv = board.detect(image)
    if ids.size < MIN_CORNERS:
        return None
    still = project(camera, port, pose.apply(corners))[ids]
    dt = 1e-3
    ends = [project(camera, port, pose.apply(corners[ids]) + effects.board_shift(s * dt))
            for s in (-1.0, 1.0)]
    velocity = (ends[1] - ends[0]) / (2 * dt)  # px/s
    t = effects.row_time(still[:, 1], camera.size[1])
    design = np.column_stack([np.ones(len(ids)), still[:, 1] / 1000.0])
    measured = np.linalg.lstsq(design, uv[:, 0] - still[:, 0], rcond=None)[0][1]
    expected = np.linalg.lstsq(design, velocity[:, 0] * t, rcond=None)[0][1]
    rms = float(np.sqrt(np.mean(np.sum((uv - truth_uv[ids]) ** 2, axis=1))))
    return float(measured), float(expected), rms


def folder_shear(folder) -> list:
    """Per pose and view ``(pose, view, (measured, expected, rms) or None)`` of a rolling boards
    folder (:func:`view_shear`)."""
    from synth.products.board_camera import CameraEffects
    from synth.products.boards import read_boards

    data = read_boards(folder)
    effects = CameraEffects(**data.manifest.get("camera_effects", {}))
    if not effects.rolling:
        raise ValueError(f"{folder}: not rendered with a rolling shutter (--readout-ms)")
    rig = data.calib["rig"]
    rows = []
    for k, (pair, pose) in enumerate(zip(data.images, data.poses)):
        truth = data.corners[data.corners[:, 0] == k]
        for v, (image, camera) in enumerate(zip(pair, rig.cameras)):
            rows.append((k, v, view_shear(image, camera, rig.view_port(v), data.board, pose,
                                          effects, truth[:, 5 + 2 * v:7 + 2 * v])))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder")
    args = parser.parse_args(argv)
    try:
        rows = folder_shear(args.folder)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for k, v, shear in rows:
        if shear is None:
            print(f"pose {k:2d} view {v}: board not found")
            continue
        measured, expected, rms = shear
        print(f"pose {k:2d} view {v}: shear {measured:+.3f} px/1000 rows, motion x readout "
              f"{expected:+.3f} ({measured / expected - 1:+.2%}); corners vs truth RMS "
              f"{rms:.4f} px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
