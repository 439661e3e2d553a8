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
from ..geometry.projection import project
from ..stereo.triangulate import StereoRig
from .air import Detections
from .board import Board
from .covariance import AIR_INTRINSICS, intrinsics_jacobian
from .problem import (MAX_INDEX, observations, parameter_offset, pose_left_jacobians, rows_jacobian,
                      usable_poses)

#: Free parameters of a rig of two domes: each camera's decentring (x, y, z in its own frame,
#: left then right) and the water index; and the default.
DOME_PARAMETERS = {"dome_center": 6, "n_water": 1}


def dome_offset(camera: Camera, dome: DomePort) -> np.ndarray:
    """A dome's decentring: its centre relative to the camera's centre, in the camera's frame
    (mm), ``R^T (M − C)``."""
    return camera.R.T @ (dome.center - camera.center)


def dome_problem(rig: StereoRig, board: Board, detections: Detections, names, views=(0, 1)):
    """:func:`housing_problem` of a rig of two domes (:data:`DOME_PARAMETERS`): the unknowns are
    the free dome numbers — ``dome_center``: each camera's decentring in its own frame (left
    x, y, z, then right), mm; ``n_water`` — then 6 per usable pose. Radius, thickness, glass
    index and the cameras stay at the starting rig's values. Residuals through each camera's
    own dome; the Jacobian from ``project(..., parameters=True)``'s
    :class:`measure.geometry.dome_projection.DomeParameterJacobian` (``dome_center`` turned into each
    camera's frame). ``views``: the cameras whose corners enter and whose decentring
    ``dome_center`` holds (3 numbers each; ``(0,)``: one camera inside its dome,
    :func:`measure.calibration.housing.calibrate_camera_housing`)."""
    from scipy.spatial.transform import Rotation
    views = tuple(views)
    table = parameters_of(views)
    starts, usable, detections = usable_poses(rig, board, detections)
    P = len(starts)
    n_global = sum(table[n] for n in names)
    domes0 = (rig.port.left, rig.port.right)
    corners, obs = observations(board, detections, views)
    m = sum(2 * o[1].size for o in obs)

    def unpack(x):
        offsets = [dome_offset(c, d) for c, d in zip(rig.cameras, domes0)]
        n_water = domes0[0].n_water
        k = 0
        for name in names:
            if name == "dome_center":
                for i, view in enumerate(views):
                    offsets[view] = x[k + 3 * i:k + 3 * i + 3]
            else:
                n_water = x[k]
            k += table[name]
        domes = DomePair(*(d.replace(center=c.center + c.R @ o,
                                     indices=d.indices[:-1] + (float(n_water),))
                           for c, d, o in zip(rig.cameras, domes0, offsets)))
        Rs = Rotation.from_rotvec(x[n_global:].reshape(P, 6)[:, :3]).as_matrix()
        ts = x[n_global:].reshape(P, 6)[:, 3:]
        return domes, rig.cameras, Rs, ts

    def residuals(x):
        try:
            domes, cameras, Rs, ts = unpack(x)
        except ValueError:  # e.g. a non-physical index on the way
            return np.full(m, 1e3)
        out = []
        for view, pose_idx, ids, uv in obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids]) + ts[pose_idx]
            r = (project(cameras[view], domes[view], world) - uv).ravel()
            out.append(np.where(np.isfinite(r), r, 1e3))
        return np.concatenate(out)

    def jacobian(x):
        width = n_global + 6
        try:
            domes, cameras, Rs, ts = unpack(x)
        except ValueError:
            return rows_jacobian(np.zeros((m, width)), np.zeros(m, int), n_global, x.size)
        turn = pose_left_jacobians(x[n_global:].reshape(P, 6)[:, :3])
        blocks, poses = [], []
        for view, pose_idx, ids, _ in obs:
            rotated = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids])
            _, d_points, jac = project(cameras[view], domes[view], rotated + ts[pose_idx],
                                       parameters=True)
            columns = []
            for name in names:
                if name == "dome_center":  # M = C + R·o: d pixel / d o = d pixel / d M · R
                    own = jac.dome_center @ cameras[view].R
                    columns += [own if v == view else np.zeros_like(own) for v in views]
                else:
                    columns.append(jac.indices[..., -1:])
            d_turn = np.einsum("nrj,njk->nrk", np.cross(rotated[:, None, :], d_points),
                               turn[pose_idx])
            columns += [d_turn, d_points]
            blocks.append(np.concatenate(columns, axis=-1).reshape(-1, width))
            poses.append(np.repeat(pose_idx, 2))
        return rows_jacobian(np.concatenate(blocks), np.concatenate(poses), n_global, x.size)

    def air_jacobian(x, air):
        """Dense ``(m, len(air))``: d residuals / d the in-air parameters ``air`` at ``x``, as
        :func:`housing_problem`'s. With ``dome_center`` free each dome moves with its camera
        (the unknowns are offsets in the camera's frame, ``M = C + R·o``): the right camera's
        ``rotation`` column adds ``d pixel / d M · (−[R·o]×)``, its ``center`` column
        ``d pixel / d M``; otherwise the domes stay where they are."""
        domes, cameras, Rs, ts = unpack(x)
        column = {name: j for j, name in enumerate(air)}
        follow = "dome_center" in names
        out, row = np.zeros((m, len(air))), 0
        for view, pose_idx, ids, _ in obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids]) + ts[pose_idx]
            pixels, _, jac = project(cameras[view], domes[view], world, parameters=True)
            n = 2 * pose_idx.size
            camera = ("left", "right")[view]
            d_int = intrinsics_jacobian(cameras[view], pixels).reshape(n, -1)
            for j, p in enumerate(AIR_INTRINSICS):
                if f"{camera}.{p}" in column:
                    out[row:row + n, column[f"{camera}.{p}"]] = d_int[:, j]
            if view == 1:
                rotation, center = jac.rotation, jac.center
                if follow:
                    rotation = rotation - jac.dome_center @ _skew(domes[1].center
                                                                  - cameras[1].center)
                    center = center + jac.dome_center
                for k in range(3):
                    for what, values in (("rotation", rotation), ("center", center)):
                        if f"right.{what}[{k}]" in column:
                            out[row:row + n, column[f"right.{what}[{k}]"]] = (
                                values[..., k].reshape(n))
            row += n
        return np.where(np.isfinite(out), out, 0.0)

    x0 = []
    for name in names:
        x0 += (np.concatenate([dome_offset(rig.cameras[v], domes0[v]) for v in views]).tolist()
               if name == "dome_center" else [domes0[0].n_water])
    for R, t in starts:
        x0 += list(Rotation.from_matrix(R).as_rotvec()) + list(t)
    x0 = np.asarray(x0, dtype=np.float64)
    lower = np.full(x0.size, -np.inf)
    upper = np.full(x0.size, np.inf)
    if "n_water" in names:
        k = parameter_offset(names, "n_water", table)
        lower[k], upper[k] = 1.0, MAX_INDEX
        x0[k] = np.clip(x0[k], lower[k] + 1e-9, upper[k] - 1e-9)
    return SimpleNamespace(residuals=residuals, jacobian=jacobian, unpack=unpack, x0=x0,
                           air_jacobian=air_jacobian,
                           lower=lower, upper=upper, obs=obs, usable=usable, P=P,
                           n_global=n_global, basis=(), m=m)



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




def check_free(rig: StereoRig, names) -> None:
    """Every parameter of :data:`DOME_PARAMETERS` applies to every rig of two domes."""


def estimate(name, domes, cameras, views=(0, 1)):
    """The estimate of free parameter ``name`` (:attr:`HousingCalibration.estimates`): each
    camera's decentring ``{"left": [x, y, z], …}`` of ``views``, or the water index."""
    if name == "dome_center":
        return {("left", "right")[i]: dome_offset(cameras[i], domes[i]).tolist() for i in views}
    return domes.n_water


def rig_parameters(names, air, x, basis, rig: StereoRig, port, cameras, n_global):
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
