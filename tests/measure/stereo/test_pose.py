"""The pose of a known object through the port (measure.stereo.pose), against the analytic
Fermat forward model: a 1 m docking frame (synth.scene.layouts.docking_frame) seen by the paper's
rig (full size), its pixels projected from a known pose, the pose estimated from no guess.

References: the true pose (exact pixels: the issue's 1e-6 mm and 1e-8 rad), Monte Carlo of
noisy pixels and of rig errors drawn from a rig covariance (coverage of the 95 % ellipsoid of
the position in 0.90–0.98 over 200 draws: with p = 0.95 the binomial σ of the fraction is
1.5 %, so the band is about ±3σ and a covariance off by 20 % in σ leaves it), and OpenCV's
solvePnP with the in-air intrinsics (the pinhole baseline that ignores the port)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure import FlatPort, Reason
from measure.calibration.selfcal import tilt_basis
from measure.geometry.projection import project
from measure.stereo.multiview import View
from measure.stereo.pose import (estimate_pose, estimate_poses, pinhole_pose, rotation_error,
                                 shared_offset_covariance)
from measure.stereo.rig_covariance import RigCovariance
from measure.stereo.uncertainty import CHI2_3_95, mahalanobis_squared, perturbed_rig
from synth.scene.layouts import docking_frame
from synth.scene.rig import paper_cameras, paper_rig

POSITION_MM = 1e-6
ANGLE_RAD = 1e-8


def _pose(rng, z, spread=0.15, tilt=0.35):
    """A random pose of the frame facing the cameras at depth ``z``: its centre within
    ``spread`` · z of the axis, turned up to ~``tilt`` rad."""
    R = Rotation.from_rotvec(rng.uniform(-tilt, tilt, 3)).as_matrix()
    t = np.array([rng.uniform(-spread, spread) * z, rng.uniform(-spread, spread) * z, z])
    return R, t


def _pixels(views, obj, R, t, in_image=True):
    """``(V, M, 2)`` pixels of the frame at pose (R, t), NaN outside each image."""
    X = obj @ R.T + t
    out = []
    for view in views:
        uv = project(view.camera, view.port, X)
        if in_image:
            uv[~view.camera.in_image(uv)] = np.nan
        out.append(uv)
    return np.stack(out)


def _assert_exact(pose, R, t):
    assert pose.reason == Reason.OK, Reason(pose.reason).name
    assert np.max(np.abs(pose.t - t)) <= POSITION_MM, pose.t - t
    assert rotation_error(pose.R, R) <= ANGLE_RAD
    assert pose.rms_px < 1e-8


def _rig_and_frame(seed, z):
    """The paper's rig, the docking frame at a random pose at depth ``z`` (``_pose``) and its
    pixels in both views: ``(rig, obj, rng, R, t, views, uv)``; ``rng`` goes on drawing."""
    rig = paper_rig()
    obj = docking_frame()
    rng = np.random.default_rng(seed)
    R, t = _pose(rng, z)
    views = [View(c, rig.view_port(v)) for v, c in enumerate(rig.cameras)]
    return rig, obj, rng, R, t, views, _pixels(views, obj, R, t)


@pytest.mark.parametrize("post", [100.0, 0.0], ids=["posts", "planar"])
def test_one_camera_exact_from_no_guess(post):
    """0.5–5 m from the left camera behind the paper's port, only the markers inside the image
    (at 0.5 m the field is about 0.76 × 0.67 m: the four inner markers)."""
    rig = paper_rig()
    view = View(rig.left, rig.view_port(0))
    obj = docking_frame(post=post)
    rng = np.random.default_rng(3)
    for z in (500.0, 1000.0, 2000.0, 5000.0):
        for _ in range(3):
            R, t = _pose(rng, z, spread=0.05 if z < 1000 else 0.15)
            uv = _pixels([view], obj, R, t)[0]
            assert np.sum(np.isfinite(uv[:, 0])) >= 4
            _assert_exact(estimate_pose(view, obj, uv), R, t)


def test_rig_jointly_with_different_subsets():
    """Both cameras, each seeing a different subset; and three markers per camera, where no
    camera alone has a pose (TOO_FEW_POINTS) but the two together do."""
    rig, obj, _, R, t, _, uv = _rig_and_frame(5, 1500.0)
    assert np.all(np.isfinite(uv))  # the whole frame in both images at 1.5 m
    subsets = uv.copy()
    subsets[0, :4] = np.nan
    subsets[1, 6:] = np.nan
    _assert_exact(estimate_pose(rig, obj, subsets), R, t)
    three = np.full_like(uv, np.nan)
    three[0, [0, 2, 9]] = uv[0, [0, 2, 9]]
    three[1, [4, 6, 11]] = uv[1, [4, 6, 11]]
    for v in range(2):
        alone = np.full_like(three, np.nan)
        alone[v] = three[v]
        assert estimate_pose(rig, obj, alone).reason == Reason.TOO_FEW_POINTS
    _assert_exact(estimate_pose(rig, obj, three), R, t)


@pytest.mark.parametrize("case", ["rig", "left alone", "rig, own σ and rows left out"])
def test_shared_offset_covariance_is_the_pose_that_the_offset_moves(case):
    """One error shared by every observation (all pixels moved by ε · a pattern): the pose
    re-estimated from the moved exact pixels moves by ε · g, and the covariance is g gᵀ —
    against finite differences of the estimator itself (ε = 1e-3 px), each of the six
    components on its own scale (the rotation's are ~1e-3 of the translation's). The third
    case weights the pixels by their own σ (0.05–0.5 px) and leaves out rows: NaN offsets and
    a NaN σ (not seen, as estimate_pose takes it)."""
    rig, obj, rng, R, t, views, uv = _rig_and_frame(11, 1200.0)
    pattern = rng.normal(0.0, 1.0, uv.shape)
    sigma = None
    target = views[0] if case == "left alone" else rig
    if case == "left alone":
        uv, pattern = uv[:1], pattern[:1]
    if case.startswith("rig, own"):
        sigma = rng.uniform(0.05, 0.5, uv.shape[:2])
        sigma[1, 3] = np.nan
        pattern[0, 5] = np.nan
    given = uv if target is rig else uv[0]
    kept = np.where(np.isfinite(pattern), uv, np.nan)  # what the pattern moves
    base = estimate_pose(target, obj, kept if target is rig else kept[0], sigma)
    _assert_exact(base, R, t)
    eps = 1e-3
    moved_px = kept + eps * np.nan_to_num(pattern)
    moved = estimate_pose(target, obj, moved_px if target is rig else moved_px[0], sigma)
    phi = Rotation.from_matrix(moved.R @ base.R.T).as_rotvec()
    g = np.concatenate([phi, moved.t - base.t]) / eps
    covariance = shared_offset_covariance(target, obj, given, base, pattern, sigma)
    values, vectors = np.linalg.eigh(covariance)
    assert np.all(np.abs(values[:5]) < 1e-9 * values[5])  # rank one
    analytic = np.sqrt(values[5]) * vectors[:, 5]
    analytic *= np.sign(analytic @ g)
    np.testing.assert_allclose(analytic, g, rtol=1e-3)


def test_dome_and_tank():
    """Through a decentred dome (the port interface: its own projection and trace), and through
    a tank: air | glass | water | glass | air and air | water | air, the object in the air
    beyond. For the tank the forward model is checked first against the trace (each pixel's
    ray, refracted at every interface, passes through its point) and against physics (a
    parallel slab leaves a ray parallel to itself)."""
    from synth.scene.dome import dome_pair

    cameras = paper_cameras()
    dome = dome_pair(cameras, 50.0, 8.0, (2.0, -1.0, 1.5), (1.0, 1.54, 1.33))
    obj = docking_frame()
    rng = np.random.default_rng(11)
    view = View(cameras[0], dome.view(0))
    for z in (800.0, 3000.0):
        R, t = _pose(rng, z)
        _assert_exact(estimate_pose(view, obj, _pixels([view], obj, R, t)[0]), R, t)
    walls = FlatPort((0.0, 0.0, 1.0), 200.0, (10.0, 400.0, 10.0), (1.0, 1.5, 1.33, 1.5, 1.0))
    bare = FlatPort((0.0, 0.0, 1.0), 200.0, (400.0,), (1.0, 1.33, 1.0))  # air | water | air
    for tank in (walls, bare):
        view = View(cameras[0], tank)
        R, t = _pose(rng, 1500.0)
        X = obj @ R.T + t
        uv = project(view.camera, tank, X)
        directions = view.camera.rays(uv)
        rays = tank.trace(view.camera.center, directions)
        off_ray = np.linalg.norm(np.cross(X - rays.origins, rays.directions), axis=1)
        assert np.max(off_ray) < 1e-9
        np.testing.assert_allclose(rays.directions, directions, atol=1e-15)
        _assert_exact(estimate_pose(view, obj, uv), R, t)


def _monte_carlo(views, obj, R, t, rng, draws, sigma, rig=None, rig_covariance=None):
    """Estimates of noisy copies (and, with a rig covariance, of rigs drawn from it: the pixels
    come from the drawn rig, the estimate believes ``views``)."""
    names = () if rig_covariance is None else rig_covariance.names
    deltas = (rng.multivariate_normal(np.zeros(len(names)), rig_covariance.matrix, draws)
              if names else np.zeros((draws, 0)))
    pixels = []
    for delta in deltas:
        truth = views if not names else perturbed_rig(rig, names, delta,
                                                      rig_covariance.normal_axes)
        truth_views = [View(c, truth.view_port(v)) for v, c in enumerate(truth.cameras)] \
            if names else views
        uv = _pixels(truth_views, obj, R, t)
        pixels.append(uv + rng.normal(scale=sigma, size=uv.shape))
    return estimate_poses(rig if rig is not None else views, obj, np.array(pixels), sigma,
                          rig_covariance)


def _coverage(poses, R, t):
    ok = poses.valid
    assert ok.all(), np.bincount(poses.reason)
    d2_position = mahalanobis_squared(poses.t - t, poses.covariance[:, 3:, 3:])
    phi = np.stack([Rotation.from_matrix(Rk @ R.T).as_rotvec() for Rk in poses.R])
    d2_rotation = mahalanobis_squared(phi, poses.covariance[:, :3, :3])
    return np.mean(d2_position <= CHI2_3_95), np.mean(d2_rotation <= CHI2_3_95)


def test_covariance_against_monte_carlo():
    """200 noisy poses (σ = 0.3 px) from one camera at 2 m: the 95 % ellipsoids of the
    position (and of the rotation) hold 90–98 % of the estimates."""
    rig = paper_rig()
    view = View(rig.left, rig.port)
    obj = docking_frame()
    rng = np.random.default_rng(21)
    R, t = _pose(rng, 2000.0)
    poses = _monte_carlo([view], obj, R, t, rng, 200, 0.3)
    position, rotation = _coverage(poses, R, t)
    assert 0.90 <= position <= 0.98, position
    assert 0.90 <= rotation <= 0.98, rotation
    assert np.allclose(poses.sigma_px, 0.3) and np.all(poses.rig == 0)


def test_rig_covariance_against_monte_carlo():
    """The rig jointly, its calibration drawn from a rig covariance (and 0.1 px noise) in 200
    trials: the total covariance (pixel + rig part) covers 90–98 % of the positions; the rig
    part alone is most of it."""
    rig = paper_rig()
    names = ("left.fx", "left.cx", "right.rotation[1]", "right.center[0]", "port.distance",
             "port.tilt[0]", "port.index[2]")
    sig = np.array([1.0, 0.5, 1e-4, 0.1, 0.5, 5e-4, 5e-4])
    rig_covariance = RigCovariance(names, np.diag(sig ** 2),
                                   np.array(tilt_basis(np.array([0.0, 0.0, 1.0]))))
    obj = docking_frame()
    rng = np.random.default_rng(23)
    R, t = _pose(rng, 1500.0)
    poses = _monte_carlo(None, obj, R, t, rng, 200, 0.1, rig, rig_covariance)
    position, _ = _coverage(poses, R, t)
    assert 0.90 <= position <= 0.98, position
    np.testing.assert_allclose(poses.covariance, poses.pixel + poses.rig)
    assert np.all(np.trace(poses.rig[:, 3:, 3:], axis1=1, axis2=2)
                  > np.trace(poses.pixel[:, 3:, 3:], axis1=1, axis2=2))


def test_reason_codes_and_a_batch_that_goes_on():
    rig = paper_rig()
    view = View(rig.left, rig.port)
    obj = docking_frame()
    rng = np.random.default_rng(31)
    R, t = _pose(rng, 2000.0)
    good = _pixels([view], obj, R, t)[0]
    few = np.full_like(good, np.nan)
    few[:3] = good[:3]
    line = np.array([[x, -500.0, 0.0] for x in (-500.0, -250.0, 0.0, 250.0, 500.0)])  # a rod
    scrambled = good[rng.permutation(12)]
    outside = good.copy()
    outside[:] = np.nan
    frames = np.stack([good, few, scrambled, outside, good])
    poses = estimate_poses(view, obj, frames)
    assert poses.reason.tolist() == [Reason.OK, Reason.TOO_FEW_POINTS, Reason.NOT_CONVERGED,
                                     Reason.TOO_FEW_POINTS, Reason.OK]
    assert np.all(np.isnan(poses.t[1:4])) and np.all(np.isnan(poses.covariance[1:4]))
    np.testing.assert_allclose(poses.t[4], t, atol=POSITION_MM)
    empty = estimate_poses(view, obj, frames[:0])
    assert len(empty) == 0 and empty.covariance.shape == (0, 6, 6)
    collinear = estimate_pose(view, line, _pixels([view], line, R, t)[0])
    assert collinear.reason == Reason.DEGENERATE
    with pytest.raises(ValueError, match="pixels must have shape"):
        estimate_poses(view, obj, frames[:, :5])
    with pytest.raises(ValueError, match="rig_covariance needs the views as a StereoRig"):
        estimate_pose(view, obj, good, rig_covariance=RigCovariance(("left.fx",), [[1.0]]))


def test_pinhole_baseline_is_off_by_the_port():
    """OpenCV's solvePnP with the camera's in-air intrinsics (a calibration that ignores the
    port) near 0.5 m with the frame's inner markers near the edge of the field: off by 114 mm
    (the water magnifies: the frame looks nearer), where the refractive pose is exact."""
    rig = paper_rig()
    view = View(rig.left, rig.port)
    obj = docking_frame()
    R = Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix()
    t = np.array([60.0, 40.0, 520.0])
    uv = _pixels([view], obj, R, t)[0]
    seen = np.isfinite(uv[:, 0])
    assert seen.sum() >= 4
    edge = np.max(np.abs(uv[seen] - rig.left.K[:2, 2]) / (np.array(rig.left.size) / 2), axis=1)
    assert edge.max() > 0.8  # a marker in the outer fifth of the half-width
    _assert_exact(estimate_pose(view, obj, uv), R, t)
    R_pin, t_pin = pinhole_pose(rig.left, obj, uv)
    assert np.linalg.norm(t_pin - t) > 50.0


def test_interface_from_a_known_object():
    """The port's distance and normal with the frame's poses, from four frames of one camera,
    started from the design port (D 100 mm, N = z) where the truth is D = 103 mm and N tilted
    by 1° and −0.5°: exact pixels give it back exactly; 60 noisy trials (σ = 0.1 px) spread as
    the covariance says (the σ of a spread of 60 draws is known to ±9 %, so 0.75–1.25 is ±2.8
    of that)."""
    from measure.calibration.interface import estimate_interface
    from synth.scene.rig import tilted_port_normal

    rig = paper_rig()
    design = rig.port
    truth = design.replace(distance=103.0, normal=tilted_port_normal(1.0, -0.5))
    obj = docking_frame()
    rng = np.random.default_rng(41)
    Rs = Rotation.from_rotvec(rng.uniform(-0.35, 0.35, (4, 3))).as_matrix()
    ts = np.array([[100.0, -50.0, 800.0], [-200.0, 100.0, 1400.0], [150.0, 200.0, 2200.0],
                   [0.0, 0.0, 3000.0]])
    exact = np.stack([_pixels([View(rig.left, truth)], obj, R, t)[0] for R, t in zip(Rs, ts)])
    found = estimate_interface(View(rig.left, design), obj, exact)
    assert found.reason == Reason.OK
    assert abs(found.port.distance - 103.0) <= 1e-6
    assert np.linalg.norm(np.cross(found.port.normal, truth.normal)) <= 1e-8
    assert np.max(np.abs(found.t - ts)) <= POSITION_MM
    assert max(rotation_error(found.R[f], Rs[f]) for f in range(4)) <= ANGLE_RAD
    estimates, covariance = [], None
    for _ in range(60):
        noisy = exact + rng.normal(scale=0.1, size=exact.shape)
        e = estimate_interface(View(rig.left, design), obj, noisy, 0.1)
        assert e.reason == Reason.OK
        tilt = (e.port.normal - truth.normal) @ e.normal_axes.T
        estimates.append([e.port.distance - 103.0, *tilt])
        covariance = e.covariance
    ratio = np.std(estimates, axis=0) / np.sqrt(np.diag(covariance))
    assert np.all((ratio > 0.75) & (ratio < 1.25)), ratio


def test_interface_started_without_a_design_value():
    """Agrawal et al.'s flat refraction constraint gives the tilted normal (1°, −0.5°) exactly
    from exact pixels, and the distance search then starts the refinement in the basin of the
    truth (D 103 mm) from nothing but the layers: exact back to 1e-6 mm; with 0.1 px of noise
    the refined D and normal lie within 3σ of the truth. Without refraction (every index 1) the
    constraint holds for any axis, and no start is given."""
    from measure.calibration.interface import (estimate_interface, interface_start,
                                               refraction_axis)
    from synth.scene.rig import tilted_port_normal

    rig = paper_rig()
    truth = rig.port.replace(distance=103.0, normal=tilted_port_normal(1.0, -0.5))
    layers_only = rig.port.replace(distance=1.0, normal=[0.0, 0.0, 1.0])
    obj = docking_frame()
    rng = np.random.default_rng(7)
    Rs = Rotation.from_rotvec(rng.uniform(-0.35, 0.35, (4, 3))).as_matrix()
    ts = np.array([[100.0, -50.0, 800.0], [-200.0, 100.0, 1400.0], [150.0, 200.0, 2200.0],
                   [0.0, 0.0, 3000.0]])
    exact = np.stack([_pixels([View(rig.left, truth)], obj, R, t)[0] for R, t in zip(Rs, ts)])
    axis = refraction_axis(rig.left, obj, exact)
    assert np.linalg.norm(np.cross(axis, truth.normal)) <= 1e-9 and axis[2] > 0
    start = interface_start(View(rig.left, layers_only), obj, exact)
    found = estimate_interface(View(rig.left, start), obj, exact)
    assert found.reason == Reason.OK
    assert abs(found.port.distance - 103.0) <= 1e-6
    assert np.linalg.norm(np.cross(found.port.normal, truth.normal)) <= 1e-8
    noisy = exact + rng.normal(scale=0.1, size=exact.shape)
    start = interface_start(View(rig.left, layers_only), obj, noisy)
    e = estimate_interface(View(rig.left, start), obj, noisy, 0.1)
    assert e.reason == Reason.OK
    error = np.array([e.port.distance - 103.0, *((e.port.normal - truth.normal) @ e.normal_axes.T)])
    assert np.all(np.abs(error) <= 3.0 * np.sqrt(np.diag(e.covariance))), error
    air = rig.port.replace(indices=(1.0, 1.0, 1.0))
    pinhole = np.stack([_pixels([View(rig.left, air)], obj, R, t)[0] for R, t in zip(Rs, ts)])
    assert not np.isfinite(refraction_axis(rig.left, obj, pinhole)).any()
    assert interface_start(View(rig.left, air), obj, pinhole) is None
