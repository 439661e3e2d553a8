"""Dome ports in scene files: a dome around each camera of a rig (two: a
:class:`measure.geometry.dome.DomePair`; N > 2: a list of :class:`measure.geometry.dome.DomePort`,
one per camera), the check that the fields of view fit through them, and the Mitsuba spheres
that model them.

Units mm, reference frame = the left (first) camera's (OpenCV axes). A dome scene holds, per
camera (``left``, ``right``; of N > 2 cameras ``cam0``, ``cam1``, …), two concentric Mitsuba
``sphere`` shapes (analytic spheres, not meshes)
with ``dielectric`` BSDFs: ``dome_<camera>_inner`` (radius ``R``) and ``dome_<camera>_outer``
(radius ``R + T``). A Mitsuba sphere's normal points outwards and a ``dielectric``'s exterior
(``ext_ior``) is on the normal side, so with no ``flip_normals``: inner sphere ``int_ior`` = the
air's index, ``ext_ior`` = the glass's; outer sphere ``int_ior`` = the glass's, ``ext_ior`` =
``$n_water``. Inside the inner sphere is air, between the spheres glass, outside water (checked
against :func:`measure.geometry.dome.trace_through_dome` with Mitsuba's own ``ray_intersect`` and BSDF
sampling in ``tests/synth/scene/test_scene_dome.py``).
"""

from __future__ import annotations

import numpy as np

from measure import StereoRig
from measure.geometry.dome import DomePair, DomePort, trace_through_dome
from measure.stereo.rig import Rig, default_names
from synth.infra.cli import option_number

#: Defaults of ``synth scene --port dome``: inner radius and glass thickness, mm. With the
#: paper's 200 mm baseline the two outer spheres (58 mm) leave 84 mm between them, and no ray of
#: either camera's field of view (±48° across, ±55° at the corners, the right camera turned 5°)
#: reaches the other dome (:func:`check_field_of_view`).
DEFAULT_DOME_RADIUS_MM = 50.0
DEFAULT_DOME_THICKNESS_MM = 8.0
#: Smallest inner radius and glass thickness (mm) of a dome: below them a dome is no housing
#: (a lens's entrance pupil is millimetres across; glass under water pressure is millimetres
#: thick) and the sphere tracing is asked to resolve sub-micrometre shells (0.001 mm radius,
#: 1e-9 mm glass were accepted).
MIN_DOME_RADIUS_MM = 1.0
MIN_DOME_THICKNESS_MM = 0.1
#: Shape ids of the spheres: ``DOME_ID.format(camera="left", sphere="inner")``.
DOME_ID = "dome_{camera}_{sphere}"
CAMERA_NAMES = ("left", "right")
SPHERE_NAMES = ("inner", "outer")
#: Spacing (px) of the pixels whose rays :func:`check_field_of_view` traces (plus the border).
FOV_CHECK_STEP_PX = 16


def check_dome_size(radius: float, thickness: float) -> None:
    """ValueError, stating the minimum, for a dome smaller than :data:`MIN_DOME_RADIUS_MM` or
    glass thinner than :data:`MIN_DOME_THICKNESS_MM`."""
    if radius < MIN_DOME_RADIUS_MM:
        raise ValueError(f"dome radius {option_number(radius)} mm is below the minimum of "
                         f"{MIN_DOME_RADIUS_MM:g} mm (a dome housing is tens of mm across)")
    if thickness < MIN_DOME_THICKNESS_MM:
        raise ValueError(f"dome thickness {option_number(thickness)} mm is below the minimum of "
                         f"{MIN_DOME_THICKNESS_MM:g} mm (the glass of a dome port is mm thick)")


def camera_domes(cameras, radius: float, thickness: float, offset, indices) -> list:
    """A dome around each camera: its centre ``offset`` (mm, in that camera's frame) from the
    camera's centre — the same offset for every camera; ``indices`` ``(n_air, n_glass,
    n_water)``. Raises ``ValueError`` for a radius or thickness below the minimum, a camera
    outside its own dome or inside another's glass (:class:`measure.stereo.rig.Rig`;
    two cameras: :func:`dome_pair`)."""
    check_dome_size(radius, thickness)
    offset = np.asarray(offset, dtype=np.float64).reshape(3)
    domes = [DomePort(cam.center + cam.R @ offset, radius, thickness, indices) for cam in cameras]
    if len(domes) > 2:
        Rig(cameras, domes)  # each camera inside its dome, none in another's glass
    return domes


def dome_pair(cameras, radius: float, thickness: float, offset, indices) -> DomePair:
    """The two domes of a rig (:func:`camera_domes` of its two cameras) as a DomePair. Raises
    ``ValueError`` for a radius or thickness that is not positive, or a camera outside its
    dome."""
    pair = DomePair(*camera_domes(cameras[:2], radius, thickness, offset, indices))
    StereoRig(cameras[0], cameras[1], pair)  # each camera inside its dome
    return pair


def named_domes(port) -> list:
    """``[(camera name, DomePort), …]`` of a DomePair (``left``, ``right``) or of a list of one
    DomePort per camera (``cam0``, ``cam1``, …; :func:`measure.stereo.rig.default_names`)."""
    if isinstance(port, (list, tuple)):
        return list(zip(default_names(len(port)), port))
    return list(zip(CAMERA_NAMES, (port.left, port.right)))


def rig_domes(rig) -> list:
    """``[(camera name, DomePort), …]`` of a rig whose cameras are each inside their own dome:
    a StereoRig with a DomePair or a Rig of DomePorts; ``ValueError`` for any other."""
    names = getattr(rig, "names", CAMERA_NAMES)
    domes = [rig.view_port(k) for k in range(len(rig.cameras))]
    if any(getattr(d, "kind", None) != "dome" for d in domes):
        raise ValueError("check_field_of_view needs a rig of cameras each inside its own dome")
    return list(zip(names, domes))


def _overlap_text(names, i: int, j: int) -> str:
    return "the two domes" if len(names) == 2 else f"the {names[i]} and {names[j]} domes"


def check_field_of_view(rig, step_px: int = FOV_CHECK_STEP_PX) -> None:
    """Raise ``ValueError`` unless each camera's whole field of view fits through its own dome
    and misses every other camera's dome.

    ``rig``: a StereoRig with a DomePair, or a Rig of one DomePort per camera. The rays of
    a grid of pixels (every ``step_px`` and the image border) are traced through the camera's
    dome (:func:`measure.geometry.dome.trace_through_dome`); each must reach the water (no
    total internal reflection) and its water ray must not meet another dome's outer sphere.
    No two domes may overlap.
    """
    named = rig_domes(rig)
    names = [name for name, _ in named]
    domes = [dome for _, dome in named]
    for i in range(len(domes)):
        for j in range(i + 1, len(domes)):
            gap = (np.linalg.norm(domes[i].center - domes[j].center) - domes[i].radii[1]
                   - domes[j].radii[1])
            if gap <= 0:
                raise ValueError(f"{_overlap_text(names, i, j)} overlap (their outer spheres are "
                                 f"{-gap:.6g} mm into each other): move the cameras apart or "
                                 f"make the domes smaller")
    for view, camera in enumerate(rig.cameras):
        name = names[view]
        w, h = camera.size
        # pixel centres every step_px and the image's outer edges (OpenCV: [-0.5, W - 0.5])
        u, v = np.meshgrid(np.r_[-0.5, np.arange(0, w, step_px), w - 0.5],
                           np.r_[-0.5, np.arange(0, h, step_px), h - 0.5])
        uv = np.column_stack([u.ravel(), v.ravel()])
        water = trace_through_dome(camera.center, camera.rays(uv), domes[view],
                                   keep_interface_points=False)
        lost = ~np.all(np.isfinite(water.directions), axis=1)
        if lost.any():
            worst = uv[np.flatnonzero(lost)[0]]
            raise ValueError(f"the {name} camera's field of view does not fit through its dome "
                             f"(the ray of pixel ({worst[0]:g}, {worst[1]:g}) does not reach "
                             f"the water)")
        for other_view, other in enumerate(domes):
            if other_view == view:
                continue
            hits = _ray_meets_sphere(water.origins, water.directions, other.center,
                                     other.radii[1])
            if hits.any():
                worst = uv[np.flatnonzero(hits)[0]]
                raise ValueError(f"the {name} camera's field of view reaches the "
                                 f"{names[other_view]} dome (the ray of pixel ({worst[0]:g}, "
                                 f"{worst[1]:g})): the field of view does not fit past it; move "
                                 f"the cameras apart or make the domes smaller")


def _ray_meets_sphere(origins, directions, center, radius) -> np.ndarray:
    """Whether rays ``(N, 3)`` (unit directions) meet a sphere ahead of their origins."""
    offset = origins - center
    b = np.einsum("ij,ij->i", offset, directions)
    c = np.einsum("ij,ij->i", offset, offset) - radius * radius
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        far = -b + np.sqrt(disc)
    return (disc >= 0) & (far > 0)


def check_targets(port, targets, target_radius: float) -> None:
    """Raise ``ValueError`` unless every target ``(N, 3)`` (mm) lies in the water, at least its
    radius outside every dome's outer sphere (a target inside a dome or in its glass is
    refused); ``port`` a DomePair or a list of one DomePort per camera."""
    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
    for name, dome in named_domes(port):
        distance = np.linalg.norm(targets - dome.center, axis=1)
        inside = distance <= dome.radii[1]
        if inside.any():
            where = "inside the dome" if distance[inside].min() < dome.radius else "in the glass"
            raise ValueError(f"targets {np.flatnonzero(inside)[:5].tolist()} lie inside the "
                             f"{name} dome's outer sphere ({where}); every target must be in "
                             f"the water")
        if np.any(distance - dome.radii[1] <= target_radius):
            raise ValueError(f"targets closer to the {name} dome than their radius")


def facing_cameras(cameras, targets, normals) -> np.ndarray:
    """Whether each target's normal ``(N, 3)`` points back towards the cameras (negative dot
    product with the direction from the mean of the camera centres — of two cameras their
    midpoint — to the target)."""
    middle = np.mean([camera.center for camera in cameras], axis=0)
    return np.einsum("ij,ij->i", np.asarray(normals, float), np.asarray(targets, float) - middle) < 0


def dome_placements(port):
    """Per sphere of a DomePair or a list of one DomePort per camera (:func:`named_domes`),
    first camera's dome first, inner sphere first: ``(shape id, centre, radius, ext_ior,
    int_ior)``; the outer sphere's ``ext_ior`` is the water's index."""
    for camera, dome in named_domes(port):
        n_air, n_glass, n_water = dome.indices
        yield DOME_ID.format(camera=camera, sphere="inner"), dome.center, dome.radii[0], \
            n_glass, n_air
        yield DOME_ID.format(camera=camera, sphere="outer"), dome.center, dome.radii[1], \
            n_water, n_glass


def sphere_xml(sid: str, centre, radius: float, ext_ior: float, int_ior: float,
               outer: bool) -> str:
    """The XML of one dome sphere (mm): ``outer`` its ``ext_ior`` is ``$n_water``."""
    from synth.scene.xml_text import number_text, vector_text

    return f"""    <shape type="sphere" id="{sid}">
        <point name="center" value="{vector_text(centre)}"/>
        <float name="radius" value="{number_text(radius)}"/>
        <bsdf type="dielectric">
            <float name="ext_ior" value="{'$n_water' if outer else number_text(ext_ior)}"/>
            <float name="int_ior" value="{number_text(int_ior)}"/>
        </bsdf>
    </shape>"""


def pair_from_spheres(spheres: dict) -> DomePair:
    """The DomePair of a scene's spheres (:func:`domes_from_spheres` of ``left``, ``right``)."""
    return DomePair(*domes_from_spheres(spheres, CAMERA_NAMES))


def domes_from_spheres(spheres: dict, names) -> list:
    """The domes of cameras ``names`` (in order) from a scene's spheres: ``{shape id: (centre,
    radius, ext_ior, int_ior)}`` with the two ids of :data:`DOME_ID` per camera. Raises
    ``ValueError`` naming what does not fit (a missing sphere, spheres that are not concentric,
    an outer sphere not larger than the inner one, indices that do not chain air → glass →
    water, domes in different water)."""
    domes = []
    known = [DOME_ID.format(camera=c, sphere=s) for c in names for s in SPHERE_NAMES]
    every = ", ".join(known) if len(names) == 2 else f"{known[0]}, … {known[-1]}"
    extra = sorted(set(spheres) - set(known))
    if extra:
        raise ValueError(f"sphere {extra[0]!r} is not a dome sphere (a dome scene holds {every})")
    for camera in names:
        ids = [DOME_ID.format(camera=camera, sphere=s) for s in SPHERE_NAMES]
        missing = [i for i in ids if i not in spheres]
        if missing:
            raise ValueError(f"dome sphere {missing[0]!r} is missing (a dome scene holds "
                             f"{every})")
        (c_in, r_in, ext_in, int_in), (c_out, r_out, ext_out, int_out) = (spheres[i] for i in ids)
        if not np.allclose(c_in, c_out, rtol=0, atol=1e-9):
            raise ValueError(f"spheres {ids[0]!r} and {ids[1]!r} are not concentric")
        if not r_out > r_in:
            raise ValueError(f"sphere {ids[1]!r} (radius {r_out:g}) must be larger than "
                             f"{ids[0]!r} (radius {r_in:g})")
        check_dome_size(r_in, r_out - r_in)
        if abs(ext_in - int_out) > 1e-9:
            raise ValueError(f"the glass of the {camera} dome has two indices: ext_ior "
                             f"{ext_in:g} of {ids[0]!r}, int_ior {int_out:g} of {ids[1]!r}")
        domes.append(DomePort(c_in, r_in, r_out - r_in, (int_in, ext_in, ext_out)))
    waters = [d.n_water for d in domes]
    if max(waters) - min(waters) > 1e-12:
        what = "the two domes are" if len(domes) == 2 else "the domes are"
        raise ValueError(f"{what} in different water (ext_ior "
                         f"{' and '.join(f'{n:g}' for n in waters)})")
    return domes


__all__ = ["CAMERA_NAMES", "DEFAULT_DOME_RADIUS_MM", "DEFAULT_DOME_THICKNESS_MM", "DOME_ID",
           "FOV_CHECK_STEP_PX", "camera_domes", "check_field_of_view", "check_targets",
           "dome_pair", "dome_placements", "domes_from_spheres", "facing_cameras", "named_domes",
           "pair_from_spheres", "rig_domes", "sphere_xml"]
