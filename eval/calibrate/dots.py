"""The eccentricity of a circle grid's dots taken out of every calibration of ``eval
calibrate`` (:func:`measure.calibration.circles.corrected_for_eccentricity`): each kind of fit
says where its cameras, ports and board poses are (:func:`views_of_camera`,
:func:`views_of_air`, :func:`views_of_housing`), and :func:`with_eccentricity` wraps the fit.

A board that is no circle grid, or one whose dots' diameter is not given (``--circle-mm``),
is fitted as before.
"""

from __future__ import annotations

import cv2
import numpy as np


def views_of_camera(size, model_of=lambda result: result["model"]):
    """``views_of`` of one camera's OpenCV fit (the dict of :mod:`eval.calibrate.single`: its
    ``out`` and ``poses``): the camera at the origin, no port, each pose's ``rvec, tvec``."""
    def views(result) -> dict:
        from measure.calibration.air import lens_camera

        out, camera = result["out"], lens_camera(result["out"], model_of(result), size)
        return {(k, 0): (camera, None, cv2.Rodrigues(np.ravel(rvec))[0], np.ravel(tvec))
                for k, rvec, tvec in zip(result["poses"], out[3], out[4])}
    return views


def views_of_air(air) -> dict:
    """``views_of`` of a pair's in-air fit (:class:`measure.calibration.air.AirCalibration`):
    its cameras in the reference frame, no port, the board poses it gives per view."""
    return {(k, v): (air.rig.cameras[v], None, R, t) for (k, v), (R, t) in air.board_poses.items()}


def views_of_housing(housing) -> dict:
    """``views_of`` of a housing fit (:class:`measure.calibration.housing.HousingCalibration`):
    each camera through its own view of the port, the fitted board poses."""
    rig = housing.fitted or housing.rig
    views = sorted({v for (_, v) in housing.rms_px_per})
    return {(k, v): (rig.cameras[v], rig.view_port(v), R, t)
            for k, (R, t) in zip(housing.pose_ids, housing.poses) for v in views}


def with_eccentricity(fit, board, views_of):
    """``fit`` with the dots' eccentricity taken out (module docs); ``fit`` itself where it
    does not apply."""
    from measure.calibration.circles import corrected_for_eccentricity

    if board.kind not in ("circles", "acircles") or board.circle_mm <= 0:
        return fit
    return lambda detections: corrected_for_eccentricity(fit, detections, board, views_of)[0]


__all__ = ["views_of_air", "views_of_camera", "views_of_housing", "with_eccentricity"]
