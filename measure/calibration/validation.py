"""Which model predicts photos it has not seen: the housing (the in-air camera behind its port)
against a pinhole camera that absorbs the port, by cross-validation over the photos.

The absorbed pinhole fits its eight (or more) intrinsics to the underwater photos themselves;
the housing keeps the in-air intrinsics (moved only within their in-air prior) and fits two or
three port numbers. On the photos they were fitted to the pinhole has the lower RMS almost
always — more numbers fitted to the same corners — so comparing raw RMS rejects a right port
(OUC's flat interface: 0.230 against 0.218 px). Here each model is fitted without a group of
photos and asked to predict them: a held-out photo's board pose is fitted with the model held
(six numbers per photo, the same for both), and its corners' residuals are the prediction
error (:func:`cross_validate_housing`). The photos are split into :data:`FOLDS` groups
(every ``k``-th photo; one photo a group when there are fewer).

The verdict (:class:`CrossValidation`): the per-photo difference of the mean squared
prediction errors, housing minus pinhole, over the photos; the housing is worse than the
pinhole when the mean difference exceeds :data:`WORSE_SIGMAS` standard errors of the mean (a
paired test; photos, not corners, are the independent units, since a photo's corners share
its errors) and its prediction RMS exceeds the pinhole's by more than :data:`WORSE_FRACTION`.

Units: px (OpenCV pixels), mm; the camera's frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry.projection import project
from ..stereo.multiview import View
from ..stereo.pose import estimate_pose
from .air import CalibrationError, Detections, calibrate_camera

#: Groups of photos held out in turn (fewer photos: one each).
FOLDS = 5
#: The housing predicts worse than the pinhole when the mean per-photo difference of the
#: squared errors exceeds this many of its standard errors and the housing's prediction RMS
#: exceeds the pinhole's by more than this fraction (a difference that matters).
WORSE_SIGMAS, WORSE_FRACTION = 3.0, 0.05
#: Fewest photos with a prediction from both models for a verdict.
MIN_PREDICTED = 4


@dataclass(frozen=True)
class CrossValidation:
    """Prediction errors of held-out photos: ``housing_rms_px`` and ``pinhole_rms_px`` over
    every corner predicted; ``per_photo`` ``{pose: (housing mean square, pinhole mean
    square)}`` px²; ``difference_px2`` the mean per-photo difference (housing − pinhole) and
    ``standard_error_px2`` its standard error; ``housing_worse`` the verdict (module docs);
    ``folds`` the groups; ``failed`` the poses no prediction could be made for (a fold whose
    fit failed, a pose that could not be fitted)."""

    housing_rms_px: float
    pinhole_rms_px: float
    per_photo: dict
    difference_px2: float
    standard_error_px2: float
    housing_worse: bool
    folds: int
    failed: tuple

    def to_dict(self) -> dict:
        return {"housing_rms_px": self.housing_rms_px, "pinhole_rms_px": self.pinhole_rms_px,
                "difference_px2": self.difference_px2,
                "standard_error_px2": self.standard_error_px2,
                "housing_worse": self.housing_worse, "folds": self.folds,
                "photos": len(self.per_photo), "failed": list(self.failed),
                "rule": f"the housing predicts held-out photos worse when the mean per-photo "
                        f"difference of the squared errors exceeds {WORSE_SIGMAS:g} standard "
                        f"errors and its RMS the pinhole's by more than "
                        f"{100 * WORSE_FRACTION:g} %"}


def _one_view(detections: Detections, poses) -> Detections:
    """Camera 0's corners of ``poses`` only (the other poses empty)."""
    keep = set(poses)
    empty = (np.empty(0, int), np.empty((0, 2)))
    return Detections([[ids[0] if k in keep else empty[0], empty[0]]
                       for k, ids in enumerate(detections.ids)],
                      [[px[0] if k in keep else empty[1], empty[1]]
                       for k, px in enumerate(detections.pixels)])


def _housing_errors(fit_housing, board, detections, train, test) -> dict:
    """``{pose: squared errors (M,)}`` of the held-out ``test`` poses under the housing fitted
    to ``train`` (``fit_housing(detections)`` → :class:`HousingCalibration`)."""
    housing = fit_housing(_one_view(detections, train))
    if not housing.identifiable:
        return {}
    view = View(housing.rig.left, housing.rig.view_port(0))
    corners = board.corners()
    out = {}
    for k in test:
        ids, uv = detections.ids[k][0], detections.pixels[k][0]
        pose = estimate_pose(view, corners[ids], uv, max_rms_px=np.inf)
        if not np.all(np.isfinite(pose.t)):
            continue
        predicted = project(view.camera, view.port, corners[ids] @ pose.R.T + pose.t)
        out[k] = np.sum((predicted - uv) ** 2, axis=1)
    return out


def _pinhole_errors(board, detections, size, lens_model, train, test) -> dict:
    """``{pose: squared errors (M,)}`` of the held-out poses under OpenCV's calibration of
    ``train`` (``lens_model``; each held-out pose by ``cv2.solvePnP``)."""
    corners = board.corners().astype(np.float32)
    obj = [corners[detections.ids[k][0]] for k in train]
    img = [detections.pixels[k][0].astype(np.float32) for k in train]
    out, model = calibrate_camera(obj, img, size, lens_model)[:2]
    if model == "fisheye":
        raise CalibrationError("the cross-validation of a fisheye pinhole is not implemented")
    K, dist = out[1], out[2]
    errors = {}
    for k in test:
        o, uv = corners[detections.ids[k][0]], detections.pixels[k][0]
        ok, rvec, tvec = cv2.solvePnP(o, uv.astype(np.float32), K, dist,
                                      flags=cv2.SOLVEPNP_ITERATIVE)
        if ok:
            predicted = cv2.projectPoints(o, rvec, tvec, K, dist)[0].reshape(-1, 2)
            errors[k] = np.sum((predicted - uv) ** 2, axis=1)
    return errors


def cross_validate_housing(fit_housing, board, detections: Detections, size,
                           lens_model: str = "auto", folds: int = FOLDS) -> CrossValidation:
    """The housing against the absorbed pinhole on held-out photos (module docs).
    ``fit_housing(detections)``: the housing calibration of camera 0's corners (e.g.
    :func:`measure.calibration.housing.calibrate_camera_housing` with the camera, design port,
    free parameters and in-air covariance bound); ``lens_model`` the pinhole's
    (:func:`measure.calibration.air.calibrate_camera`). CalibrationError when fewer than
    :data:`MIN_PREDICTED` photos could be predicted by both."""
    poses = detections.found(0)
    groups = min(folds, len(poses))
    housing, pinhole = {}, {}
    for g in range(groups):
        test = poses[g::groups]
        train = [k for k in poses if k not in test]
        try:
            housing.update(_housing_errors(fit_housing, board, detections, train, test))
        except CalibrationError:
            pass
        try:
            pinhole.update(_pinhole_errors(board, detections, size, lens_model, train, test))
        except (CalibrationError, cv2.error):
            pass
    both = [k for k in poses if k in housing and k in pinhole]
    if len(both) < MIN_PREDICTED:
        raise CalibrationError(f"only {len(both)} held-out photo(s) could be predicted by both "
                               f"models (at least {MIN_PREDICTED} are needed)")
    per = {k: (float(np.mean(housing[k])), float(np.mean(pinhole[k]))) for k in both}
    d = np.array([h - p for h, p in per.values()])
    se = float(np.std(d, ddof=1) / np.sqrt(len(d)))
    mean = float(np.mean(d))
    rms = [float(np.sqrt(np.mean(np.concatenate([errors[k] for k in both]))))
           for errors in (housing, pinhole)]
    worse = mean > WORSE_SIGMAS * se and rms[0] > (1 + WORSE_FRACTION) * rms[1]
    return CrossValidation(rms[0], rms[1], per, mean, se, bool(worse), groups,
                           tuple(k for k in poses if k not in both))


__all__ = ["CrossValidation", "FOLDS", "MIN_PREDICTED", "WORSE_FRACTION", "WORSE_SIGMAS",
           "cross_validate_housing"]
