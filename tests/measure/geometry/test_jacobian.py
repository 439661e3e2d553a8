"""Analytic derivatives of the forward projection (``project(..., jacobian=True)``) against
central differences of the projection itself.

Criterion (norm-relative, per point): ``‖J_fd − J‖ ≤ 1e-6 ‖J‖`` where the norm is the
Frobenius norm of that point's block for one parameter (2 × 3 for a point, the camera centre,
its rotation and the port normal; 2 for the distance and one index or thickness). Steps: 1e-3 mm
for lengths (points at 0.1–3 m: truncation error ~1e-12 relative); every central difference
takes one Richardson step (fourth order), 1e-4 for indices (a thin
layer's index moves a pixel by a fraction of a pixel per unit: smaller steps drown in the
solver's ~1e-13 px rounding) and 1e-6 rad for angles. An index within two steps of 1 (the
lower bound of an index) gets the one-sided third-order difference.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from scipy.spatial.transform import Rotation

from measure import Camera, Reason
from measure.geometry.projection import ParameterJacobian, project, solve_paths
from measure.calibration.selfcal import tilt_basis
from synth.scene.layouts import paper_plane

from tests.measure.geometry.test_geometry import rigs_and_points

TOLERANCE = 1e-6
LENGTH_STEP, INDEX_STEP, ANGLE_STEP = 1e-3, 1e-4, 1e-6


def _central(function, step):
    """Central difference with one Richardson step (fourth order): ``(4·D(h/2) − D(h)) / 3``.
    A plain central difference at the index step leaves up to ~1e-6 relative truncation error
    on steep rays (hypothesis found one at 1.03e-6, where the extrapolation agreed with the
    analytic derivative to 1e-10)."""
    def plain(h):
        return (function(h) - function(-h)) / (2 * h)
    return (4 * plain(step / 2) - plain(step)) / 3


def _assert_close(analytic, numeric, name, step):
    """Per point (first axis), the norm-relative criterion of the module docs, plus the
    rounding floor of the difference quotient for derivatives that vanish (e.g. a layer with the
    water's index: its thickness changes nothing): the projection's rounding, ~1e-12 px
    (measured: a zero derivative's central differences are 9e-10 px/mm at a 1e-3 mm step), times
    3 for the Richardson step (4/3 · 2ε/h + 1/3 · ε/h), over the step."""
    analytic = analytic.reshape(analytic.shape[0], -1)
    numeric = numeric.reshape(numeric.shape[0], -1)
    error = np.linalg.norm(analytic - numeric, axis=1)
    allowed = TOLERANCE * np.linalg.norm(analytic, axis=1) + 3e-12 / step
    worst = np.max(error / allowed)
    assert worst <= 1.0, f"{name}: error {worst:.2f} times the allowed"


def _with_camera(camera, R=None, t=None):
    return camera.with_pose(camera.R if R is None else R, camera.t if t is None else t)


def _check_all(camera, port, points, solver="fermat"):
    pixels, d_points, jac = project(camera, port, points, solver, parameters=True)
    assert isinstance(jac, ParameterJacobian)
    np.testing.assert_array_equal(pixels, project(camera, port, points, solver))
    _, alone = project(camera, port, points, solver, jacobian=True)
    np.testing.assert_array_equal(alone, d_points)

    def proj(cam=camera, prt=port, pts=points):
        return project(cam, prt, pts, solver)

    eye = np.eye(3)
    numeric = np.stack([_central(lambda h: proj(pts=points + h * eye[j]), LENGTH_STEP)
                        for j in range(3)], axis=-1)
    _assert_close(d_points, numeric, "point", LENGTH_STEP)
    _assert_close(jac.distance, _central(
        lambda h: proj(prt=port.replace(distance=port.distance + h)), LENGTH_STEP), "distance",
        LENGTH_STEP)
    for axis in tilt_basis(port.normal):
        numeric = _central(lambda h: proj(prt=port.replace(normal=port.normal + h * axis)),
                           ANGLE_STEP)
        _assert_close(jac.normal @ axis, numeric, "normal", ANGLE_STEP)
    np.testing.assert_allclose(jac.normal @ port.normal, 0.0, atol=1e-9)
    for i in range(len(port.indices)):
        def changed(h, i=i):
            indices = list(port.indices)
            indices[i] += h
            return proj(prt=port.replace(indices=tuple(indices)))
        if port.indices[i] - INDEX_STEP >= 1.0:
            _assert_close(jac.indices[..., i], _central(changed, INDEX_STEP), f"index {i}",
                          INDEX_STEP)
        else:  # an index cannot go below 1: a one-sided difference of third order
            numeric = (-11 * changed(0.0) + 18 * changed(INDEX_STEP) - 9 * changed(2 * INDEX_STEP)
                       + 2 * changed(3 * INDEX_STEP)) / (6 * INDEX_STEP)
            _assert_close(jac.indices[..., i], numeric, f"index {i}", INDEX_STEP)
    assert jac.thicknesses.shape == (len(points), 2, len(port.thicknesses))
    for j in range(len(port.thicknesses)):
        def thicker(h, j=j):
            thicknesses = list(port.thicknesses)
            thicknesses[j] += h
            return proj(prt=port.replace(thicknesses=tuple(thicknesses)))
        _assert_close(jac.thicknesses[..., j], _central(thicker, LENGTH_STEP), f"thickness {j}",
                      LENGTH_STEP)
    numeric = np.stack([_central(lambda h: proj(cam=_with_camera(camera, t=camera.t + h * eye[j])),
                                 LENGTH_STEP) for j in range(3)], axis=-1)
    _assert_close(jac.center, numeric, "center", LENGTH_STEP)
    numeric = np.stack([_central(lambda h: proj(cam=_with_camera(
        camera, R=Rotation.from_rotvec(h * eye[j]).as_matrix() @ camera.R)), ANGLE_STEP)
        for j in range(3)], axis=-1)
    _assert_close(jac.rotation, numeric, "rotation", ANGLE_STEP)


@given(rigs_and_points())
def test_jacobians_match_central_differences(data):
    rig, points = data
    points = points[:40]
    for camera in rig.cameras:
        ok = np.isfinite(project(camera, rig.port, points)).all(axis=1)
        _check_all(camera, rig.port, points[ok])


@given(rigs_and_points(distorted=True))
def test_jacobians_with_lens_distortion(data):
    rig, points = data
    points = points[:40]
    camera = rig.right
    ok = np.isfinite(project(camera, rig.port, points)).all(axis=1)
    _check_all(camera, rig.port, points[ok])


@pytest.mark.parametrize("solver", ["fermat", "snell"])
def test_paper_rig_jacobians_for_both_solvers(rig, solver):
    points = paper_plane(1000.0)[::7]
    for camera in rig.cameras:
        _check_all(camera, rig.port, points, solver)


def test_jacobians_with_a_fisheye_lens(rig):
    """OpenCV's fisheye model (Kannala–Brandt) through the projector's chain rule."""
    points = paper_plane(1000.0)[::7]
    right = rig.right
    camera = Camera(right.K, right.size, (0.05, 0.01, 0.004, -0.01), right.R, right.t, "fisheye")
    _check_all(camera, rig.port, points)


def test_jacobian_on_the_normal_through_the_camera_and_nan_rows(rig):
    """A point on the camera's port normal (lateral distance 0, the in-plane axis undefined)
    has a finite Jacobian equal to the central differences; rows without a pixel are NaN."""
    points = np.array([[0.0, 0.0, 1000.0], [0.0, 0.0, 50.0], [np.nan, 0.0, 900.0],
                       [30.0, -20.0, 800.0]])
    pixels, d_points, jac = project(rig.left, rig.port, points, parameters=True)
    assert np.isfinite(d_points[[0, 3]]).all() and np.isnan(d_points[1:3]).all()
    assert np.isnan(jac.normal[1:3]).all() and np.isnan(jac.distance[1:3]).all()
    assert list(solve_paths(rig.left, rig.port, points).reason) == [
        Reason.OK, Reason.NOT_IN_WATER, Reason.INVALID_INPUT, Reason.OK]
    eye = np.eye(3)
    numeric = np.stack([_central(lambda h: project(rig.left, rig.port, points[:1] + h * eye[j]),
                                 LENGTH_STEP) for j in range(3)], axis=-1)
    _assert_close(d_points[:1], numeric, "point on the normal", LENGTH_STEP)


def test_no_port_jacobian_is_the_pinhole_one(air_rig):
    """Through an index-matched port the derivative is the pinhole camera's: with
    X_cam = Rᵀ(X − t), d(u, v)/dX = K₂ₓ₂ · (1/Z)[[1, 0, −x], [0, 1, −y]] · Rᵀ."""
    camera = air_rig.right
    points = paper_plane(1000.0)[::11]
    _, d_points = project(camera, None, points, jacobian=True)
    X = camera.to_camera(points)
    x, y, inv = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2], 1.0 / X[:, 2]
    rows = np.zeros((len(points), 2, 3))
    rows[:, 0, 0], rows[:, 0, 2] = inv, -x * inv
    rows[:, 1, 1], rows[:, 1, 2] = inv, -y * inv
    expected = camera.K[:2, :2] @ rows @ camera.R.T
    np.testing.assert_allclose(d_points, expected, rtol=1e-12, atol=1e-12)
