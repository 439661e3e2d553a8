"""The paper's experimental set-up (Li et al. 2024, Table 1 and section 3.1) in one place.

The paper gives the port (D = 100 mm, d = 5 mm, N = (0, 0, 1), n = 1.0 / 1.54 / 1.33) but not the
intrinsics, baseline or image size. The rig below (2448 x 2048 px, f = 1100 px, principal point at
the image centre, right camera 200 mm to the right and turned 5 degrees about y towards the left
camera) keeps all 496 targets at 1 m inside both images, the outer circle spanning ~94 % of the
left image height. Experiments, tests and scene files all take their numbers from here.
"""

from __future__ import annotations

import numpy as np

from measure import Camera, FlatPort, Rig, StereoRig

PAPER_IMAGE_SIZE = (2448, 2048)  # (width, height), px
PAPER_FOCAL_PX = 1100.0
PAPER_BASELINE_MM = 200.0
PAPER_TOE_IN_DEG = 5.0  # right camera turned about y towards the left camera
PAPER_PORT_DISTANCE_MM = 100.0
PAPER_GLASS_THICKNESS_MM = 5.0
PAPER_INDICES = (1.0, 1.54, 1.33)  # air, glass, water


def rotation_y(angle_rad: float) -> np.ndarray:
    """Rotation matrix about the y axis (right-handed, OpenCV axes)."""
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec([0.0, angle_rad, 0.0]).as_matrix()


def tilted_port_normal(about_x_deg: float, about_y_deg: float) -> np.ndarray:
    """The unit normal of a port tilted from the left optical axis (0, 0, 1) by ``about_y_deg``
    about y, then ``about_x_deg`` about x (degrees; ``python -m synth scene --port-tilt``)."""
    from scipy.spatial.transform import Rotation
    ax, ay = np.radians([about_x_deg, about_y_deg])
    return Rotation.from_rotvec([ax, 0.0, 0.0]).apply(
        Rotation.from_rotvec([0.0, ay, 0.0]).apply([0.0, 0.0, 1.0]))


def paper_intrinsics(size=PAPER_IMAGE_SIZE, focal_px=PAPER_FOCAL_PX) -> np.ndarray:
    """3x3 K with square pixels and the principal point at the image centre (OpenCV pixels)."""
    w, h = size
    return np.array([[focal_px, 0.0, (w - 1) / 2.0], [0.0, focal_px, (h - 1) / 2.0], [0, 0, 1.0]])


def paper_port(n_water: float = PAPER_INDICES[2]) -> FlatPort:
    """The paper's Table 1 port: air - 5 mm glass - water, N = (0, 0, 1), D = 100 mm."""
    return FlatPort(normal=(0.0, 0.0, 1.0), distance=PAPER_PORT_DISTANCE_MM,
                    thicknesses=(PAPER_GLASS_THICKNESS_MM,),
                    indices=(PAPER_INDICES[0], PAPER_INDICES[1], n_water))


def air_port() -> FlatPort:
    """An index-matched 'port' (all indices 1): the all-air copy of the scene."""
    return FlatPort(normal=(0.0, 0.0, 1.0), distance=PAPER_PORT_DISTANCE_MM,
                    thicknesses=(PAPER_GLASS_THICKNESS_MM,), indices=(1.0, 1.0, 1.0))


def paper_cameras(size=PAPER_IMAGE_SIZE, focal_px=PAPER_FOCAL_PX, dist=None):
    """Left camera at the origin; right camera at (200, 0, 0) mm turned 5 deg towards the left.

    ``size`` and ``focal_px`` scale together for small test renders (keep the field of view by
    passing ``focal_px = PAPER_FOCAL_PX * width / 2448``).
    """
    K = paper_intrinsics(size, focal_px)
    left = Camera(K, size, dist=dist)
    right = Camera(K, size, dist=dist, R=rotation_y(-np.deg2rad(PAPER_TOE_IN_DEG)),
                   t=(PAPER_BASELINE_MM, 0.0, 0.0))
    return left, right


def row_cameras(count: int, size=PAPER_IMAGE_SIZE, focal_px=PAPER_FOCAL_PX, dist=None,
                baseline_mm: float = PAPER_BASELINE_MM, toe_in_deg: float = PAPER_TOE_IN_DEG):
    """``count`` cameras in a row along x, ``baseline_mm`` apart: camera k at
    ``(k · baseline, 0, 0)`` turned ``k · toe_in_deg`` about y towards the first (which is the
    reference, at the origin, unturned), so that all look in towards the targets ahead of the
    row. Two of them are :func:`paper_cameras`."""
    K = paper_intrinsics(size, focal_px)
    return tuple(Camera(K, size, dist=dist, R=None if k == 0 else
                        rotation_y(-np.deg2rad(toe_in_deg * k)), t=(baseline_mm * k, 0.0, 0.0))
                 for k in range(count))


def ring_cameras(count: int, size=PAPER_IMAGE_SIZE, focal_px=PAPER_FOCAL_PX, dist=None,
                 radius_mm: float = PAPER_BASELINE_MM, toe_in_deg: float = PAPER_TOE_IN_DEG):
    """``count`` ≥ 3 cameras as a ring round a centre camera: camera 0 at the origin, unturned
    (the reference), looking along +z; cameras 1 … count − 1 evenly on the circle of
    ``radius_mm`` about its optical axis in the plane z = 0, camera k at angle
    ``2π (k − 1) / (count − 1)`` from +x towards +y, each turned ``toe_in_deg`` towards the
    centre's axis (about the circle's tangent), so that all look in at the targets ahead."""
    if count < 3:
        raise ValueError(f"a ring holds a centre camera and at least two round it, got {count}")
    from scipy.spatial.transform import Rotation
    K = paper_intrinsics(size, focal_px)
    cameras = [Camera(K, size, dist=dist)]
    for k in range(1, count):
        angle = 2.0 * np.pi * (k - 1) / (count - 1)
        tangent = np.array([-np.sin(angle), np.cos(angle), 0.0])
        R = Rotation.from_rotvec(-np.deg2rad(toe_in_deg) * tangent).as_matrix()
        cameras.append(Camera(K, size, dist=dist, R=R,
                              t=(radius_mm * np.cos(angle), radius_mm * np.sin(angle), 0.0)))
    return tuple(cameras)


def paper_rig(in_air: bool = False, size=PAPER_IMAGE_SIZE, focal_px=None, dist=None,
              n_water: float = PAPER_INDICES[2]) -> Rig:
    """The full stereo rig behind the paper's port (``in_air=True``: the all-air copy)."""
    if focal_px is None:
        focal_px = PAPER_FOCAL_PX * size[0] / PAPER_IMAGE_SIZE[0]
    left, right = paper_cameras(size, focal_px, dist)
    return StereoRig(left, right, air_port() if in_air else paper_port(n_water))
