"""A sea scene drawn from one seed: the stereo rig and its port, the water, the light and the
sea floor's pose, each from ranges of real rigs and dives (:class:`SeaRanges`).

Frames and units: millimetres; the reference frame is the left camera's (OpenCV axes: x right,
y down, z forward); the *seabed frame* (:mod:`synth.scene.seabed`) has ``z`` up. A scene is
placed by its rig: the rig's centre (between the camera centres) is ``distance_mm`` along the
bisector of the two optical axes from the point of the mean sea floor it looks at, the bisector
pitched ``pitch_deg`` below the horizontal and rolled ``roll_deg`` about itself. The distance
is drawn within :data:`MAX_ATTENUATION_LENGTHS` of the water's attenuation length (no one
films a sea floor through 4 m of harbour water: the direct light left is exp(-8)).

Ranges of real rigs (:data:`PORT_KINDS`):

* ``per-camera`` — two housings, a flat port each: the port 18–25 mm in front of its camera,
  its normal 0.4–2° off the optical axis, 5 mm of glass of index 1.5 — the ranges of the
  calibrated two-housing rigs of Ermisgc/uMVS (MIT licence; ``binouwcam_*.yaml``: ports 18.1–24.6
  mm, tilts 0.36–2.0°, 5 mm glass, n 1.5, water 1.333; baselines 151–359 mm, convergence
  0.8–34°);
* ``flat`` — one window in front of both cameras (the paper's kind of housing): 30–120 mm from
  the left camera, tilted 0–2°, 5–20 mm of glass (index 1.49–1.54), convergence at most 10°;
* ``dome`` — a glass dome per camera, inner radius 50–120 mm, 5–12 mm thick (index 1.49–1.54),
  its centre up to 2 mm off the camera's centre across and 5 mm along the axis.

Cameras: 960 × 768 px (or the size asked), a horizontal field of view in air of 50–80° (uMVS:
53° and 78°), the principal point within 2 % of the image centre, square pixels, no lens
distortion; baseline 100–360 mm; the right camera turned towards the left by the convergence,
and by up to ±0.3° about its other axes (rigs are never perfect).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from measure import Camera, FlatPort, Rig, StereoRig
from synth.rendering.water import PRESETS as WATER_PRESETS
from synth.scene.dome import check_field_of_view, dome_pair
from synth.scene.rig import tilted_port_normal
from synth.scene.seabed import SeabedParams, draw_seabed
from synth.scene.windows import check_windows, fit_windows, flat_pair

#: The kinds of port a scene is drawn with (``synth learn --ports``).
PORT_KINDS = ("flat", "per-camera", "dome")
#: The waters (``clear``: no medium; the others :data:`synth.rendering.water.PRESETS`).
WATERS = ("clear",) + tuple(WATER_PRESETS)
#: The lights: two ``lamps`` on the housing's sides, or the ``sun`` far above.
LIGHTS = ("lamps", "sun")
#: The farthest a rig is drawn from the floor, in attenuation lengths of its water (1 / c):
#: turbid harbour water (c = 2.19 / m) keeps the rig within 0.91 m, the others are not limited
#: by the default ranges.
MAX_ATTENUATION_LENGTHS = 2.0
#: Draws of a rig that a port does not fit (a window in the other camera's view, a field of view
#: that misses a dome) before the scene is given up.
MAX_RIG_DRAWS = 20


@dataclass(frozen=True)
class SeaRanges:
    """What a scene may be drawn with: image ``size`` (W, H) px, the port kinds, waters and
    lights to choose from (uniformly), the range of the rig's distance to the floor (mm) and of
    the bisector's pitch below the horizontal (degrees), the object meshes set on the floor."""

    size: tuple = (960, 768)
    ports: tuple = PORT_KINDS
    waters: tuple = WATERS
    lights: tuple = LIGHTS
    distance_mm: tuple = (800.0, 2500.0)
    pitch_deg: tuple = (50.0, 90.0)
    #: Object meshes (paths: PLY or OBJ, mm, z up) set on the floors (:mod:`synth.scene.sea_objects`).
    objects: tuple = ()

    def describe(self) -> dict:
        """Plain lists (no ``objects`` when there are none: a set without objects keeps the
        request keys it had before objects existed)."""
        return {k: list(v) for k, v in asdict(self).items() if k != "objects" or v}


@dataclass(frozen=True)
class SeaScene:
    """One drawn scene (module docs): ``rig`` (reference frame), ``port_kind``, ``water``
    (a :data:`WATERS` name), ``light``, ``seabed`` parameters, ``to_reference`` ``(R, t)``
    taking seabed-frame points into the reference frame, and what was drawn (``drawn``: plain
    numbers for the manifest)."""

    seed: int
    rig: Rig
    port_kind: str
    water: str
    light: str
    seabed: SeabedParams
    to_reference: tuple
    distance_mm: float
    drawn: dict = field(default_factory=dict)
    objects: tuple = ()


def seed_streams(seed: int, count: int = 4) -> list:
    """Independent generators for the parts of a scene (rig, seabed, texture, objects): a
    change to how one part is drawn leaves the others' draws as they were."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(count)]


def _intrinsics(rng, size) -> tuple[np.ndarray, float]:
    w, h = size
    hfov = rng.uniform(50.0, 80.0)
    f = (w / 2.0) / np.tan(np.radians(hfov) / 2.0)
    cx = (w - 1) / 2.0 + rng.uniform(-0.02, 0.02) * w
    cy = (h - 1) / 2.0 + rng.uniform(-0.02, 0.02) * h
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]), float(hfov)


def _rig_cameras(rng, size, port_kind: str, distance: float):
    """The two cameras in the rig frame (bisector along z, baseline along x) and what was
    drawn: left at ``(-B/2, 0, 0)`` turned ``+c/2`` about y, right at ``(B/2, 0, 0)`` turned
    ``-c/2`` and by a small misalignment."""
    from scipy.spatial.transform import Rotation  # here: synth learn --help loads no SciPy

    K, hfov = _intrinsics(rng, size)
    baseline = rng.uniform(100.0, 360.0)
    widest = 10.0 if port_kind == "flat" else 34.0
    crossing = np.degrees(2 * np.arctan(baseline / (2 * 0.6 * distance)))
    convergence = rng.uniform(0.0, min(widest, crossing))
    misalign = rng.uniform(-0.3, 0.3, size=2)
    half = np.radians(convergence / 2)
    R_left = Rotation.from_rotvec([0, half, 0]).as_matrix()
    R_right = (Rotation.from_rotvec([0, -half, 0])
               * Rotation.from_rotvec(np.radians([misalign[0], 0, misalign[1]]))).as_matrix()
    t_left, t_right = np.array([-baseline / 2, 0, 0]), np.array([baseline / 2, 0, 0])
    # into the left camera's frame: X_left = R_left^T (X_rig - t_left)
    right = Camera(K, size, R=R_left.T @ R_right, t=R_left.T @ (t_right - t_left))
    left = Camera(K, size)
    drawn = {"hfov_air_deg": hfov, "focal_px": float(K[0, 0]), "baseline_mm": float(baseline),
             "convergence_deg": float(convergence), "misalignment_deg": misalign.tolist()}
    return (left, right), (R_left, t_left), drawn


def _port(rng, kind: str, cameras, n_water: float):
    """The port of ``kind`` for ``cameras`` (reference frame) and what was drawn."""
    from scipy.spatial.transform import Rotation  # here: synth learn --help loads no SciPy

    if kind == "per-camera":
        distances = rng.uniform(18.0, 25.0, size=2)
        tilts = [_small_tilt(rng, 0.4, 2.0) for _ in range(2)]
        port = flat_pair(cameras, distances, tilts, (5.0, 5.0), (1.0, 1.5, n_water))
        return port, {"port_distance_mm": distances.tolist(), "port_tilt_deg": tilts,
                      "glass_mm": 5.0, "n_glass": 1.5}
    if kind == "flat":
        bisector = cameras[0].R[:, 2] + cameras[1].R[:, 2]
        tilt = _small_tilt(rng, 0.0, 2.0)
        normal = Rotation.align_vectors([bisector], [[0, 0, 1.0]])[0].apply(
            tilted_port_normal(*tilt))
        distance = rng.uniform(30.0, 120.0)
        glass, n_glass = rng.uniform(5.0, 20.0), rng.uniform(1.49, 1.54)
        port = FlatPort(normal, distance, (glass,), (1.0, n_glass, n_water))
        StereoRig(cameras[0], cameras[1], port)
        return port, {"port_distance_mm": float(distance), "port_tilt_deg": tilt,
                      "glass_mm": float(glass), "n_glass": float(n_glass)}
    radius, thickness = rng.uniform(50.0, 120.0), rng.uniform(5.0, 12.0)
    offset = np.r_[rng.uniform(-2.0, 2.0, size=2), rng.uniform(-5.0, 5.0)]
    n_glass = rng.uniform(1.49, 1.54)
    port = dome_pair(cameras, radius, thickness, offset, (1.0, n_glass, n_water))
    return port, {"dome_radius_mm": float(radius), "dome_thickness_mm": float(thickness),
                  "dome_offset_mm": offset.tolist(), "n_glass": float(n_glass)}


def _small_tilt(rng, low: float, high: float) -> list:
    """A tilt of ``low``–``high`` degrees in a random direction, as (about x, about y) degrees."""
    amount, direction = rng.uniform(low, high), rng.uniform(0.0, 2 * np.pi)
    return [float(amount * np.cos(direction)), float(amount * np.sin(direction))]


def _check_port(rig: Rig, kind: str) -> None:
    if kind == "dome":
        check_field_of_view(rig)
    elif kind == "per-camera":
        check_windows(rig, fit_windows(rig))


def _placement(rng, ranges: SeaRanges, rig_pose, distance: float):
    """``(R, t)`` taking seabed-frame points into the reference frame, and what was drawn."""
    from scipy.spatial.transform import Rotation  # here: synth learn --help loads no SciPy

    pitch = np.radians(rng.uniform(*ranges.pitch_deg))
    roll = np.radians(rng.uniform(-10.0, 10.0))
    ahead = np.array([np.cos(pitch), 0.0, -np.sin(pitch)])     # the bisector (rig z)
    down = np.array([-np.sin(pitch), 0.0, -np.cos(pitch)])     # image down (rig y)
    across = np.cross(down, ahead)                             # image right (rig x)
    rolled = Rotation.from_rotvec(roll * ahead)
    rig_to_sea = np.column_stack([rolled.apply(across), rolled.apply(down), ahead])
    centre = np.array([0.0, 0.0, distance * np.sin(pitch)])    # the rig's centre, seabed frame
    R_left, t_left = rig_pose
    R_cam = rig_to_sea @ R_left                                # left camera -> seabed
    c_cam = centre + rig_to_sea @ t_left
    # X_ref = R_cam^T (X_sea - c_cam)
    return (R_cam.T, -R_cam.T @ c_cam), {"pitch_deg": float(np.degrees(pitch)),
                                         "roll_deg": float(np.degrees(roll)),
                                         "look_at_mm": [float(distance * np.cos(pitch)), 0.0, 0.0]}


def draw_scene(seed: int, ranges: SeaRanges = SeaRanges()) -> SeaScene:
    """The scene of ``seed`` (module docs): everything drawn from ``seed`` alone, so that one
    seed and the same ranges give the same scene on any machine."""
    rig_rng, seabed_rng = seed_streams(seed)[:2]
    port_kind = str(rig_rng.choice(ranges.ports))
    water = str(rig_rng.choice(ranges.waters))
    light = str(rig_rng.choice(ranges.lights))
    near, far = ranges.distance_mm
    if water in WATER_PRESETS:
        far = max(near, min(far, 1000.0 * MAX_ATTENUATION_LENGTHS / WATER_PRESETS[water].c_per_m))
    distance = float(rig_rng.uniform(near, far))
    n_water = float(rig_rng.uniform(1.333, 1.345))
    for draws in range(1, MAX_RIG_DRAWS + 1):
        cameras, rig_pose, drawn = _rig_cameras(rig_rng, tuple(ranges.size), port_kind, distance)
        try:
            port, port_drawn = _port(rig_rng, port_kind, cameras, n_water)
            rig = StereoRig(cameras[0], cameras[1], port)
            _check_port(rig, port_kind)
        except ValueError:
            continue
        drawn["rig_draws"] = draws
        break
    else:
        raise ValueError(f"seed {seed}: no {port_kind} port fitted {MAX_RIG_DRAWS} drawn rigs")
    to_reference, placed = _placement(rig_rng, ranges, rig_pose, distance)
    # the sun on the far side of the point looked at from the rig (seabed +x)
    placed.update(sun_zenith_deg=float(rig_rng.uniform(35.0, 55.0)),
                  sun_azimuth_deg=float(rig_rng.uniform(-40.0, 40.0)))
    drawn.update(port_drawn, n_water=n_water, **placed)
    return SeaScene(int(seed), rig, port_kind, water, light, draw_seabed(seabed_rng),
                    to_reference, distance, drawn, tuple(ranges.objects))


__all__ = ["LIGHTS", "MAX_ATTENUATION_LENGTHS", "MAX_RIG_DRAWS", "PORT_KINDS", "SeaRanges",
           "SeaScene", "WATERS", "draw_scene", "seed_streams"]
