"""The renderer's rays stay on the refracted path (synth.rendering.integrator).

Mitsuba's ``path`` starts each new ray ``(1 + max|p_i|)·8.9e-5`` along the surface normal, off the
refracted ray; far from the scene origin that step is millimetres. A rig 50 m from the origin
makes the difference between the two integrators large enough to see on a small image."""

from __future__ import annotations

import numpy as np
import pytest

from measure import Camera
from measure.images.detect import detect_targets
from measure.images.eccentricity import outline_centroid_offsets
from measure.geometry.projection import project
from synth.products.crosscheck import associate_detections
from synth.scene.layouts import grid_plane
from synth.rendering.render import load_mitsuba_scene, render_view
from synth.scene.rig import paper_cameras, paper_port
from synth.scene import load_scene, write_scene

#: Every test here renders with Mitsuba.
pytestmark = pytest.mark.slow

SMALL = (320, 268)
FOCAL = 150.0
FAR_MM = 50_000.0  # rig, port and targets this far from the scene origin along x
RADIUS_MM = 20.0


def _far_scene(tmp_path):
    left, right = paper_cameras(SMALL, FOCAL)
    shift = np.array([FAR_MM, 0.0, 0.0])
    cameras = [Camera(c.K, c.size, R=c.R, t=c.t + shift) for c in (left, right)]
    targets = grid_plane(1000.0, 700.0, 100.0) + shift
    path = write_scene(tmp_path / "far.xml", cameras, paper_port(), targets, RADIUS_MM,
                       interface_half_size=2 * FAR_MM)
    return load_scene(path), cameras, targets


def _errors(image, camera, port, targets):
    """Distance (px) of each detected centre from the simulator's image of its target's outline
    centroid, ``inf`` for a target with no detection within the association gate."""
    expected = project(camera, port, targets)
    expected += outline_centroid_offsets(camera, port, targets,
                                         np.broadcast_to([0.0, 0.0, -1.0], targets.shape),
                                         RADIUS_MM)
    inside = camera.in_image(expected, margin_px=10)
    centres = np.asarray(detect_targets(image).centers).reshape(-1, 2)
    assert inside.sum() >= 20
    index, distance = associate_detections(centres, expected[inside])
    errors = np.full(inside.sum(), np.inf)
    errors[index[index >= 0]] = distance[index >= 0]
    return errors


def test_rays_stay_on_the_refracted_path_far_from_the_origin(tmp_path):
    spec, cameras, targets = _far_scene(tmp_path)
    mscene, mi, _ = load_mitsuba_scene(spec)
    port = spec.rig.port
    ours = _errors(render_view(mscene, mi, 0, cameras[0], 64, 0), cameras[0], port, targets)
    assert ours.max() <= 0.05, ours.max()
    # Mitsuba's own path integrator on the same scene: the sideways step shows
    plain = np.asarray(mi.render(mscene, sensor=0, spp=64, seed=0))[..., 0]
    theirs = _errors(plain, cameras[0], port, targets)
    assert np.median(theirs) > 0.2, np.median(theirs)
