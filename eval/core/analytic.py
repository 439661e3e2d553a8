"""The analytic forward model — pixels of points through the port, which targets an image holds
wholly — and its triangulation errors, shared by ``eval paper`` (section 3 of the paper on the
simulator), ``eval run``, ``eval score`` and the analytic cells of ``eval sweep``.

Frames and units: the reference frame is the left camera's (OpenCV axes), millimetres; pixels
in the OpenCV convention (integer coordinates are pixel centres).
"""

from __future__ import annotations

import numpy as np

from measure import Rig, triangulate
from measure.geometry.projection import project
from synth.products.crosscheck import wholly_in_image


def project_pair(rig: Rig, points: np.ndarray, port=None):
    """The forward model: the pixels ``(left, right)`` of ``points`` ``(..., 3)`` mm through
    ``port`` (default the rig's; each camera through its own, :meth:`RigPort.view`)."""
    port = rig.port if port is None else port
    return project(rig.left, port.view(0), points), project(rig.right, port.view(1), points)


def triangulation_errors(rig: Rig, uv_left, uv_right, method: str, truth: np.ndarray):
    """``(errors, Triangulation)``: ``method`` on pixels ``(..., 2)``, errors measured − true
    ``(..., 3)`` mm."""
    result = triangulate(rig, uv_left.reshape(-1, 2), uv_right.reshape(-1, 2), method)
    shape = uv_left.shape[:-1] + (3,)
    errors = (result.points - truth.reshape(-1, 3)).reshape(shape)
    return errors, result


def air_copy(rig: Rig) -> Rig:
    """The same cameras behind an index-matched port (every index 1): the paper's all-air rig."""
    return rig.with_port(rig.port.replace(indices=(1.0,) * len(rig.port.indices)))


def visible_targets(camera, port, targets, radius_mm):
    """Simulator pixels ``(N, 2)`` and whether each target lies wholly inside the image."""
    uv = project(camera, port, targets)
    return uv, wholly_in_image(camera, uv, targets, radius_mm)


__all__ = ["air_copy", "project_pair", "triangulation_errors", "visible_targets"]
