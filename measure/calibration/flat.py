"""The housing problem of a flat port (:func:`housing_problem`): its free parameters
(:data:`HOUSING_PARAMETERS`), residuals and analytic Jacobian, and the free numbers as
:mod:`measure.stereo.rig_covariance` names (:func:`flat_rig_parameters`)."""

from __future__ import annotations

from functools import partial
from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.camera import Camera
from ..geometry.port import FlatPort
from ..geometry.projection import project
from ..stereo.triangulate import StereoRig
from .air import CalibrationError, Detections
from .board import Board
from .covariance import AIR_INTRINSICS, intrinsics_jacobian, left_jacobian
from .problem import (MAX_INDEX, MIN_LENGTH_MM, observations, parameter_offset, pose_left_jacobians,
                      rows_jacobian, usable_poses)
from .selfcal import tilt_basis

#: Free housing parameters and how many numbers each is.
HOUSING_PARAMETERS = {"distance": 1, "normal": 2, "thickness": 1, "n_water": 1, "extrinsics": 6}


def housing_problem(rig: StereoRig, board: Board, detections: Detections, names,
                    views=(0, 1)):
    """The bundle adjustment of :func:`calibrate_housing` as functions of the unknowns ``x``
    (free housing numbers, then 6 per usable pose): ``residuals``, its analytic ``jacobian``,
    ``unpack``, the start ``x0`` and its ``lower`` / ``upper`` bounds, and the bookkeeping.
    ``views``: the cameras whose corners enter (``(0,)``: one camera behind its port,
    :func:`measure.calibration.housing.calibrate_camera_housing`)."""
    starts, usable, detections = usable_poses(rig, board, detections)
    P = len(starts)
    n_global = sum(HOUSING_PARAMETERS[n] for n in names)
    port0, basis = rig.port, tilt_basis(rig.port.normal)
    corners, obs = observations(board, detections, views)
    m = sum(2 * o[1].size for o in obs)

    def unpack(x):
        indices, thick, distance = list(port0.indices), list(port0.thicknesses), port0.distance
        normal, right = port0.normal, rig.right
        k = 0
        for name in names:
            if name == "distance":
                distance = x[k]
            elif name == "normal":
                normal = port0.normal + x[k] * basis[0] + x[k + 1] * basis[1]
            elif name == "thickness":
                thick[0] = x[k]
            elif name == "n_water":
                indices[-1] = x[k]
            elif name == "extrinsics":
                dR = Rotation.from_rotvec(x[k:k + 3]).as_matrix()
                right = Camera(rig.right.K, rig.right.size, rig.right.dist,
                               dR @ rig.right.R, rig.right.t + x[k + 3:k + 6])
            k += HOUSING_PARAMETERS[name]
        port = FlatPort(normal, distance, tuple(thick), tuple(indices))
        Rs = Rotation.from_rotvec(x[n_global:].reshape(P, 6)[:, :3]).as_matrix()
        ts = x[n_global:].reshape(P, 6)[:, 3:]
        return port, (rig.left, right), Rs, ts

    def residuals(x):
        try:
            port, cameras, Rs, ts = unpack(x)
        except ValueError:  # e.g. a non-physical index or thickness on the way
            return np.full(m, 1e3)
        out = []
        for view, pose_idx, ids, uv in obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids]) + ts[pose_idx]
            r = (project(cameras[view], port, world) - uv).ravel()
            out.append(np.where(np.isfinite(r), r, 1e3))
        return np.concatenate(out)

    def jacobian(x):
        """Analytic (:func:`measure.geometry.projection.project` with ``parameters=True``): a row touches
        the free housing numbers and its pose's 6 columns (rotation vector, translation)."""
        width = n_global + 6
        try:
            port, cameras, Rs, ts = unpack(x)
        except ValueError:  # the residuals are constant there
            return rows_jacobian(np.zeros((m, width)), np.zeros(m, int), n_global, x.size)
        turn = pose_left_jacobians(x[n_global:].reshape(P, 6)[:, :3])
        blocks, poses = [], []
        for view, pose_idx, ids, _ in obs:
            rotated = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids])
            _, d_points, jac = project(cameras[view], port, rotated + ts[pose_idx],
                                       parameters=True)
            columns = []
            for name in names:
                if name == "distance":
                    columns.append(jac.distance[..., None])
                elif name == "normal":  # normal = m / |m|, m = N0 + a·x_a + b·x_b
                    k = parameter_offset(names, name, HOUSING_PARAMETERS)
                    length = np.linalg.norm(port0.normal + x[k] * basis[0] + x[k + 1] * basis[1])
                    columns.append(np.stack([jac.normal @ axis / length for axis in basis], -1))
                elif name == "thickness":
                    columns.append(jac.thicknesses[..., :1])
                elif name == "n_water":
                    columns.append(jac.indices[..., -1:])
                elif view == 1:  # the right camera: R = exp(ω) R0, t = t0 + δt
                    k = parameter_offset(names, name, HOUSING_PARAMETERS)
                    columns.append(jac.rotation @ pose_left_jacobians(x[None, k:k + 3])[0])
                    columns.append(jac.center)
                else:
                    columns.append(np.zeros(d_points.shape[:2] + (6,)))
            # a pose: X = exp(ω) c + t, so dX/dω = −[R c]× J_l(ω) and dX/dt = I
            d_turn = np.einsum("nrj,njk->nrk", np.cross(rotated[:, None, :], d_points),
                               turn[pose_idx])
            columns += [d_turn, d_points]
            blocks.append(np.concatenate(columns, axis=-1).reshape(-1, width))
            poses.append(np.repeat(pose_idx, 2))
        return rows_jacobian(np.concatenate(blocks), np.concatenate(poses), n_global, x.size)

    def air_jacobian(x, air):
        """Dense ``(m, len(air))``: d residuals / d the in-air parameters ``air`` (names of
        :data:`measure.calibration.covariance.AIR_NAMES`) at ``x`` (module docs of
        :mod:`measure.calibration.covariance`)."""
        port, cameras, Rs, ts = unpack(x)
        column = {name: j for j, name in enumerate(air)}
        out, row = np.zeros((m, len(air))), 0
        for view, pose_idx, ids, _ in obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids]) + ts[pose_idx]
            pixels, _, jac = project(cameras[view], port, world, parameters=True)
            n = 2 * pose_idx.size
            camera = ("left", "right")[view]
            d_int = intrinsics_jacobian(cameras[view], pixels).reshape(n, -1)
            for j, p in enumerate(AIR_INTRINSICS):
                if f"{camera}.{p}" in column:
                    out[row:row + n, column[f"{camera}.{p}"]] = d_int[:, j]
            if view == 1:
                for k in range(3):
                    for what, values in (("rotation", jac.rotation), ("center", jac.center)):
                        if f"right.{what}[{k}]" in column:
                            out[row:row + n, column[f"right.{what}[{k}]"]] = (
                                values[..., k].reshape(n))
            row += n
        return np.where(np.isfinite(out), out, 0.0)

    x0 = []
    for name in names:
        x0 += {"distance": [port0.distance], "normal": [0.0, 0.0],
               "thickness": list(port0.thicknesses[:1]), "n_water": [port0.n_water],
               "extrinsics": [0.0] * 6}[name]
    for R, t in starts:
        x0 += list(Rotation.from_matrix(R).as_rotvec()) + list(t)
    x0 = np.asarray(x0, dtype=np.float64)
    lower = np.full(x0.size, -np.inf)
    upper = np.full(x0.size, np.inf)
    k = 0
    for name in names:  # keep the port physical on the way: a layer, indices >= 1
        if name in ("distance", "thickness"):
            lower[k] = MIN_LENGTH_MM
        elif name == "n_water":
            lower[k], upper[k] = 1.0, MAX_INDEX
        k += HOUSING_PARAMETERS[name]
    x0[:n_global] = np.clip(x0[:n_global], lower[:n_global] + 1e-9, upper[:n_global] - 1e-9)
    return SimpleNamespace(residuals=residuals, jacobian=jacobian, unpack=unpack, x0=x0,
                           air_jacobian=air_jacobian,
                           lower=lower, upper=upper, obs=obs, usable=usable, P=P,
                           n_global=n_global, basis=basis, m=m)



def flat_rig_parameters(names, x, basis, start_normal, port, n_global):
    """The housing's free numbers as :mod:`measure.stereo.rig_covariance` names, the ``(g, g)``
    Jacobian of those parameters with respect to the free numbers at ``x``, and the tilt axes
    (⟂ the estimated normal; None without a free normal)."""
    out, T, axes, k = [], np.zeros((n_global, n_global)), None, 0
    for name in names:
        if name == "distance":
            out.append("port.distance")
            T[k, k] = 1.0
        elif name == "normal":  # n = m/|m|, m = n0 + a e0 + b e1; new tilts about axes ⟂ n
            m = start_normal + basis[0] * x[k] + basis[1] * x[k + 1]
            length = np.linalg.norm(m)
            n = m / length
            axes = np.array(tilt_basis(n))
            T[k:k + 2, k:k + 2] = axes @ (np.eye(3) - np.outer(n, n)) @ np.array(basis).T / length
            out += ["port.tilt[0]", "port.tilt[1]"]
        elif name == "thickness":
            out.append("port.thickness[0]")
            T[k, k] = 1.0
        elif name == "n_water":
            out.append(f"port.index[{len(port.indices) - 1}]")
            T[k, k] = 1.0
        else:  # R = exp(ω) R0: φ = J_l(ω) δω; the centre t = t0 + δt
            out += [f"right.rotation[{i}]" for i in range(3)]
            out += [f"right.center[{i}]" for i in range(3)]
            T[k:k + 3, k:k + 3] = left_jacobian(x[k:k + 3])
            T[k + 3:k + 6, k + 3:k + 6] = np.eye(3)
        k += HOUSING_PARAMETERS[name]
    return tuple(out), T, axes




def check_free(rig: StereoRig, names) -> None:
    """CalibrationError for a free parameter this port does not have."""
    if "thickness" in names and not rig.port.thicknesses:
        raise CalibrationError("--free thickness: the port has no glass layer")


def for_views(views):
    """The flat port's housing calibration from the corners of the cameras ``views`` only:
    ``(0,)`` is one camera behind its port (no second camera, so no ``extrinsics``)."""
    views = tuple(views)
    if views == (0, 1):
        return FLAT_HOUSING
    table = {n: w for n, w in HOUSING_PARAMETERS.items() if n != "extrinsics"}
    return SimpleNamespace(parameters=table, default_free=FLAT_HOUSING.default_free,
                           label="of one camera ", check_free=check_free,
                           problem=partial(housing_problem, views=views),
                           rig_parameters=rig_parameters, views=views, for_views=for_views)


def rig_parameters(names, air, x, basis, rig: StereoRig, port, cameras, n_global):
    """:func:`flat_rig_parameters` as the ``(a + g, a + g)`` Jacobian of (in-air parameters
    ``air``, the names) with respect to (``air``, the free numbers)."""
    a = len(air)
    rig_names, transform, axes = flat_rig_parameters(names, x, basis, rig.port.normal, port,
                                                     n_global)
    T = np.eye(a + n_global)
    T[a:, a:] = transform
    return rig_names, T, axes


#: The flat port's housing calibration (:data:`measure.calibration.housing.HOUSINGS`).
FLAT_HOUSING = SimpleNamespace(parameters=HOUSING_PARAMETERS, default_free=("distance", "normal"),
                               label="", check_free=check_free, problem=housing_problem,
                               rig_parameters=rig_parameters, views=(0, 1),
                               for_views=for_views)
