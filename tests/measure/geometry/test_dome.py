"""measure.geometry.dome: the dome port's parameters, its rig and the backward trace."""

from __future__ import annotations

import numpy as np
import pytest

from measure import StereoRig
from measure.geometry.dome import DomePair, DomePort, trace_through_dome
from measure.geometry.flatport_format import from_domeport, to_domeport
from synth.scene.rig import paper_rig

INDICES = (1.0, 1.49, 1.33)


def _directions(n=200, seed=0):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.5
    return v / np.linalg.norm(v, axis=1)[:, None]


def test_a_centred_dome_bends_no_ray_from_its_centre():
    dome = DomePort((1.0, -2.0, 3.0), 50.0, 8.0, INDICES)
    rays = trace_through_dome(dome.center, _directions(), dome)
    np.testing.assert_allclose(rays.directions, _directions(), atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(rays.origins - dome.center, axis=1), 58.0,
                               rtol=1e-15)


def test_a_decentred_dome_obeys_snell_at_both_spheres():
    dome = DomePort((2.0, -1.0, 1.5), 50.0, 8.0, INDICES)
    d = _directions()
    rays = trace_through_dome(np.zeros(3), d, dome)
    headings = [d, None, rays.directions]
    inner, outer = rays.interface_points
    mid = (outer - inner) / np.linalg.norm(outer - inner, axis=1)[:, None]
    headings[1] = mid
    for k, point in enumerate((inner, outer)):
        normal = (point - dome.center) / dome.radii[k]
        np.testing.assert_allclose(np.linalg.norm(point - dome.center, axis=1), dome.radii[k],
                                   rtol=1e-14)
        sin_in = np.linalg.norm(np.cross(headings[k], normal), axis=1)
        sin_out = np.linalg.norm(np.cross(headings[k + 1], normal), axis=1)
        np.testing.assert_allclose(INDICES[k] * sin_in, INDICES[k + 1] * sin_out, atol=1e-14)
        # coplanar: incident, refracted and normal in one plane
        np.testing.assert_allclose(np.einsum("ij,ij->i", np.cross(headings[k], normal),
                                             headings[k + 1]), 0.0, atol=1e-14)
    assert np.abs(rays.directions - d).max() > 1e-3


def test_bad_domes_and_cameras_outside_are_refused():
    for radius, thickness in ((0.0, 5.0), (50.0, -1.0), (np.nan, 5.0)):
        with pytest.raises(ValueError, match="positive"):
            DomePort((0, 0, 0), radius, thickness, INDICES)
    rig = paper_rig()
    inside = DomePort(rig.left.center, 50.0, 8.0, INDICES)
    with pytest.raises(ValueError, match="right camera centre lies outside its dome"):
        StereoRig(rig.left, rig.right, DomePair(inside, inside))
    pair = DomePair(inside, inside.replace(center=rig.right.center))
    assert StereoRig(rig.left, rig.right, pair).view_port(1) is pair.right


def test_domeport_parameters_round_trip():
    """DOMEPORT: the dome centre in the camera's frame, radius and thickness in metres."""
    rig = paper_rig()
    dome = DomePort(rig.right.center + (1.5, -2.0, 3.25), 50.0, 8.0, INDICES)
    params = to_domeport(dome, rig.right)
    np.testing.assert_allclose(params[:3], rig.right.R.T @ (1.5, -2.0, 3.25) * 1e-3, rtol=1e-12)
    assert params[3:] == [0.05, 0.008, *INDICES]
    back = from_domeport(params, rig.right)
    np.testing.assert_allclose(back.center, dome.center, rtol=0, atol=1e-12)
    assert (back.radius, back.thickness, back.indices) == (50.0, 8.0, INDICES)
    with pytest.raises(ValueError, match="DOMEPORT needs 8 finite numbers"):
        from_domeport(params[:7], rig.right)


def _fork_cam_from_img(direction, params):
    """The refractive COLMAP fork's ``DomePort::CamFromImg`` (src/colmap/sensor/models_refrac.h
    lines 500–538, with ``RaySphereIntersection`` and ``ComputeRefraction`` of
    src/colmap/sensor/ray3d.h lines 75–107), transcribed for one ray: camera frame, metres."""
    center, radius, thick, na, ng, nw = (np.asarray(params[:3]), *params[3:])
    ori, d = np.zeros(3), direction / np.linalg.norm(direction)
    for r, n1, n2 in ((radius, na, ng), (radius + thick, ng, nw)):
        diff = center - ori
        t0 = diff @ d
        ori = ori + (t0 + np.sqrt(r * r - (diff @ diff - t0 * t0))) * d  # dmax
        normal = (ori - center) / np.linalg.norm(ori - center)
        ratio, c = n1 / n2, normal @ d
        d = ratio * d - (ratio * c - np.sqrt(1 - ratio * ratio * (1 - c * c))) * normal
        d /= np.linalg.norm(d)
    return ori, d


def test_a_domeport_read_traces_as_the_fork_does():
    """The fork's own DomePort test case (models_refrac_test.cc lines 154–165: centre
    (0.42, 3.67, 28.4) mm, radius 0.05 m) read with from_domeport for a rotated, shifted camera:
    trace_through_dome gives the fork's water rays (converted to mm, reference frame)."""
    params = [0.00042007, 0.00366894, 0.0283927, 0.05, 0.007, 1.003, 1.473, 1.333]
    camera = paper_rig().right
    dome = from_domeport(params, camera)
    d_cam = _directions(20, seed=3)
    rays = trace_through_dome(camera.center, d_cam @ camera.R.T, dome)
    for k, d in enumerate(d_cam):
        ori, direction = _fork_cam_from_img(d, params)
        np.testing.assert_allclose(rays.origins[k], camera.R @ (ori * 1e3) + camera.t,
                                   rtol=0, atol=1e-10)
        np.testing.assert_allclose(rays.directions[k], camera.R @ direction, rtol=0, atol=1e-14)
