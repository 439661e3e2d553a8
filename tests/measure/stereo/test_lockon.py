"""Lock-on (measure.stereo.lockon): the first pose of a known docking frame from a stereo pair's
unlabelled detections, with no guess, against the analytic Fermat forward model of the paper's
rig. References: the true pose the pixels were projected from, and the true identity of every
detection (the detections are shuffled and mixed with spurious ones)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure.geometry.projection import project
from measure.stereo.lockon import lock_on
from measure.stereo.pose import rotation_error
from synth.scene.layouts import docking_frame
from synth.scene.rig import paper_rig

NOISE_PX = 0.05


def _detections(rig, obj, R, t, rng, spurious=5):
    """Per view the frame's pixels with noise, shuffled, plus ``spurious`` random detections;
    and per view the index of each marker's detection (−1: outside the image)."""
    out, index = [], []
    for camera, port in ((rig.left, rig.view_port(0)), (rig.right, rig.view_port(1))):
        uv = project(camera, port, obj @ R.T + t) + rng.normal(0.0, NOISE_PX, (len(obj), 2))
        seen = camera.in_image(uv)
        junk = rng.uniform([0, 0], camera.size, (spurious, 2))
        stack = np.vstack([uv[seen], junk])
        order = rng.permutation(len(stack))
        where = np.full(len(obj), -1)
        where[np.flatnonzero(seen)] = np.argsort(order)[: seen.sum()]
        out.append(stack[order])
        index.append(where)
    return out, index


@pytest.mark.parametrize("z", [1500.0, 3000.0, 5000.0])
def test_lock_on_finds_the_pose_and_the_identities(z):
    rng = np.random.default_rng(int(z))
    rig, obj = paper_rig(), docking_frame()
    R = Rotation.from_rotvec(rng.uniform(-0.3, 0.3, 3)).as_matrix()
    t = np.array([rng.uniform(-0.05, 0.05) * z, rng.uniform(-0.05, 0.05) * z, z])
    (left, right), (i_left, i_right) = _detections(rig, obj, R, t, rng)
    found = lock_on(rig, obj, left, right)
    assert found.reason is None
    assert found.ambiguous == 4  # the square under quarter turns (the posts break the mirror)
    assert rotation_error(found.R, R) < np.radians(0.5)
    assert np.linalg.norm(found.t - t) < 0.002 * z
    both = (i_left >= 0) & (i_right >= 0)
    assert found.assigned == both.sum() >= 10
    np.testing.assert_array_equal(found.pixels[0, both], left[i_left[both]])
    np.testing.assert_array_equal(found.pixels[1, both], right[i_right[both]])


def test_lock_on_prefers_the_turn_nearest_the_given_rotation():
    rng = np.random.default_rng(7)
    rig, obj = paper_rig(), docking_frame()
    R, t = np.eye(3), np.array([0.0, 0.0, 3000.0])
    (left, right), _ = _detections(rig, obj, R, t, rng, spurious=0)
    quarter = Rotation.from_rotvec([0.0, 0.0, np.pi / 2]).as_matrix()
    found = lock_on(rig, obj, left, right, prefer=quarter)
    assert rotation_error(found.R, quarter) < np.radians(0.5)


def test_too_few_detections_give_a_reason_not_a_pose():
    rig, obj = paper_rig(), docking_frame()
    uv = project(rig.left, rig.view_port(0), obj[:3] + [0.0, 0.0, 3000.0])
    found = lock_on(rig, obj, uv, uv)
    assert found.reason is not None and "4" in found.reason
    assert np.all(np.isnan(found.t))
