"""The housing problem of a rig of two domes (:func:`dome_problem`): each camera's decentring
(:func:`dome_offset`) and the water index (:data:`DOME_PARAMETERS`), residuals through each
camera's own dome, the analytic Jacobian, and the free numbers as
:mod:`measure.stereo.rig_covariance` names (:func:`dome_rig_parameters`)."""

from __future__ import annotations

from functools import partial
from types import SimpleNamespace

import numpy as np

from ..geometry.camera import Camera
from ..geometry.dome import DomePair, DomePort
from ..stereo.rig import Rig
from .air import Detections
from .board import Board
from .problem import MAX_INDEX, HousingProblem, parameter_offset

#: Free parameters of a rig of two domes: each camera's decentring (x, y, z in its own frame,
#: left then right) and the water index; and the default.
DOME_PARAMETERS = {"dome_center": 6, "n_water": 1}


def dome_offset(camera: Camera, dome: DomePort) -> np.ndarray:
    """A dome's decentring: its centre relative to the camera's centre, in the camera's frame
    (mm), ``R^T (M − C)``."""
    return camera.R.T @ (dome.center - camera.center)


def dome_problem(rig: Rig, board: Board, detections: Detections, names, views=(0, 1)):
    """:func:`housing_problem` of a rig of two domes (:data:`DOME_PARAMETERS`): the unknowns are
    the free dome numbers — ``dome_center``: each camera's decentring in its own frame (left
    x, y, z, then right), mm; ``n_water`` — then 6 per usable pose. Radius, thickness, glass
    index and the cameras stay at the starting rig's values. Residuals through each camera's
    own dome; the Jacobian from ``project(..., parameters=True)``'s
    :class:`measure.geometry.dome_projection.DomeParameterJacobian` (``dome_center`` turned into each
    camera's frame). ``views``: the cameras whose corners enter and whose decentring
    ``dome_center`` holds (3 numbers each; ``(0,)``: one camera inside its dome,
    :func:`measure.calibration.housing.calibrate_camera_housing`)."""
    return _DomeHousingProblem(rig, board, detections, names, tuple(views))


class _DomeHousingProblem(HousingProblem):
    """:func:`dome_problem`: the free dome numbers are ``dome_center`` (3 per camera of
    ``views``, mm in each camera's frame) and ``n_water``."""

    def __init__(self, rig, board, detections, names, views):
        super().__init__(rig, board, detections, names, views, parameters_of(views))
        self.domes0 = (rig.port.left, rig.port.right)
        self.x0, self.lower, self.upper = self._start()
        self.basis = ()

    def _start(self):
        """``(x0, lower, upper)``: the starting rig's decentrings and water, the poses' starts;
        the water index kept in [1, :data:`MAX_INDEX`]."""
        rig, domes0, names = self.rig, self.domes0, self.names
        x0 = []
        for name in names:
            x0 += (np.concatenate([dome_offset(rig.cameras[v], domes0[v])
                                   for v in self.views]).tolist()
                   if name == "dome_center" else [domes0[0].n_water])
        x0 = np.asarray(x0 + self.start_poses(), dtype=np.float64)
        lower = np.full(x0.size, -np.inf)
        upper = np.full(x0.size, np.inf)
        if "n_water" in names:
            k = parameter_offset(names, "n_water", self.table)
            lower[k], upper[k] = 1.0, MAX_INDEX
            x0[k] = np.clip(x0[k], lower[k] + 1e-9, upper[k] - 1e-9)
        return x0, lower, upper

    def unpack(self, x):
        """``(domes, cameras, Rs, ts)`` at ``x``: each dome moved with its camera's offset."""
        rig, domes0 = self.rig, self.domes0
        offsets = [dome_offset(c, d) for c, d in zip(rig.cameras, domes0)]
        n_water = domes0[0].n_water
        k = 0
        for name in self.names:
            if name == "dome_center":
                for i, view in enumerate(self.views):
                    offsets[view] = x[k + 3 * i:k + 3 * i + 3]
            else:
                n_water = x[k]
            k += self.table[name]
        domes = DomePair(*(d.replace(center=c.center + c.R @ o,
                                     indices=d.indices[:-1] + (float(n_water),))
                           for c, d, o in zip(rig.cameras, domes0, offsets)))
        return (domes, rig.cameras, *self.poses(x))

    def housing_columns(self, x, name, view, jac, d_points, cameras) -> list:
        if name == "dome_center":  # M = C + R·o: d pixel / d o = d pixel / d M · R
            own = jac.dome_center @ cameras[view].R
            return [own if v == view else np.zeros_like(own) for v in self.views]
        return [jac.indices[..., -1:]]

    def right_pose_columns(self, jac, housing, cameras) -> tuple:
        """With ``dome_center`` free each dome moves with its camera (the unknowns are offsets
        in the camera's frame, ``M = C + R·o``): the right camera's ``rotation`` column adds
        ``d pixel / d M · (−[R·o]×)``, its ``center`` column ``d pixel / d M``; otherwise the
        domes stay where they are."""
        rotation, center = jac.rotation, jac.center
        if "dome_center" in self.names:
            rotation = rotation - jac.dome_center @ _skew(housing[1].center - cameras[1].center)
            center = center + jac.dome_center
        return rotation, center



def parameters_of(views) -> dict:
    """:data:`DOME_PARAMETERS` of the cameras ``views``: 3 decentring numbers per camera."""
    return {"dome_center": 3 * len(tuple(views)), "n_water": 1}


def dome_rig_parameters(names, air, cameras, domes, views=(0, 1)):
    """The dome calibration's free numbers as :mod:`measure.stereo.rig_covariance` names —
    ``left/right.dome_center[0..2]`` (each dome's centre in the reference frame, mm) and
    ``port.index[2]`` — and the ``(a + g, a + g)`` Jacobian of (in-air parameters ``air``,
    those names) with respect to (``air``, the free numbers): ``M = C + R·o`` with ``o`` the
    decentring in the camera's frame, so ``δM = R·δo`` and, for the right camera,
    ``+ δC − [R·o]× φ`` where its pose is among ``air``. No tilt axes (None)."""
    a = len(air)
    out = []
    g = sum(parameters_of(views)[n] for n in names)
    T = np.zeros((a + g, a + g))
    T[:a, :a] = np.eye(a)
    k = a
    for name in names:
        if name == "dome_center":
            for view in views:
                camera, R = ("left", "right")[view], cameras[view].R
                T[k:k + 3, k:k + 3] = R
                if view == 1:
                    lever = -_skew(domes[1].center - cameras[1].center)
                    for i in range(3):
                        if f"right.rotation[{i}]" in air:
                            T[k:k + 3, air.index(f"right.rotation[{i}]")] = lever[:, i]
                        if f"right.center[{i}]" in air:
                            T[k + i, air.index(f"right.center[{i}]")] = 1.0
                out += [f"{camera}.dome_center[{i}]" for i in range(3)]
                k += 3
        else:
            out.append(f"port.index[{len(domes.left.indices) - 1}]")
            T[k, k] = 1.0
            k += 1
    return tuple(out), T, None


def _skew(v) -> np.ndarray:
    """``[v]×`` ``(3, 3)``: ``[v]× w = v × w``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])




def check_free(rig: Rig, names) -> None:
    """Every parameter of :data:`DOME_PARAMETERS` applies to every rig of two domes."""


def estimate(name, domes, cameras, views=(0, 1)):
    """The estimate of free parameter ``name`` (:attr:`HousingCalibration.estimates`): each
    camera's decentring ``{"left": [x, y, z], …}`` of ``views``, or the water index."""
    if name == "dome_center":
        return {("left", "right")[i]: dome_offset(cameras[i], domes[i]).tolist() for i in views}
    return domes.n_water


def rig_parameters(names, air, x, basis, rig: Rig, port, cameras, n_global):
    """:func:`dome_rig_parameters` (the housing calibration's common signature)."""
    return dome_rig_parameters(names, air, cameras, port)


def for_views(views):
    """The domes' housing calibration from the corners of the cameras ``views`` only: ``(0,)``
    is one camera inside its dome (``dome_center``: its decentring, 3 numbers)."""
    views = tuple(views)
    if views == (0, 1):
        return DOME_HOUSING

    def rig_parameters_of_views(names, air, x, basis, rig, port, cameras, n_global):
        return dome_rig_parameters(names, air, cameras, port, views)

    return SimpleNamespace(parameters=parameters_of(views), default_free=("dome_center",),
                           label="of one dome ", check_free=check_free,
                           problem=partial(dome_problem, views=views),
                           rig_parameters=rig_parameters_of_views,
                           estimate=partial(estimate, views=views), views=views,
                           for_views=for_views)


#: The domes' housing calibration (:data:`measure.calibration.housing.HOUSINGS`).
DOME_HOUSING = SimpleNamespace(parameters=DOME_PARAMETERS, default_free=("dome_center",),
                               label="of two domes ", check_free=check_free, problem=dome_problem,
                               rig_parameters=rig_parameters, estimate=estimate, views=(0, 1),
                               for_views=for_views)
