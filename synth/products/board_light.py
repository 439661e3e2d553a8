"""A printed calibration board lit by a lamp: the light of ``synth boards --light``.

By default a rendered board is self-luminous (an ``area`` emitter whose radiance is the
pattern, :mod:`synth.products.boards`): every white square equally bright. A real board is
printed paper lit from one side, and its white squares differ across the board by 1.0–3.5×
(``ouc_flat/air``, docs/calibration.md). :class:`BoardLight` is that board instead: the
rectangle is a Mitsuba ``diffuse`` BSDF whose reflectance is the printed pattern (``black``
and ``white`` reflectances, the white margin included; nearest-texel lookup, so the squares'
edges are where OpenCV's model puts them) and it is lit by one lamp, a Mitsuba ``spot`` or
``point`` emitter, fixed relative to the left camera (a lamp on the rig or beside it). Only the
light changes: the geometry, and so every corner's forward-model pixel, is the luminous
board's.

Frames and units: ``position_mm`` and ``aim_mm`` are in the **left camera's frame** (OpenCV
axes, mm); :meth:`BoardLight.placement` gives them in the reference frame
(``X_ref = R·X_cam + t``). ``intensity`` is the lamp's radiant intensity on its axis in the
renderer's linear units: a diffuse surface of reflectance ρ at distance r facing the lamp has
radiance ``ρ/π · I / r²`` (``intensity`` × the spot's falloff × cos θ / r² in general,
:func:`board_radiance`). The default makes white paper (ρ = 0.8) at 1 m facing the lamp as
bright as the luminous board's white (radiance 1.0): ``I = π / 0.8 · 10⁶``.

The spot's falloff is Mitsuba's: full intensity within ``beam_deg`` of its axis, falling
linearly in angle to 0 at ``cutoff_deg`` (:func:`spot_falloff`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

LIGHT_KINDS = ("spot", "point")
#: Where the lamp sits by default, mm in the left camera's frame: behind a port 300 mm to the
#: left of the camera, 200 mm above it and 150 mm ahead (beyond the paper port's glass, in the
#: water, like a strobe on an arm); in air 200 mm left, 150 mm above and 600 mm behind it (a
#: lamp on a stand behind the photographer: the in-air boards come as near as 350 mm, and a
#: lamp beside them would light their near and far sides 5–30× apart). Measured in
#: docs/calibration.md ("A printed, lit board").
DEFAULT_LIGHT_POSITION_MM = (-300.0, -200.0, 150.0)
DEFAULT_AIR_LIGHT_POSITION_MM = (-200.0, -150.0, -600.0)
#: The lamp's intensity (linear units, see the module docs): white paper at 1 m facing it has
#: the luminous board's radiance.
DEFAULT_PAPER_WHITE = 0.8
DEFAULT_LIGHT_INTENSITY = np.pi / DEFAULT_PAPER_WHITE * 1.0e6
#: Reflectance of the printed black (toner on paper, a few percent).
DEFAULT_PAPER_BLACK = 0.04
#: The spot's cut-off half-angle (degrees); the full-intensity beam is 3/4 of it (Mitsuba's
#: default ratio).
DEFAULT_SPOT_CUTOFF_DEG = 45.0
BEAM_FRACTION = 0.75


@dataclass(frozen=True)
class BoardLight:
    """The lamp that lights a printed board (module docs). ``kind`` ``"spot"`` or ``"point"``;
    ``position_mm`` (3,) and ``aim_mm`` (3,) in the left camera's frame (mm; None until
    :meth:`placed`: the default position for the medium, and a point on the left optical axis
    at the middle of the board distances); ``intensity`` (linear units); ``cutoff_deg`` the spot's
    cut-off half-angle (its full beam ``BEAM_FRACTION`` of it); ``black``, ``white`` the
    printed reflectances (0–1)."""

    kind: str = "spot"
    position_mm: tuple | None = None
    aim_mm: tuple | None = None
    intensity: float = DEFAULT_LIGHT_INTENSITY
    cutoff_deg: float = DEFAULT_SPOT_CUTOFF_DEG
    black: float = DEFAULT_PAPER_BLACK
    white: float = DEFAULT_PAPER_WHITE

    def __post_init__(self):
        if self.kind not in LIGHT_KINDS:
            raise ValueError(f"light kind {self.kind!r}: choose from {', '.join(LIGHT_KINDS)}")
        position = None if self.position_mm is None else _vector(self.position_mm,
                                                                   "light position")
        aim = None if self.aim_mm is None else _vector(self.aim_mm, "light aim")
        if (aim is not None and position is not None
                and np.linalg.norm(np.subtract(aim, position)) < 1e-6):
            raise ValueError("the light's aim point is its position: no direction")
        if not (np.isfinite(self.intensity) and self.intensity > 0):
            raise ValueError(f"light intensity must be positive, got {self.intensity!r}")
        if not 0 < self.cutoff_deg < 90:
            raise ValueError(f"spot angle must lie in (0, 90) degrees, got {self.cutoff_deg!r}")
        if not 0 <= self.black < self.white <= 1:
            raise ValueError(f"print reflectances must satisfy 0 <= black < white <= 1, got "
                             f"{self.black!r}, {self.white!r}")
        object.__setattr__(self, "position_mm", position)
        object.__setattr__(self, "aim_mm", aim)
        object.__setattr__(self, "intensity", float(self.intensity))
        object.__setattr__(self, "cutoff_deg", float(self.cutoff_deg))
        object.__setattr__(self, "black", float(self.black))
        object.__setattr__(self, "white", float(self.white))

    @property
    def beam_deg(self) -> float:
        """Half-angle of the spot's full-intensity beam (degrees)."""
        return BEAM_FRACTION * self.cutoff_deg

    def placed(self, air: bool, aim_depth_mm: float) -> BoardLight:
        """The same lamp with what it was not given: the default position for the medium
        (:data:`DEFAULT_AIR_LIGHT_POSITION_MM` in ``air``, else
        :data:`DEFAULT_LIGHT_POSITION_MM`) and the aim point ``(0, 0, aim_depth_mm)`` (left
        camera frame, mm)."""
        position = self.position_mm or (DEFAULT_AIR_LIGHT_POSITION_MM if air
                                        else DEFAULT_LIGHT_POSITION_MM)
        aim = self.aim_mm or (0.0, 0.0, float(aim_depth_mm))
        return BoardLight(self.kind, position, aim, self.intensity, self.cutoff_deg, self.black,
                          self.white)

    def placement(self, left_camera) -> tuple[np.ndarray, np.ndarray]:
        """``(position, aim)`` (mm) in the reference frame, ``left_camera`` a
        :class:`measure.Camera` (``X_ref = R·X_cam + t``)."""
        if self.aim_mm is None or self.position_mm is None:
            raise ValueError("the light is not placed yet (BoardLight.placed)")
        R, t = left_camera.R, left_camera.t
        return R @ np.asarray(self.position_mm) + t, R @ np.asarray(self.aim_mm) + t

    def to_dict(self) -> dict:
        data = asdict(self)
        data["position_mm"] = None if self.position_mm is None else list(self.position_mm)
        data["aim_mm"] = None if self.aim_mm is None else list(self.aim_mm)
        return data

    def emitter_dict(self, mi, left_camera) -> dict:
        """The lamp as a Mitsuba ``mi.load_dict`` emitter in the reference frame."""
        origin, aim = self.placement(left_camera)
        if self.kind == "point":
            return {"type": "point", "position": origin.tolist(),
                    "intensity": {"type": "rgb", "value": self.intensity}}
        to_world = mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=aim.tolist(),
                                                  up=_perpendicular(aim - origin).tolist())
        return {"type": "spot", "to_world": to_world,
                "intensity": {"type": "rgb", "value": self.intensity},
                "cutoff_angle": self.cutoff_deg, "beam_width": self.beam_deg}

    def reflectance(self, pattern_uint8: np.ndarray) -> np.ndarray:
        """The printed reflectance ``(H, W, 1)`` float32 of a pattern (0 black, 255 white)."""
        a = pattern_uint8.astype(np.float32) / np.float32(255)
        return (np.float32(self.black) + np.float32(self.white - self.black) * a)[..., None]


def _vector(value, what: str) -> tuple:
    try:
        v = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        v = ()
    if len(v) != 3 or not np.all(np.isfinite(v)):
        raise ValueError(f"{what} must be three finite numbers (mm), got {value!r}")
    return v


def _perpendicular(d: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to ``d`` (the spot's ``up``: it is round, any will do)."""
    d = d / np.linalg.norm(d)
    other = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    up = np.cross(d, other)
    return up / np.linalg.norm(up)


def spot_falloff(cos_angle, cutoff_deg: float, beam_deg: float) -> np.ndarray:
    """Mitsuba's ``spot`` falloff at angles of cosine ``cos_angle`` off its axis: 1 within
    ``beam_deg``, ``(cutoff − angle) / (cutoff − beam)`` up to ``cutoff_deg`` (angles in
    radians inside), 0 beyond."""
    angle = np.arccos(np.clip(cos_angle, -1.0, 1.0))
    cutoff, beam = np.radians(cutoff_deg), np.radians(beam_deg)
    ramp = (cutoff - angle) / (cutoff - beam)
    return np.where(angle <= beam, 1.0, np.where(angle < cutoff, ramp, 0.0))


def board_radiance(light: BoardLight, left_camera, points, normal, reflectance) -> np.ndarray:
    """Closed-form radiance of diffuse board points ``(P, 3)`` (mm, reference frame) with unit
    ``normal`` (3,) on their lit side and ``reflectance`` (scalar or (P,)) under ``light`` alone
    (no occlusion, no medium): ``ρ/π · I · falloff · max(cos θ, 0) / r²``."""
    origin, aim = light.placement(left_camera)
    to_light = origin - np.asarray(points, float)
    r = np.linalg.norm(to_light, axis=1)
    cos_board = np.maximum(to_light @ np.asarray(normal, float) / r, 0.0)
    falloff = 1.0
    if light.kind == "spot":
        axis = (aim - origin) / np.linalg.norm(aim - origin)
        falloff = spot_falloff(-(to_light @ axis) / r, light.cutoff_deg, light.beam_deg)
    return np.asarray(reflectance) / np.pi * light.intensity * falloff * cos_board / r ** 2


def check_light(rig, light: BoardLight, air: bool) -> None:
    """ValueError unless the lamp can light the boards: behind a port it must be in the water
    (a lamp inside the housing would light the board only through the glass, which the
    renderer's next-event estimation cannot see through)."""
    position, _ = light.placement(rig.left)
    water_side = getattr(rig, "water_side", None) or rig.port.water_side  # N cameras, or a pair
    wet = water_side(position[None])[0]
    if not air and not wet:
        x, y, z = light.position_mm
        raise ValueError(f"the light at {x:g},{y:g},{z:g} mm (left camera frame) is not in the "
                         f"water: behind a port it must sit beyond the glass (like a strobe on "
                         f"an arm); move it farther along z")


def light_record(light: BoardLight, rig) -> dict:
    """The manifest's ``light``: its options and where it was, in the reference frame."""
    position, aim = light.placement(rig.left)
    return {**light.to_dict(), "position_reference_mm": position.tolist(),
            "aim_reference_mm": aim.tolist()}


__all__ = ["BoardLight", "DEFAULT_AIR_LIGHT_POSITION_MM", "DEFAULT_LIGHT_INTENSITY",
           "DEFAULT_LIGHT_POSITION_MM", "LIGHT_KINDS",
           "board_radiance", "check_light", "light_record", "spot_falloff", "stored_white_ratios",
           "white_square_centres", "white_square_levels"]


def white_square_centres(board) -> np.ndarray:
    """The centres ``(S, 3)`` (mm, board frame) of a chessboard's white squares (the top-left
    square is black: square (row i, column j) is white when i + j is odd)."""
    if board.kind != "chessboard":
        raise ValueError(f"white squares are measured on chessboards, not {board.kind}")
    cols, rows = board.squares
    i, j = np.mgrid[0:rows, 0:cols]
    white = (i + j) % 2 == 1
    return np.column_stack([j[white] + 0.5, i[white] + 0.5, np.zeros(white.sum())]) \
        * board.square_mm


#: Offsets (fractions of a square) of the points averaged inside each white square.
_PATCH = np.linspace(-0.25, 0.25, 5)


def white_square_levels(image, camera, port, board, pose) -> np.ndarray:
    """The mean image value ``(S,)`` over the middle half of each white square of a chessboard
    at ``pose`` (a :class:`synth.products.boards.BoardPose`) seen by ``camera`` through
    ``port``: 25 points per square projected with the forward model and sampled bilinearly
    (``cv2.remap``); NaN for a square that is not wholly inside the image."""
    import cv2

    from measure.geometry.projection import project

    s = board.square_mm
    du, dv = np.meshgrid(_PATCH * s, _PATCH * s)
    offsets = np.column_stack([du.ravel(), dv.ravel(), np.zeros(du.size)])
    points = (white_square_centres(board)[:, None, :] + offsets[None]).reshape(-1, 3)
    uv = project(camera, port, pose.apply(points))
    values = cv2.remap(np.ascontiguousarray(image, np.float32),
                       uv[:, 0].astype(np.float32)[:, None], uv[:, 1].astype(np.float32)[:, None],
                       cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    inside = camera.in_image(uv, 1.0).reshape(-1, offsets.shape[0]).all(axis=1)
    levels = values.reshape(-1, offsets.shape[0]).mean(axis=1)
    return np.where(inside, levels, np.nan)


def stored_white_ratios(levels, white_dn: float, clip_dn: float = 255.0):
    """The white squares as a camera with one exposure for every view would store them: the
    linear ``levels`` (a sequence of ``(S,)`` arrays, one per view, the rendered values; NaN
    for a square outside the image) scaled so that the median over the views of each view's
    median white square is ``white_dn``, rounded and clipped at ``clip_dn`` (an 8-bit linear
    camera that saturates). ``(max/min of the stored levels per view, whether each view has a
    clipped white square)``, arrays over the views."""
    medians = [np.nanmedian(v) for v in levels]
    scale = float(white_dn) / float(np.median(medians))
    stored = [np.clip(np.rint(np.asarray(v, float) * scale), 0.0, clip_dn) for v in levels]
    ratio = np.array([np.nanmax(v) / np.nanmin(v) for v in stored])
    clipped = np.array([bool(np.nanmax(v) >= clip_dn) for v in stored])
    return ratio, clipped
