"""The housing of a rig of N cameras behind one shared flat port, from board corners under water.

The cameras stay as calibrated in air (:func:`measure.calibration.multi_air.calibrate_rig_in_air`:
every camera's intrinsics and pose); the unknowns are every board pose (6 each) and the free
port parameters (:data:`PARAMETERS`): ``distance`` (D, mm, the first interface ``N·X = D`` in
the reference frame), ``normal`` (2 tilts, rad, about axes ⟂ the starting normal),
``thickness`` (the first layer, mm) and ``n_water``. Residuals: every detected corner of every
camera reprojected through the port with the exact forward model
(:func:`measure.geometry.projection.project`), px; ``scipy.optimize.least_squares`` with the
analytic Jacobian (``project(..., parameters=True)``) in its sparse structure (a pose's 6
columns touch only its own corners' rows). Starting board poses: ``cv2.solvePnP`` on the
refracted corners of the first camera that found the board, with its in-air intrinsics.

σ: ``s² (JᵀJ)⁻¹`` (``s² = Σr² / (m − n)``, conditional on the in-air calibration) and, given
the in-air calibration's covariance (its ``parameter_names`` and ``covariance``), that
covariance propagated through the fit: ``Σ = s²(JᵀJ)⁻¹ + G Σ_air Gᵀ`` with ``G = (JᵀJ)⁻¹ Jᵀ
J_air``; ``J_air`` (d residuals / d the in-air camera parameters) by central differences of
the same residuals. Units mm, px, rad; the reference frame is the first camera's.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ..geometry.camera import Camera
from ..geometry.port import FlatPort, require_flat_port
from ..geometry.projection import project
from ..stereo.multirig import MultiRig
from .air import CalibrationError, Detections
from .board import Board
from .multi_air import DISTORTION_NAMES, INTRINSIC_NAMES
from .problem import (MAX_INDEX, MIN_LENGTH_MM, observations, pose_left_jacobians, rows_jacobian,
                      usable_poses)
from .selfcal import tilt_basis

#: The free port parameters and how many numbers each is.
PARAMETERS = {"distance": 1, "normal": 2, "thickness": 1, "n_water": 1}
DEFAULT_FREE = ("distance", "normal")
#: Central-difference steps of the in-air parameters (rad, mm, px, distortion units).
STEPS = {"rotation": 1e-6, "center": 1e-4, "f": 1e-3, "c": 1e-3, "dist": 1e-6}


@dataclass(frozen=True)
class MultiHousingCalibration:
    """``rig`` (the in-air cameras behind the calibrated shared port), ``estimates``
    ``{distance, normal (unit 3-vector), thickness, n_water}`` of the free ones, ``sigmas``
    (distance mm, normal: its two tilts rad, thickness mm, n_water) with the in-air covariance
    propagated when one was given, ``sigmas_conditional`` without, ``labels`` of the free
    numbers, ``covariance`` of those numbers, ``normal_axes`` the tilt axes, ``rms_px`` (all
    corners, residual length) and ``rms_px_per`` per camera, ``poses`` ``{pose: (R, t)}``
    (board to reference), ``n_observations`` corners, ``uncertainty`` (``propagate`` or
    ``conditional``)."""

    rig: MultiRig
    estimates: dict
    sigmas: dict
    sigmas_conditional: dict
    labels: tuple
    covariance: np.ndarray
    normal_axes: tuple
    rms_px: float
    rms_px_per: dict
    poses: dict
    n_observations: int
    uncertainty: str


def _camera_moved(camera: Camera, name: str, step: float) -> Camera:
    """``camera`` with one in-air parameter (``rotation[k]``, ``center[k]``, ``fx`` … ``cy``,
    a distortion coefficient) moved by ``step``."""
    K, dist, R, t = camera.K.copy(), np.array(camera.dist, dtype=float), camera.R, camera.t.copy()
    if name.startswith("rotation["):
        axis = np.zeros(3)
        axis[int(name[9])] = step
        R = Rotation.from_rotvec(axis).as_matrix() @ R
    elif name.startswith("center["):
        t[int(name[7])] += step
    elif name in INTRINSIC_NAMES:
        r, c = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[name]
        K[r, c] += step
    else:
        dist[DISTORTION_NAMES.index(name)] += step
    return Camera(K, camera.size, dist, R, t)


def _step(name: str) -> float:
    if name.startswith(("rotation", "center")):
        return STEPS[name.split("[")[0]]
    if name in INTRINSIC_NAMES:
        return STEPS[name[0]]
    return STEPS["dist"]


def calibrate_rig_housing(rig: MultiRig, board: Board, detections: Detections, free=DEFAULT_FREE,
                          air_names=(), air_covariance=None) -> MultiHousingCalibration:
    """The shared flat port of ``rig`` (its cameras in air, every camera's port the starting
    one: the design values) from the corners ``detections`` (``ids[k][v]`` for pose k, camera
    v) of ``board`` (module docs). ``air_names``, ``air_covariance``: the in-air calibration's
    (:class:`measure.calibration.multi_air.MultiAirCalibration`), propagated into σ.
    CalibrationError (one line) for a rig that is not behind one shared flat port, unknown free
    parameters, too few boards, or a fit that does not determine them."""
    message = "the housing calibration of N cameras models one flat port that every camera shares"
    try:
        port0 = require_flat_port(rig.ports[0], message)
    except ValueError as exc:
        raise CalibrationError(str(exc)) from None
    if any(p != port0 for p in rig.ports):
        raise CalibrationError(message)
    names = tuple(dict.fromkeys(free))
    unknown = [n for n in names if n not in PARAMETERS]
    if not names or unknown:
        raise CalibrationError(f"--free {','.join(free) or '(nothing)'}: the housing calibration "
                               f"of N cameras estimates {', '.join(PARAMETERS)}")
    if "thickness" in names and not port0.thicknesses:
        raise CalibrationError("--free thickness: the port has no glass layer")
    cameras = rig.cameras
    views = tuple(range(len(cameras)))
    start_rig = SimpleNamespace(cameras=cameras, port=port0, depth_axis=port0.normal,
                                left=cameras[0])
    starts, usable, detections = usable_poses(start_rig, board, detections)
    P = len(starts)
    n_global = sum(PARAMETERS[n] for n in names)
    basis = tilt_basis(port0.normal)
    corners, obs = observations(board, detections, views)
    m = sum(2 * o[1].size for o in obs)
    if m == 0:
        raise CalibrationError("no camera found the board in the underwater images")

    def unpack(x):
        distance, normal = port0.distance, port0.normal
        thick, n_water = list(port0.thicknesses), port0.n_water
        k = 0
        for name in names:
            if name == "distance":
                distance = x[k]
            elif name == "normal":
                normal = port0.normal + x[k] * basis[0] + x[k + 1] * basis[1]
            elif name == "thickness":
                thick[0] = x[k]
            else:
                n_water = x[k]
            k += PARAMETERS[name]
        port = FlatPort(normal, distance, tuple(thick), port0.indices[:-1] + (float(n_water),))
        Rs = Rotation.from_rotvec(x[n_global:].reshape(P, 6)[:, :3]).as_matrix()
        return port, Rs, x[n_global:].reshape(P, 6)[:, 3:]

    def residuals(x, cams=cameras):
        try:
            port, Rs, ts = unpack(x)
        except ValueError:  # a non-physical index or thickness on the way
            return np.full(m, 1e3)
        out = []
        for view, pose_idx, ids, uv in obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids]) + ts[pose_idx]
            r = (project(cams[view], port, world) - uv).ravel()
            out.append(np.where(np.isfinite(r), r, 1e3))
        return np.concatenate(out)

    def jacobian(x):
        width = n_global + 6
        try:
            port, Rs, ts = unpack(x)
        except ValueError:
            return rows_jacobian(np.zeros((m, width)), np.zeros(m, int), n_global, x.size)
        turn = pose_left_jacobians(x[n_global:].reshape(P, 6)[:, :3])
        length = np.linalg.norm(port0.normal + sum(
            x[k] * b for k, b in zip(_offsets(names, "normal"), basis)))
        blocks, rows = [], []
        for view, pose_idx, ids, _ in obs:
            rotated = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids])
            _, d_points, jac = project(cameras[view], port, rotated + ts[pose_idx],
                                       parameters=True)
            columns = []
            for name in names:
                if name == "distance":
                    columns.append(jac.distance[..., None])
                elif name == "normal":  # normal = m / |m|, m = N0 + a·x_a + b·x_b
                    columns.append(np.stack([jac.normal @ axis / length for axis in basis], -1))
                elif name == "thickness":
                    columns.append(jac.thicknesses[..., :1])
                else:
                    columns.append(jac.indices[..., -1:])
            d_turn = np.einsum("nrj,njk->nrk", np.cross(rotated[:, None, :], d_points),
                               turn[pose_idx])
            columns += [d_turn, d_points]
            blocks.append(np.concatenate(columns, axis=-1).reshape(-1, width))
            rows.append(np.repeat(pose_idx, 2))
        return rows_jacobian(np.concatenate(blocks), np.concatenate(rows), n_global, x.size)

    x0 = []
    for name in names:
        x0 += {"distance": [port0.distance], "normal": [0.0, 0.0],
               "thickness": list(port0.thicknesses[:1]), "n_water": [port0.n_water]}[name]
    for R, t in starts:
        x0 += list(Rotation.from_matrix(R).as_rotvec()) + list(t)
    x0 = np.asarray(x0, dtype=np.float64)
    lower, upper = np.full(x0.size, -np.inf), np.full(x0.size, np.inf)
    k = 0
    for name in names:
        if name in ("distance", "thickness"):
            lower[k] = MIN_LENGTH_MM
        elif name == "n_water":
            lower[k], upper[k] = 1.0, MAX_INDEX
        k += PARAMETERS[name]
    fit = least_squares(residuals, x0, jac=jacobian, method="trf", x_scale="jac",
                        bounds=(lower, upper), xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=300,
                        tr_solver="lsmr", tr_options={"atol": 1e-14, "btol": 1e-14})
    r = fit.fun
    J = fit.jac.toarray()
    s2 = float(r @ r) / max(r.size - x0.size, 1)
    N = J.T @ J
    try:
        conditional = s2 * np.linalg.inv(N)
    except np.linalg.LinAlgError:
        raise CalibrationError("the boards do not determine the port (singular normal "
                               "equations)") from None
    rms = float(np.sqrt(np.mean(r.reshape(-1, 2) ** 2) * 2))
    if not fit.status > 0 or rms > 2.0:
        raise CalibrationError(f"the adjustment stopped with a reprojection RMS of {rms:.3g} px "
                               f"({fit.message.rstrip('.')}): it did not find a port that fits "
                               f"the corners (check the design port)")
    covariance, uncertainty = conditional, "conditional"
    if air_covariance is not None and len(air_names):
        J_air = np.zeros((m, len(air_names)))
        by_name = {c: i for i, c in enumerate(rig.names)}
        for j, full in enumerate(air_names):
            camera_name, parameter = full.split(".", 1)
            v = by_name[camera_name]
            h = _step(parameter)
            plus = list(cameras)
            minus = list(cameras)
            plus[v] = _camera_moved(cameras[v], parameter, h)
            minus[v] = _camera_moved(cameras[v], parameter, -h)
            J_air[:, j] = (residuals(fit.x, plus) - residuals(fit.x, minus)) / (2 * h)
        G = np.linalg.solve(N, J.T @ J_air)
        covariance = conditional + G @ np.asarray(air_covariance) @ G.T
        uncertainty = "propagate"
    port, Rs, ts = unpack(fit.x)
    labels = tuple(f"{n}[{k}]" if PARAMETERS[n] > 1 else n for n in names
                   for k in range(PARAMETERS[n]))
    sig = np.sqrt(np.diag(covariance))[:n_global]
    sig_c = np.sqrt(np.diag(conditional))[:n_global]
    estimates, sigmas, sigmas_c, k = {}, {}, {}, 0
    for name in names:
        w = PARAMETERS[name]
        estimates[name] = {"distance": port.distance, "normal": port.normal.tolist(),
                           "thickness": port.thicknesses[0] if port.thicknesses else None,
                           "n_water": port.n_water}[name]
        sigmas[name] = float(sig[k]) if w == 1 else sig[k:k + w].tolist()
        sigmas_c[name] = float(sig_c[k]) if w == 1 else sig_c[k:k + w].tolist()
        k += w
    per, offset = {}, 0
    for view, pose_idx, _, _ in obs:
        rv = r[offset:offset + 2 * pose_idx.size].reshape(-1, 2)
        offset += 2 * pose_idx.size
        if rv.size:
            per[rig.names[view]] = float(np.sqrt(np.mean(rv ** 2) * 2))
    return MultiHousingCalibration(
        rig=MultiRig(cameras, [port] * len(cameras), rig.names), estimates=estimates,
        sigmas=sigmas, sigmas_conditional=sigmas_c, labels=labels,
        covariance=covariance[:n_global, :n_global], normal_axes=tuple(b.tolist() for b in basis),
        rms_px=rms, rms_px_per=per,
        poses={usable[i]: (Rs[i], ts[i]) for i in range(P)}, n_observations=m // 2,
        uncertainty=uncertainty)


def _offsets(names, name) -> list:
    """The positions of ``name``'s numbers among the free numbers (empty when not free)."""
    if name not in names:
        return []
    start = sum(PARAMETERS[n] for n in names[:names.index(name)])
    return list(range(start, start + PARAMETERS[name]))


__all__ = ["DEFAULT_FREE", "MultiHousingCalibration", "PARAMETERS", "calibrate_rig_housing"]
