"""The layers of a water tank from a known object seen through it (measure.calibration.interface,
Agrawal et al. 2012's multi-layer flat geometry): air | glass | water | glass | air with the
object in the air beyond, and air | glass | water with the object in the water.

References: the truth the pixels were projected from (exact pixels: back to 1e-6 mm / 1e-8),
physics (a stack of parallel layers between two equal media only shifts a ray, by an amount that
depends on the thicknesses and not on where the stack stands: the distance is then not fixed by
any image, and the estimate says DEGENERATE), and Monte Carlo (the spread of 40 noisy estimates
against the covariance: the σ of a spread of 40 draws is known to ±11 %, so 0.7–1.3 is about
±2.7 of that)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from measure import FlatPort, Reason
from measure.calibration.interface import estimate_interface
from measure.geometry.projection import project
from measure.stereo.multiview import View
from measure.stereo.pose import rotation_error
from synth.scene.layouts import docking_frame
from synth.scene.rig import paper_cameras, tilted_port_normal

TANK = FlatPort(tilted_port_normal(2.0, -1.0), 300.0, (10.0, 400.0, 10.0),
                (1.0, 1.5, 1.333, 1.5, 1.0))


def _frames(view, obj, seed, depths):
    rng = np.random.default_rng(seed)
    Rs = Rotation.from_rotvec(rng.uniform(-0.35, 0.35, (len(depths), 3))).as_matrix()
    ts = np.column_stack([rng.uniform(-0.1, 0.1, (len(depths), 2)) * np.c_[depths, depths],
                          depths])
    pixels = np.stack([project(view.camera, view.port, obj @ R.T + t) for R, t in zip(Rs, ts)])
    assert np.all(view.camera.in_image(pixels.reshape(-1, 2)))
    return Rs, ts, pixels


def test_the_water_of_a_tank_from_an_object_beyond_it():
    camera = paper_cameras()[0]
    obj = docking_frame()
    Rs, ts, exact = _frames(View(camera, TANK), obj, 3, [1600.0, 2200.0, 3000.0, 4000.0])
    design = TANK.replace(normal=[0.0, 0.0, 1.0], thicknesses=(10.0, 300.0, 10.0))
    view = View(camera, design)
    found = estimate_interface(view, obj, exact, free_thicknesses=(1,), free_distance=False)
    assert found.reason == Reason.OK, Reason(found.reason).name
    assert found.names == ("port.tilt[0]", "port.tilt[1]", "port.thickness[1]")
    assert abs(found.port.thicknesses[1] - 400.0) <= 1e-6
    assert np.linalg.norm(np.cross(found.port.normal, TANK.normal)) <= 1e-8
    assert np.max(np.abs(found.t - ts)) <= 1e-6
    assert max(rotation_error(found.R[f], Rs[f]) for f in range(len(Rs))) <= 1e-8
    assert found.rms_px < 1e-8
    # physics: the stack only shifts rays, wherever it stands — its distance is not fixed
    moved = estimate_interface(view, obj, exact, free_thicknesses=(1,))
    assert moved.reason == Reason.DEGENERATE
    rng = np.random.default_rng(5)
    errors, covariance = [], None
    for _ in range(40):
        noisy = exact + rng.normal(scale=0.1, size=exact.shape)
        e = estimate_interface(view, obj, noisy, 0.1, free_thicknesses=(1,), free_distance=False)
        assert e.reason == Reason.OK
        errors.append([*((e.port.normal - TANK.normal) @ e.normal_axes.T),
                       e.port.thicknesses[1] - 400.0])
        covariance = e.covariance
    ratio = np.std(errors, axis=0) / np.sqrt(np.diag(covariance))
    assert np.all((ratio > 0.7) & (ratio < 1.3)), ratio


def test_a_tank_wall_and_the_object_in_the_water():
    """air | glass | water, the object in the water: the wall's distance, normal and glass
    thickness together, exactly from exact pixels."""
    camera = paper_cameras()[0]
    wall = FlatPort(tilted_port_normal(-1.5, 0.5), 150.0, (12.0,), (1.0, 1.5, 1.333))
    obj = docking_frame()
    Rs, ts, exact = _frames(View(camera, wall), obj, 8, [1400.0, 2000.0, 2700.0, 3500.0])
    design = wall.replace(normal=[0.0, 0.0, 1.0], distance=120.0, thicknesses=(8.0,))
    found = estimate_interface(View(camera, design), obj, exact, free_thicknesses=(0,))
    assert found.reason == Reason.OK, Reason(found.reason).name
    assert found.names == ("port.distance", "port.tilt[0]", "port.tilt[1]", "port.thickness[0]")
    assert abs(found.port.distance - 150.0) <= 1e-6
    assert abs(found.port.thicknesses[0] - 12.0) <= 1e-6
    assert np.linalg.norm(np.cross(found.port.normal, wall.normal)) <= 1e-8
    assert np.max(np.abs(found.t - ts)) <= 1e-6


def test_the_in_air_calibrations_uncertainty_carried_into_the_tanks():
    """``camera_covariance``: the linear propagation of a held intrinsic's σ into the water's
    thickness and the normal agrees with refitting with that intrinsic moved by ±σ (half the
    difference of the two refits; exact pixels, so the pixel term is nil and the covariance is
    the propagated term alone). At σ(fx) = 0.2 px the thickness moves 1.14 mm per σ."""
    from measure.stereo.rig_covariance import RigCovariance
    from measure.stereo.triangulate import StereoRig
    from measure.stereo.uncertainty import perturbed_rig

    camera = paper_cameras()[0]
    obj = docking_frame()
    _, _, exact = _frames(View(camera, TANK), obj, 3, [1600.0, 2200.0, 3000.0, 4000.0])
    design = TANK.replace(normal=[0.0, 0.0, 1.0], thicknesses=(10.0, 300.0, 10.0))
    for name, sigma in (("left.fx", 0.2), ("left.cx", 0.2)):
        cov = RigCovariance((name,), [[sigma ** 2]])
        found = estimate_interface(View(camera, design), obj, exact, free_thicknesses=(1,),
                                   free_distance=False, camera_covariance=cov)
        assert found.reason == Reason.OK
        refits = []
        for step in (sigma, -sigma):
            moved = perturbed_rig(StereoRig(camera, camera, TANK), (name,), [step]).left
            refit = estimate_interface(View(moved, design), obj, exact, free_thicknesses=(1,),
                                       free_distance=False)
            refits.append([*(refit.port.normal @ found.normal_axes.T),
                           refit.port.thicknesses[1]])
        shift = np.abs(np.subtract(*refits)) / 2.0
        predicted = np.sqrt(np.diag(found.covariance))
        assert np.all(np.abs(shift - predicted) <= 0.05 * predicted), (name, shift, predicted)
