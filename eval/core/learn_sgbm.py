"""What refraction does to a learner's inputs: OpenCV's ``StereoSGBM`` on a sea scene of
``python -m synth learn`` rectified three ways, each scored against the truth of its own frame.

The three rectifications (:data:`METHODS`):

* ``pinhole`` — the raw pair rectified as if the cameras were pinholes in water with their in-air
  intrinsics and pose (the port ignored): ``cv2.stereoRectify`` + ``initUndistortRectifyMap``;
* ``absorbed`` — the same with the *absorbed* pinhole calibration (the cameras calibrated under
  water as pinholes with OpenCV's distortion, the port absorbed: :mod:`eval.core.absorbed`,
  from 15 boards projected through the scene's port at 0.7–1.3 × its median distance, the
  board's squares scaled with that distance, lens model k1 k2 p1 p2: ``tools/learn_sgbm.py``);
* ``port-exact`` — the scene's own rectified pair (:mod:`measure.stereo.rectify`, exact on the
  plane at its median distance: ``rectified/``).

The truth of each frame: every rectified left pixel's real left pixel (its map), that pixel's
refracted ray to the sea floor, the point's Fermat projection into the right camera (seen by it,
:func:`synth.products.learn_truth.correspondence`), that right pixel carried into the rectified
right image (the rectification's homography with the lens model, ``cv2.undistortPoints``; the
port-exact warp's own inverse) — so the truth disparity of a frame is where the point *is* in
it. Depths: each method's disparity triangulated by its own pinhole pair (``f·B/d`` along the
rectified left camera, put back into the reference frame), against the truth point's z along
the left camera's axis (mm); ``port-exact + refractive`` also triangulates the port-exact
matches with the true rig through its port (``optical_path``), as a port-aware tool would.

``StereoSGBM`` (``MODE_SGBM_3WAY``, block 5, P1 = 8·25, P2 = 32·25, uniqueness 10, speckle
window 100 / range 2) searches the disparities of the frame's truth ± 16 px (rounded to a
multiple of 16; at most :data:`MAX_DISPARITIES`, around the truth's median, and no more than
the image's width leaves: a frame whose matches lie off its right image gets no disparity) for
every method alike: an oracle range, so that the scores are the rectification's and not the
search's.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import cv2
import numpy as np

from eval.core.disparity_scores import disparity_scores
from measure import triangulate
from synth.formats.calib_formats import stereo_extrinsics
from synth.formats.exchange import read_pfm
from synth.products import learn_truth as lt
from synth.products.truth_maps import MeshTracer, pixel_grid
from synth.scene.sea_draw import SeaRanges, draw_scene
from synth.scene.surfaces import read_ply

METHODS = ("pinhole", "absorbed", "port-exact", "port-exact + refractive")
BLOCK = 5
#: The widest search (px): a frame whose truth spans more is searched around its median.
MAX_DISPARITIES = 512
#: Every this many rectified pixels (in raster order: every second pixel of each row of an
#: even width) are kept for the depth statistics.
DEPTH_STEP = 2


@dataclass(frozen=True)
class SceneForEval:
    """A scene folder of a learning set with what scoring needs: the drawn scene, the tracer of
    its floor, its 8-bit photos and its folder."""

    folder: str
    scene: object
    tracer: MeshTracer
    left: np.ndarray
    right: np.ndarray
    manifest: dict


def load_scene(folder: str) -> SceneForEval:
    """A scene of a learning set, drawn again from its seed and ranges (the rig is the one that
    rendered it: the same seed, the same draws)."""
    with open(os.path.join(folder, "manifest.json"), encoding="utf-8") as handle:
        manifest = json.load(handle)
    ranges = SeaRanges(**{k: tuple(v) for k, v in manifest["generator"]["ranges"].items()})
    scene = draw_scene(manifest["seed"], ranges)
    mesh = os.path.join(folder, "scene", "seabed.ply")
    vertices, triangles = read_ply(mesh)
    images = [cv2.imread(os.path.join(folder, f"{v}.png"), cv2.IMREAD_GRAYSCALE)
              for v in ("left", "right")]
    return SceneForEval(folder, scene, MeshTracer(mesh, vertices, triangles), *images, manifest)


def pinhole_rectification(left, right) -> dict:
    """``cv2.stereoRectify`` (``alpha = 0``) of two pinhole cameras (their K, distortion and
    poses) and its maps: ``{K, D, R, P (per view), Q, maps}``."""
    size = tuple(left.size)
    R, T = stereo_extrinsics(left, right)
    D = [np.zeros(5) if c.dist is None else np.asarray(c.dist, float) for c in (left, right)]
    R1, R2, P1, P2, Q = cv2.stereoRectify(left.K, D[0], right.K, D[1], size, R,
                                          T.reshape(3, 1), alpha=0)[:5]
    maps = [cv2.initUndistortRectifyMap(c.K, d, r, p, size, cv2.CV_32FC1)
            for c, d, r, p in ((left, D[0], R1, P1), (right, D[1], R2, P2))]
    return {"K": (left.K, right.K), "D": D, "R": (R1, R2), "P": (P1, P2), "Q": Q, "maps": maps}


def pinhole_truth(item: SceneForEval, rect: dict):
    """The truth of a pinhole rectification's frame: disparity ``(H, W)`` (NaN where the right
    camera does not see the point), the truth points ``(H·W, 3)`` of the rectified left pixels."""
    rig = item.scene.rig
    w, h = rig.left.size
    real = np.column_stack([m.ravel() for m in rect["maps"][0]]).astype(np.float64)
    real[~rig.left.in_image(real)] = np.nan
    points = np.full((real.shape[0], 3), np.nan)
    shows = np.all(np.isfinite(real), axis=1)
    points[shows] = lt.pixel_hits(item.tracer, rig, 0, real[shows])[0]
    uv_right, seen = lt.correspondence(item.tracer, rig, points, 1)
    q_right = np.full_like(uv_right, np.nan)
    if seen.any():
        q_right[seen] = cv2.undistortPoints(uv_right[seen].reshape(-1, 1, 2), rect["K"][1],
                                            rect["D"][1], R=rect["R"][1],
                                            P=rect["P"][1]).reshape(-1, 2)
    return (pixel_grid((w, h))[:, 0] - q_right[:, 0]).reshape(h, w), points


def sgbm(left8: np.ndarray, right8: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``StereoSGBM`` (module docs) over the truth's disparities ± 16 px (px; at most
    :data:`MAX_DISPARITIES` of them, around the truth's median, and only those the image's
    width leaves room for); NaN where it gave none, everywhere when the truth has none."""
    finite = truth[np.isfinite(truth)]
    if not finite.size:
        return np.full(left8.shape, np.nan)
    low = int(np.floor((finite.min() - 16) / 16.0) * 16)
    count = int(np.ceil((finite.max() + 16 - low) / 16.0) * 16)
    if count > MAX_DISPARITIES:  # a span no matcher searches: the middle of it
        low = int(np.floor((np.median(finite) - MAX_DISPARITIES / 2) / 16.0) * 16)
        count = MAX_DISPARITIES
    # OpenCV fails (an allocation of ~2^64 bytes, or a crash) unless the search ends at a
    # disparity of 16 or more and leaves the block room within the image's width.
    count = max(count, int(np.ceil((16 - low) / 16.0) * 16))
    count = min(count, MAX_DISPARITIES, (left8.shape[1] - max(low, 0) - 2 * BLOCK) // 16 * 16)
    if count < 16 or low + count < 16:  # the matches lie off the right image: none to find
        return np.full(left8.shape, np.nan)
    matcher = cv2.StereoSGBM_create(minDisparity=low, numDisparities=count, blockSize=BLOCK,
                                    P1=8 * BLOCK ** 2, P2=32 * BLOCK ** 2, uniquenessRatio=10,
                                    speckleWindowSize=100, speckleRange=2,
                                    mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    raw = matcher.compute(left8, right8).astype(np.float64) / 16.0
    return np.where(raw >= low, raw, np.nan)


def pinhole_points(rect: dict, disparity: np.ndarray) -> np.ndarray:
    """Reference-frame points ``(H·W, 3)`` of a pinhole rectification's disparities (its Q; the
    rectified left camera is turned by ``R1`` from the real left one, the reference)."""
    xyz = cv2.reprojectImageTo3D(np.nan_to_num(disparity, nan=0).astype(np.float32),
                                 rect["Q"]).reshape(-1, 3).astype(np.float64)
    xyz[~np.isfinite(disparity).ravel()] = np.nan
    return xyz @ rect["R"][0]  # X_ref = R1ᵀ X_rect


def _exact_points(item: SceneForEval, warp, disparity: np.ndarray, refractive: bool):
    """Reference-frame points of the port-exact pair's disparities: the virtual pair's pinhole
    triangulation, or (``refractive``) the matches carried back to real pixels and
    triangulated through the port (``optical_path``)."""
    h, w = disparity.shape
    q = pixel_grid((w, h))
    d = disparity.ravel()
    ok = np.isfinite(d)
    q_right = q[ok] - np.column_stack([d[ok], np.zeros(ok.sum())])
    points = np.full((q.shape[0], 3), np.nan)
    if not refractive:
        points[ok] = triangulate(warp.virtual, q[ok], q_right, "regular").points
        return points
    right_real = np.column_stack([lt.bilinear(m.astype(np.float64), q_right)[0]
                                  for m in warp.maps[1]])
    outside = lt.bilinear((warp.maps[1][0] < 0).astype(np.float64), q_right)[0]
    left_real = np.column_stack([warp.maps[0][0].ravel()[ok], warp.maps[0][1].ravel()[ok]])
    bad = np.any(left_real < 0, axis=1) | ~(outside == 0)
    right_real[bad] = np.nan
    points[ok] = triangulate(item.scene.rig, left_real.astype(np.float64), right_real,
                             "optical_path").points
    return points


def _depths(points_pred, points_true):
    """z along the left camera's axis (the reference z) of predicted and true points, every
    :data:`DEPTH_STEP`-th pixel."""
    return points_pred[::DEPTH_STEP, 2], points_true[::DEPTH_STEP, 2]


def score_scene(item: SceneForEval, absorbed_rig=None) -> dict:
    """``{method: {"scores": disparity_scores, "z": (predicted, true)}}`` of one scene
    (module docs); ``absorbed_rig`` the absorbed calibration's rig (None: leave it out)."""
    rig = item.scene.rig
    out = {}
    cameras = {"pinhole": (rig.left, rig.right)}
    if absorbed_rig is not None:
        cameras["absorbed"] = (absorbed_rig.left, absorbed_rig.right)
    for method, (left, right) in cameras.items():
        rect = pinhole_rectification(left, right)
        truth, points = pinhole_truth(item, rect)
        views = [cv2.remap(image, *maps, cv2.INTER_LINEAR)
                 for image, maps in zip((item.left, item.right), rect["maps"])]
        disparity = sgbm(views[0], views[1], truth)
        predicted = pinhole_points(rect, disparity)
        out[method] = {"scores": disparity_scores(disparity, truth),
                       "z": _depths(predicted, points)}
    folder = os.path.join(item.folder, "rectified")
    rectified = item.manifest["rectified"]
    warp, reals = lt.rectification_of(rig, rectified["distance_mm"],
                                      rectified.get("disparity_offset_px", 0.0))
    stored = read_pfm(os.path.join(folder, "disparity.pfm")).astype(np.float64)
    hidden = cv2.imread(os.path.join(folder, "occlusion.png"), cv2.IMREAD_UNCHANGED) > 0
    truth = np.where((stored > 0) & ~hidden, stored, np.nan)
    views = [cv2.imread(os.path.join(folder, f"{v}.png"), cv2.IMREAD_GRAYSCALE)
             for v in ("left", "right")]
    disparity = sgbm(views[0], views[1], truth)
    true_points = np.full((reals[0].shape[0], 3), np.nan)
    shows = rig.left.in_image(reals[0])
    true_points[shows] = lt.pixel_hits(item.tracer, rig, 0, reals[0][shows])[0]
    scores = disparity_scores(disparity, truth)
    for method, refractive in (("port-exact", False), ("port-exact + refractive", True)):
        predicted = _exact_points(item, warp, disparity, refractive)
        out[method] = {"scores": scores, "z": _depths(predicted, true_points)}
    return out


__all__ = ["METHODS", "SceneForEval", "load_scene", "pinhole_points", "pinhole_rectification",
           "pinhole_truth", "score_scene", "sgbm"]
