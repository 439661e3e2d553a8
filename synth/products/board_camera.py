"""Cameras as they are, for ``synth boards``: vignetting, a thin lens's defocus and a rolling
shutter that reads a moving board row by row. Each is off by default (the board then renders
byte for byte as before).

* **Vignetting** (``cos4``, ``lens_falloff``): the rendered linear image times
  :func:`synth.rendering.camera_effects.vignetting_map` of each camera.
* **Defocus** (``aperture_radius_mm``, ``focus_distance_mm``): Mitsuba ``thinlens`` sensors in
  place of the pinholes. Mitsuba's thin lens has no principal-point offset and the renderer
  has no distorted thin lens: a camera whose principal point is off the image centre, or that
  has lens distortion, is refused. The truth stays the pinhole's (the chief ray).
* **Motion blur** (``exposure_s``, ``velocity_mm_s``): the board moves at a constant
  velocity during a global shutter's exposure; the image is the mean of :func:`exposure_slices`
  renders at the midpoints of equal slices of the exposure (as many as keep the board's image
  moving at most :data:`SLICE_MOTION_PX` within a slice, at most :data:`MAX_BANDS`), each with
  ``ceil(spp / slices)`` samples a pixel. The truth is the board at mid-exposure (the pose of
  ``poses.csv``). Not together with a rolling shutter.
* **Rolling shutter** (``readout_s``, ``velocity_mm_s``): the board moves at a constant
  velocity (mm/s, reference frame) and image row ``v`` (a pixel-centre row, 0 at the top) is
  exposed at ``t(v) = readout · (v / (H − 1) − ½)`` s, so the pose of ``poses.csv`` is the
  board at the middle of the readout (``t = 0``). Rendered in bands of rows (each band at the
  instant of its middle row, :func:`row_bands`: as many as keep the board's image moving at
  most :data:`BAND_MOTION_PX` within a band, at most :data:`MAX_BANDS`), every band only on its
  own pixels (:func:`synth.rendering.render.render_pixels`). The truth of each corner is the
  forward model's pixel at the instant of its own row (:func:`rolling_pixels`: the pixel's
  row and the instant agree to 1e-6 px).

Units: mm, seconds, pixels (OpenCV convention); frames as in :mod:`synth.products.boards`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

#: Largest motion (px) of the board's image within one band of rows of a rolling shutter.
BAND_MOTION_PX = 0.05
#: Most bands of one rolling-shutter view (each band is one render call).
MAX_BANDS = 512
#: Largest motion (px) of the board's image within one slice of a motion-blurred exposure: the
#: blur is the mean of the slices' images, steps of at most this much along the motion (the
#: atlas's motion blur: 8 images over 4 px, 0.5 px).
SLICE_MOTION_PX = 0.25
#: The image of a moving board moves a little faster at one end of the readout than on average
#: (perspective): the bands allow for this much more than the average.
SPEED_MARGIN = 1.1


@dataclass(frozen=True)
class CameraEffects:
    """The camera effects of a boards folder (module docs): ``cos4`` (bool), ``lens_falloff``
    (fraction lost at the farthest corner, [0, 1)), ``aperture_radius_mm`` and
    ``focus_distance_mm`` (thin lens; 0: a pinhole), ``readout_s`` (rolling shutter's readout,
    s; 0: a global shutter), ``velocity_mm_s`` (3,) the board's velocity during it, and
    ``exposure_s`` (a global shutter's exposure, s, during which the board moves: motion blur;
    0: none)."""

    cos4: bool = False
    lens_falloff: float = 0.0
    aperture_radius_mm: float = 0.0
    focus_distance_mm: float = 0.0
    readout_s: float = 0.0
    velocity_mm_s: tuple = (0.0, 0.0, 0.0)
    exposure_s: float = 0.0

    def __post_init__(self):
        if not 0.0 <= self.lens_falloff < 1.0:
            raise ValueError(f"lens falloff must lie in [0, 1), got {self.lens_falloff!r}")
        if self.aperture_radius_mm < 0 or self.focus_distance_mm < 0:
            raise ValueError("a thin lens needs a positive aperture radius and focus distance")
        if self.readout_s < 0:
            raise ValueError(f"readout time must not be negative, got {self.readout_s!r}")
        if self.exposure_s < 0:
            raise ValueError(f"exposure time must not be negative, got {self.exposure_s!r}")
        if self.exposure_s > 0 and self.readout_s > 0:
            raise ValueError("motion blur (an exposure time) and a rolling shutter are not "
                             "rendered together here: give one of them")
        velocity = tuple(float(v) for v in self.velocity_mm_s)
        if len(velocity) != 3 or not np.all(np.isfinite(velocity)):
            raise ValueError(f"board velocity must be three finite numbers (mm/s), got "
                             f"{self.velocity_mm_s!r}")
        object.__setattr__(self, "velocity_mm_s", velocity)

    @property
    def rolling(self) -> bool:
        return self.readout_s > 0

    @property
    def blurred(self) -> bool:
        """Whether the board moves during a global shutter's exposure."""
        return self.exposure_s > 0

    @property
    def moving(self) -> bool:
        """A rolling shutter or motion blur: the board moves while the image is taken."""
        return self.rolling or self.blurred

    @property
    def motion_s(self) -> float:
        """How long the board moves while the image is taken (s): the readout or the
        exposure."""
        return self.readout_s if self.rolling else self.exposure_s

    @property
    def vignetting(self) -> bool:
        return self.cos4 or self.lens_falloff > 0

    def focused(self, port, depth_mm: float) -> CameraEffects:
        """The same effects with a thin lens's focus distance, when not given, at where a
        point ``depth_mm`` along the axis appears through ``port`` (paraxially: a flat port's
        :meth:`measure.FlatPort.apparent_depth`; ``port`` None: in air, ``depth_mm``)."""
        if self.aperture_radius_mm == 0 or self.focus_distance_mm > 0:
            return self
        if port is not None and not hasattr(port, "apparent_depth"):
            raise ValueError("give --focus-distance: the apparent distance through this port "
                             "has no closed form here")
        focus = depth_mm if port is None else port.apparent_depth(depth_mm)
        return replace(self, focus_distance_mm=float(focus))

    def to_dict(self) -> dict:
        """The effects as plain numbers (without an exposure time where there is none: the
        request keys of folders made before motion blur stay theirs)."""
        data = asdict(self)
        data["velocity_mm_s"] = list(self.velocity_mm_s)
        if not self.exposure_s:
            del data["exposure_s"]
        return data

    def row_time(self, v, height: int) -> np.ndarray:
        """The instant (s, 0 = the middle of the readout) at which pixel row ``v`` (px, any
        real row) is exposed in an image ``height`` px high."""
        return self.readout_s * (np.asarray(v, float) / (height - 1) - 0.5)

    def board_shift(self, t) -> np.ndarray:
        """The board's translation ``(..., 3)`` (mm) at instants ``t`` (s) from its pose."""
        return np.asarray(t, float)[..., None] * np.asarray(self.velocity_mm_s)


def check_effects(effects: CameraEffects, cameras) -> None:
    """ValueError (one line) for an effect the cameras cannot have: a thin lens on a camera
    whose principal point is off the image centre or that has lens distortion, a rolling
    shutter or motion blur on a distorted camera (rendered on an oversampled pinhole film whose rows are not
    the image's)."""
    for k, camera in enumerate(cameras):
        if effects.aperture_radius_mm > 0:
            w, h = camera.size
            centre = np.array([w / 2 - 0.5, h / 2 - 0.5])
            if np.max(np.abs(camera.K[:2, 2] - centre)) > 1e-6:
                raise ValueError(f"camera {k}: a thin lens (--aperture-radius) needs the "
                                 f"principal point at the image centre (Mitsuba's thinlens has "
                                 f"no offset), got {camera.K[0, 2]:g}, {camera.K[1, 2]:g}")
            if camera.dist is not None:
                raise ValueError(f"camera {k}: a thin lens is rendered without lens distortion "
                                 f"(set the coefficients to 0)")
        if effects.rolling and camera.dist is not None:
            raise ValueError(f"camera {k}: a rolling shutter is rendered on the image's own "
                             f"rows, which a camera with lens distortion does not have here "
                             f"(set the coefficients to 0)")
        if effects.blurred and camera.dist is not None:
            raise ValueError(f"camera {k}: motion blur is rendered on the image's own pixels, "
                             f"which a camera with lens distortion does not have here (set the "
                             f"coefficients to 0)")


def prepared_effects(effects: CameraEffects | None, rig, air: bool, distance_range):
    """The effects a boards folder renders with: None when none is on (the board of before),
    else checked against ``rig``'s cameras (:func:`check_effects`) and with a thin lens focused
    at the middle of ``distance_range`` (mm) as seen through the rig's port (:meth:`focused`)."""
    if effects is None or effects == CameraEffects():
        return None
    check_effects(effects, rig.cameras)
    return effects.focused(None if air else rig.view_port(0), 0.5 * sum(distance_range))


def thin_lens_sensor(sensor: dict, effects: CameraEffects) -> dict:
    """A pinhole sensor dict of :func:`synth.rendering.render.sensor_dict` as a Mitsuba
    ``thinlens`` of the effects' aperture and focus distance (mm)."""
    out = {k: v for k, v in sensor.items()
           if k not in ("principal_point_offset_x", "principal_point_offset_y")}
    out.update(type="thinlens", aperture_radius=effects.aperture_radius_mm,
               focus_distance=effects.focus_distance_mm)
    return out


def rolling_pixels(camera, port, points_board: np.ndarray, pose, effects: CameraEffects,
                   iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """``(uv (P, 2) px, t (P,) s)``: where ``camera`` sees board points ``(P, 3)`` (board
    frame) through ``port`` with a rolling shutter — each at the instant of the row it lands
    on (the fixed point of ``v = v(t(v))``, found by iteration; the board moves much less than
    a row per row). NaN where the forward model has no pixel or the iteration does not settle
    to 1e-6 px."""
    from measure.geometry.projection import project

    h = camera.size[1]
    still = pose.apply(points_board)
    uv = project(camera, port, still)
    for _ in range(iterations):
        t = effects.row_time(uv[:, 1], h)
        moved = project(camera, port, still + effects.board_shift(t))
        step = np.abs(moved[:, 1] - uv[:, 1])
        uv = moved
        if np.all(~(step > 1e-6)):
            break
    t = effects.row_time(uv[:, 1], h)
    settled = np.abs(project(camera, port, still + effects.board_shift(t))[:, 1] - uv[:, 1]) <= 1e-6
    return np.where(settled[:, None], uv, np.nan), np.where(settled, t, np.nan)


def row_bands(camera, port, points_board, pose, effects: CameraEffects) -> list:
    """The bands ``[(first row, end row), …]`` of a rolling-shutter view: bands of equal rows
    (the last may be shorter), as few as keep the image of ``points_board`` (the board's
    corners and outline) moving at most :data:`BAND_MOTION_PX` from a band's first row's
    instant to its last's, one row each where it moves more in a row, and at most
    :data:`MAX_BANDS` (one band without motion)."""
    from measure.geometry.projection import project

    h = camera.size[1]
    still = pose.apply(points_board)
    ends = [project(camera, port, still + effects.board_shift(t))
            for t in (-effects.readout_s / 2, effects.readout_s / 2)]
    motion = np.nanmax(np.linalg.norm(ends[1] - ends[0], axis=1)) if effects.rolling else 0.0
    per_row = SPEED_MARGIN * motion / (h - 1)  # px from one row's instant to the next
    rows = h if per_row == 0 else 1 + int(BAND_MOTION_PX / per_row)
    rows = max(rows, -(-h // MAX_BANDS))
    return [(first, min(first + rows, h)) for first in range(0, h, rows)]


def render_rolling_view(mscene, mi, view: int, camera, port, points_board, pose,
                        effects: CameraEffects, spp: int, seed: int, place):
    """One view with a rolling shutter: ``(image (H, W) float32, spp taken, stats)``. Band b of
    :func:`row_bands` is rendered on its own rows only, with the board at ``pose`` moved
    by ``place(shift)`` (a translation, mm) to where it is at the instant of the band's middle
    row, and the sampler seed of pass
    ``1 + b`` of the view (:func:`synth.rendering.render.pass_seed`, scene seed ``seed``)."""
    from synth.infra import interrupt
    from synth.rendering.integrator import render_integrator
    from synth.rendering.render import pass_seed, render_pixels

    w, h = camera.size
    bands = row_bands(camera, port, points_board, pose, effects)
    integrator = render_integrator(mi, mscene)
    image = np.zeros((h, w), np.float32)
    taken = int(spp)
    for b, (first, end) in enumerate(bands):
        interrupt.check()
        t = float(effects.row_time(0.5 * (first + end - 1), h))
        place(effects.board_shift(t))
        values, taken = render_pixels(mi, mscene, view, integrator,
                                      np.arange(first * w, end * w), spp,
                                      pass_seed(seed, view, 1 + b))
        image[first:end] = values.reshape(end - first, w)
    return image, taken, _whole_film_stats("rolling shutter", len(bands), w * h, taken)


def exposure_slices(camera, port, points_board, pose, effects: CameraEffects) -> int:
    """The slices of a motion-blurred exposure: as many as keep the image of ``points_board``
    (the board's corners and outline) moving at most :data:`SLICE_MOTION_PX` within one, at
    least 2, at most :data:`MAX_BANDS`."""
    from measure.geometry.projection import project

    still = pose.apply(points_board)
    ends = [project(camera, port, still + effects.board_shift(t))
            for t in (-effects.exposure_s / 2, effects.exposure_s / 2)]
    motion = float(np.nanmax(np.linalg.norm(ends[1] - ends[0], axis=1)))
    return int(min(MAX_BANDS, max(2, np.ceil(SPEED_MARGIN * motion / SLICE_MOTION_PX))))


def render_blurred_view(mscene, mi, view: int, camera, port, points_board, pose,
                        effects: CameraEffects, spp: int, seed: int, place):
    """One view with motion blur: ``(image (H, W) float32, spp taken, stats)``. Slice k of
    :func:`exposure_slices` renders every pixel with ``ceil(spp / slices)`` samples and the
    sampler seed of pass ``1 + k`` of the view, the board at ``pose`` moved by
    ``place(shift)`` to where it is at the slice's middle instant; the image is their mean,
    each weighted by the samples it took."""
    from synth.infra import interrupt
    from synth.rendering.integrator import render_integrator
    from synth.rendering.render import pass_seed, render_pixels

    w, h = camera.size
    slices = exposure_slices(camera, port, points_board, pose, effects)
    integrator = render_integrator(mi, mscene)
    total, weight = np.zeros(w * h, np.float64), 0
    for k in range(slices):
        interrupt.check()
        place(effects.board_shift(effects.exposure_s * ((k + 0.5) / slices - 0.5)))
        values, taken = render_pixels(mi, mscene, view, integrator, np.arange(w * h),
                                      -(-int(spp) // slices), pass_seed(seed, view, 1 + k))
        total += np.asarray(values, np.float64).ravel() * taken
        weight += taken
    return ((total / weight).astype(np.float32).reshape(h, w), weight,
            _whole_film_stats("motion blur", slices, w * h, weight))


def _whole_film_stats(mode: str, calls: int, pixels: int, spp: int) -> dict:
    """The render statistics of a view rendered on every pixel in ``calls`` render calls (bands
    of rows or slices of an exposure) with ``spp`` samples a pixel in all."""
    return {"mode": mode, "bands": calls, "film_pixels": pixels, "mask_pixels": pixels,
            "lit_fraction": None, "samples_on_mask": pixels * spp, "samples_off_mask": 0,
            "samples": pixels * spp, "spp_on_mask": spp, "spp_off_mask": spp}


def check_band_seeds(seed: int, n_poses: int, n_views: int) -> None:
    """ValueError unless every sampler seed of a rolling-shutter render fits 32 bits: band b of
    view i of pose p renders with ``seed + N·p + i + 2^21·(1 + b)``, b < ``MAX_BANDS``."""
    from synth.infra.seeds import largest_seed, render_offset

    largest = largest_seed(render_offset([MAX_BANDS + 1] * n_views, n_views * (n_poses - 1)))
    if seed > largest:
        raise ValueError(f"--seed {seed} is too large for a rolling shutter: band b of view i "
                         f"of pose p renders with seed + {n_views}p + i + 2097152*(1 + b), up to "
                         f"{MAX_BANDS} bands, and Mitsuba's sampler seed is 32-bit: the largest "
                         f"seed is {largest}")


__all__ = ["BAND_MOTION_PX", "CameraEffects", "MAX_BANDS", "SLICE_MOTION_PX", "check_band_seeds",
           "check_effects",
           "exposure_slices", "prepared_effects", "render_blurred_view", "rolling_pixels",
           "render_rolling_view", "row_bands", "thin_lens_sensor"]
