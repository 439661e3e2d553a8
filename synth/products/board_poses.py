"""Where a calibration board may stand: the cameras of a boards folder behind their ports
(:func:`board_rig`; N > 2 cameras as :class:`BoardCameras`) and seeded poses of the board
(:func:`sample_poses`) wholly in every view, in the water, tilted at most as asked. Poses are
``X_ref = R @ X_board + t`` in mm, the reference frame the left (first) camera's."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from measure import Rig, StereoRig
from measure.calibration.board import Board
from measure.geometry.port import index_matched_port
from measure.geometry.projection import project

from synth.scene import SceneSpec

#: How far the board's centre stands from the left camera along its depth axis (mm).
DEFAULT_DISTANCE_RANGE_MM = (700.0, 1400.0)
#: In air the boards come nearer, so that their corners cover about half of each image: the
#: in-air distortion and principal point are what the housing calibration trusts, and boards at
#: 0.7–1.4 m (37 % of the image) left them 0.1–0.2 px off, which moved the port distance by
#: 0.35–0.40 mm; at 0.35–0.8 m (48–52 %) the port came within 0.06 mm (docs/calibration.md).
DEFAULT_AIR_DISTANCE_RANGE_MM = (350.0, 800.0)
#: The largest tilt of the board against the depth axis (degrees).
DEFAULT_MAX_TILT_DEG = 45.0
#: Largest turn of the board about its own normal (degrees).
MAX_ROLL_DEG = 20.0
#: Smallest distance (px) of any board point from the image border.
IMAGE_MARGIN_PX = 10.0
#: Candidate poses tried per pose wanted before giving up.
ATTEMPTS_PER_POSE = 400


@dataclass(frozen=True)
class BoardPose:
    """``X_ref = R @ X_board + t`` (mm)."""

    R: np.ndarray
    t: np.ndarray

    def apply(self, points_board: np.ndarray) -> np.ndarray:
        return np.asarray(points_board, float) @ self.R.T + self.t


@dataclass(frozen=True)
class BoardCameras:
    """The N > 2 cameras of a boards folder, each behind the port it looks through
    (``ports``, one per camera: one shared flat port, an index-matched one in air, or a flat
    port each): what :func:`sample_poses` and :func:`corner_pixels` ask of a
    :class:`measure.Rig` of two (``cameras``, ``left``, ``view_port``, ``water_side``,
    ``depth_axis``), and the cameras' ``names``."""

    cameras: tuple
    names: tuple
    ports: tuple

    @property
    def left(self):
        return self.cameras[0]

    @property
    def depth_axis(self) -> np.ndarray:
        return self.ports[0].depth_axis(self.cameras[0])

    def view_port(self, view: int):
        return self.ports[view]

    def water_side(self, points) -> np.ndarray:
        """Whether points ``(P, 3)`` lie in the water of every camera's port."""
        return np.all([port.water_side(points) for port in set(self.ports)], axis=0)

    def multirig(self):
        """As a :class:`measure.stereo.rig.Rig` (``calib.yaml`` of N cameras)."""
        from measure.stereo.rig import Rig

        return Rig(self.cameras, list(self.ports), self.names)


def board_rig(spec: SceneSpec, air: bool):
    """The scene's cameras behind their ports, or (``air``) the same cameras with no port: a
    a pair (:class:`measure.Rig` of two) for two cameras, :class:`BoardCameras` for more."""
    if spec.extra_cameras:
        cameras = spec.all_cameras
        ports = ((index_matched_port(cameras[0].R[:, 2], np.stack([c.t for c in cameras])),)
                 * len(cameras) if air else spec.multirig.ports)
        return BoardCameras(tuple(cameras), tuple(spec.camera_names), tuple(ports))
    if not air:
        return spec.rig
    left, right = spec.cameras
    return StereoRig(left, right, index_matched_port(left.R[:, 2], np.stack([left.t, right.t])))


def _fits(rig, board: Board, poses_R, poses_t, water: bool, anchor: int | None = None,
          shifts=()) -> np.ndarray:
    """Which candidate poses ``(M, 3, 3)``, ``(M, 3)`` put every board point inside both images
    (and in the water behind a port) — of N > 2 cameras (``anchor`` given): inside the image
    of camera ``anchor`` and of at least one other; with ``shifts`` (mm, (3,) each) also
    every pose moved by each of them (a moving board's ends)."""
    if len(shifts):
        return np.all([_fits(rig, board, poses_R, poses_t + shift, water, anchor)
                       for shift in [np.zeros(3), *shifts]], axis=0)
    points_board = np.concatenate([board.outline(), board.corners()])
    world = np.einsum("mij,pj->mpi", poses_R, points_board) + poses_t[:, None, :]
    flat = world.reshape(-1, 3)
    wet = ((rig.water_side(flat) if isinstance(rig, BoardCameras) else rig.port.water_side(flat))
           if water else np.ones(flat.shape[0], bool))
    inside = np.stack([camera.in_image(project(camera, rig.view_port(view), flat),
                                       IMAGE_MARGIN_PX)
                       for view, camera in enumerate(rig.cameras)])
    whole = (inside & wet).reshape(len(rig.cameras), poses_R.shape[0], -1).all(axis=2)
    if anchor is None:
        return whole.all(axis=0)
    return whole[anchor] & (whole.sum(axis=0) >= 2)


def sample_poses(rig: Rig, board: Board, n: int, seed: int, water: bool,
                 distance_range=DEFAULT_DISTANCE_RANGE_MM,
                 max_tilt_deg: float = DEFAULT_MAX_TILT_DEG, shifts=()) -> list[BoardPose]:
    """``n`` seeded random poses that keep the whole board inside both images (module docs);
    of N > 2 cameras (:class:`BoardCameras`), pose k centred in the view of camera k mod N and
    wholly inside it and at least one other; also when moved by each of ``shifts`` (mm: a
    moving board's ends). Raises ``ValueError`` when the working volume cannot hold the board
    that often."""
    near, far = (float(v) for v in distance_range)
    if not (0 < near < far):
        raise ValueError(f"distance range must satisfy 0 < near < far, got {near:g}, {far:g} mm")
    if not 0 <= max_tilt_deg < 80:
        raise ValueError(f"maximum tilt must lie in [0, 80) degrees, got {max_tilt_deg:g}")
    rng = np.random.default_rng(seed)
    several = isinstance(rig, BoardCameras)
    w, h = rig.left.size
    half = np.array(board.size_mm + (0.0,)) / 2
    normal = rig.depth_axis  # the port normal, or the left optical axis for domes
    poses, tried = [], 0
    while len(poses) < n:
        if tried >= ATTEMPTS_PER_POSE * n:
            raise ValueError(
                f"only {len(poses)} of {n} board poses keep the whole {board.squares[0]}x"
                f"{board.squares[1]} board of {board.square_mm:g} mm squares inside both "
                f"{w}x{h} px images at {near:g}-{far:g} mm (tried {tried}): use a smaller "
                f"board (--squares, --square-mm) or a farther distance range")
        m = 256
        tried += m
        anchor = len(poses) % len(rig.cameras) if several else None
        left = rig.cameras[anchor] if several else rig.left
        depth = rng.uniform(near, far, m)
        uv = np.column_stack([rng.uniform(0.2 * w, 0.8 * w, m), rng.uniform(0.2 * h, 0.8 * h, m)])
        rays = left.rays(uv)
        centre = left.t + rays * ((depth - normal @ left.t) / (rays @ normal))[:, None]
        axis_angle = rng.uniform(0, 2 * np.pi, m)
        tilt = np.radians(max_tilt_deg) * np.sqrt(rng.uniform(0, 1, m))
        axes = np.column_stack([np.cos(axis_angle), np.sin(axis_angle), np.zeros(m)])
        roll = np.radians(rng.uniform(-MAX_ROLL_DEG, MAX_ROLL_DEG, m))
        R = (Rotation.from_rotvec(axes * tilt[:, None])
             * Rotation.from_rotvec(np.column_stack([np.zeros(m), np.zeros(m), roll]))).as_matrix()
        R = left.R @ R  # the untilted board faces the left camera
        t = centre - R @ half
        keep = np.flatnonzero(_fits(rig, board, R, t, water, anchor, shifts))
        poses += [BoardPose(R[i], t[i]) for i in keep[: (1 if several else n - len(poses))]]
    return poses


# ---------------------------------------------------------------------------------------------
# rendering
# ---------------------------------------------------------------------------------------------
