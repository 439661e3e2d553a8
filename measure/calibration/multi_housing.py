"""The housing of a rig of N cameras behind one shared flat port — or each behind its own — from
board corners under water.

The cameras stay as calibrated in air (:func:`measure.calibration.multi_air.calibrate_rig_in_air`:
every camera's intrinsics and pose); the unknowns are every board pose (6 each) and the free
port parameters (:data:`PARAMETERS`): ``distance`` (D, mm, the first interface ``N·X = D`` in
the reference frame), ``normal`` (2 tilts, rad, about axes ⟂ the starting normal),
``thickness`` (the first layer, mm) and ``n_water``; with a port per camera a distance, two tilts
and a thickness per camera (each camera's rows touching its own port's columns) and one
``n_water``. Residuals: every detected corner of every
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
    """``rig`` (the in-air cameras behind the calibrated port or ports), ``estimates``
    ``{distance, normal (unit 3-vector), thickness, n_water}`` of the free ones (of a port per
    camera: a list, one per camera, but ``n_water``), ``sigmas``
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
    port_names: tuple = ("port",)

    @property
    def shared(self) -> bool:
        """Whether every camera looks through one port (else each its own)."""
        return self.port_names == ("port",)


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


def _widths(S: int) -> dict:
    """How many numbers each free parameter is with ``S`` ports (1: shared): a distance, two
    tilts and a thickness per port, one water index."""
    return {"distance": S, "normal": 2 * S, "thickness": S, "n_water": 1}


def calibrate_rig_housing(rig: MultiRig, board: Board, detections: Detections, free=DEFAULT_FREE,
                          air_names=(), air_covariance=None,
                          per_camera: bool | None = None) -> MultiHousingCalibration:
    """The flat port(s) of ``rig`` (its cameras in air behind the starting ports: the design
    values) from the corners ``detections`` (``ids[k][v]`` for pose k, camera v) of ``board``
    (module docs): one port every camera shares when all of ``rig.ports`` are one, else each
    camera's own (a distance, normal and thickness per camera, one ``n_water``; each camera's
    corners through its own port) — ``per_camera`` True or False says which whatever the
    starting ports are. ``air_names``, ``air_covariance``: the in-air calibration's
    (:class:`measure.calibration.multi_air.MultiAirCalibration`), propagated into σ.
    CalibrationError (one line) for a camera not behind a flat port, unknown free parameters,
    too few boards, or a fit that does not determine them."""
    message = "the housing calibration of N cameras models flat ports"
    try:
        ports0 = [require_flat_port(p, f"{name}: {message}")
                  for name, p in zip(rig.names, rig.ports)]
    except ValueError as exc:
        raise CalibrationError(str(exc)) from None
    shared = all(p == ports0[0] for p in ports0) if per_camera is None else not per_camera
    if shared and any(p != ports0[0] for p in ports0):
        raise CalibrationError("one shared port asked for, but the cameras start behind "
                               "different ports")
    if shared:
        ports0 = ports0[:1]
    S = len(ports0)
    slot = [0 if shared else v for v in range(len(rig.cameras))]
    table = _widths(S)
    names = tuple(dict.fromkeys(free))
    unknown = [n for n in names if n not in PARAMETERS]
    if not names or unknown:
        raise CalibrationError(f"--free {','.join(free) or '(nothing)'}: the housing calibration "
                               f"of N cameras estimates {', '.join(PARAMETERS)}")
    if "thickness" in names and not all(p.thicknesses for p in ports0):
        raise CalibrationError("--free thickness: a port has no glass layer")
    cameras = rig.cameras
    views = tuple(range(len(cameras)))
    start_rig = SimpleNamespace(cameras=cameras, port=ports0[0], depth_axis=ports0[0].normal,
                                left=cameras[0])
    starts, usable, detections = usable_poses(start_rig, board, detections)
    P = len(starts)
    n_global = sum(table[n] for n in names)
    bases = [tilt_basis(p.normal) for p in ports0]
    corners, obs = observations(board, detections, views)
    m = sum(2 * o[1].size for o in obs)
    if m == 0:
        raise CalibrationError("no camera found the board in the underwater images")
    at = {}
    k = 0
    for name in names:
        at[name] = k
        k += table[name]

    def normal_vector(x, s):
        k = at["normal"] + 2 * s
        return ports0[s].normal + x[k] * bases[s][0] + x[k + 1] * bases[s][1]

    def unpack(x):
        n_water = x[at["n_water"]] if "n_water" in at else ports0[0].n_water
        ports = []
        for s, p in enumerate(ports0):
            thick = list(p.thicknesses)
            if "thickness" in at:
                thick[0] = x[at["thickness"] + s]
            ports.append(FlatPort(normal_vector(x, s) if "normal" in at else p.normal,
                                  x[at["distance"] + s] if "distance" in at else p.distance,
                                  tuple(thick), p.indices[:-1] + (float(n_water),)))
        Rs = Rotation.from_rotvec(x[n_global:].reshape(P, 6)[:, :3]).as_matrix()
        return ports, Rs, x[n_global:].reshape(P, 6)[:, 3:]

    def residuals(x, cams=cameras):
        try:
            ports, Rs, ts = unpack(x)
        except ValueError:  # a non-physical index or thickness on the way
            return np.full(m, 1e3)
        out = []
        for view, pose_idx, ids, uv in obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids]) + ts[pose_idx]
            r = (project(cams[view], ports[slot[view]], world) - uv).ravel()
            out.append(np.where(np.isfinite(r), r, 1e3))
        return np.concatenate(out)

    def own(values, s, width=1):
        """``values`` ``(n, 2, width)`` in port ``s``'s place among the ports' columns."""
        out = np.zeros(values.shape[:2] + (S * width,))
        out[..., s * width:(s + 1) * width] = values
        return out

    def jacobian(x):
        width = n_global + 6
        try:
            ports, Rs, ts = unpack(x)
        except ValueError:
            return rows_jacobian(np.zeros((m, width)), np.zeros(m, int), n_global, x.size)
        turn = pose_left_jacobians(x[n_global:].reshape(P, 6)[:, :3])
        blocks, rows = [], []
        for view, pose_idx, ids, _ in obs:
            s = slot[view]
            rotated = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids])
            _, d_points, jac = project(cameras[view], ports[s], rotated + ts[pose_idx],
                                       parameters=True)
            columns = []
            for name in names:
                if name == "distance":
                    columns.append(own(jac.distance[..., None], s))
                elif name == "normal":  # normal = m / |m|, m = N0 + a·x_a + b·x_b
                    length = np.linalg.norm(normal_vector(x, s))
                    columns.append(own(np.stack([jac.normal @ axis / length
                                                 for axis in bases[s]], -1), s, 2))
                elif name == "thickness":
                    columns.append(own(jac.thicknesses[..., :1], s))
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
        x0 += {"distance": [p.distance for p in ports0], "normal": [0.0, 0.0] * S,
               "thickness": [p.thicknesses[0] for p in ports0 if p.thicknesses],
               "n_water": [ports0[0].n_water]}[name]
    for R, t in starts:
        x0 += list(Rotation.from_matrix(R).as_rotvec()) + list(t)
    x0 = np.asarray(x0, dtype=np.float64)
    lower, upper = np.full(x0.size, -np.inf), np.full(x0.size, np.inf)
    for name in names:  # a port per camera: D in the reference frame may be negative
        if name == "thickness" or (name == "distance" and shared):
            lower[at[name]:at[name] + S] = MIN_LENGTH_MM
        elif name == "n_water":
            lower[at[name]], upper[at[name]] = 1.0, MAX_INDEX
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
    ports, Rs, ts = unpack(fit.x)
    port_names = ["port"] if shared else [f"{n}.port" for n in rig.names]
    labels = []
    for name in names:
        for s in range(S if name != "n_water" else 1):
            prefix = "" if shared or name == "n_water" else f"{rig.names[s]}."
            labels += ([f"{prefix}normal[0]", f"{prefix}normal[1]"] if name == "normal"
                       else [f"{prefix}{name}"])
    sig = np.sqrt(np.diag(covariance))[:n_global]
    sig_c = np.sqrt(np.diag(conditional))[:n_global]

    def value(name, port):
        return {"distance": port.distance, "normal": port.normal.tolist(),
                "thickness": port.thicknesses[0] if port.thicknesses else None,
                "n_water": port.n_water}[name]

    estimates, sigmas, sigmas_c = {}, {}, {}
    for name in names:
        k, w = at[name], table[name] // (S if name != "n_water" else 1)
        if shared or name == "n_water":
            estimates[name] = value(name, ports[0])
            sigmas[name] = float(sig[k]) if w == 1 else sig[k:k + w].tolist()
            sigmas_c[name] = float(sig_c[k]) if w == 1 else sig_c[k:k + w].tolist()
        else:  # one entry per camera
            estimates[name] = [value(name, p) for p in ports]
            sigmas[name] = [float(sig[k + s]) if w == 1 else sig[k + 2 * s:k + 2 * s + 2].tolist()
                            for s in range(S)]
            sigmas_c[name] = [float(sig_c[k + s]) if w == 1
                              else sig_c[k + 2 * s:k + 2 * s + 2].tolist() for s in range(S)]
    per, offset = {}, 0
    for view, pose_idx, _, _ in obs:
        rv = r[offset:offset + 2 * pose_idx.size].reshape(-1, 2)
        offset += 2 * pose_idx.size
        if rv.size:
            per[rig.names[view]] = float(np.sqrt(np.mean(rv ** 2) * 2))
    return MultiHousingCalibration(
        rig=MultiRig(cameras, [ports[slot[v]] for v in range(len(cameras))], rig.names),
        estimates=estimates, sigmas=sigmas, sigmas_conditional=sigmas_c, labels=tuple(labels),
        covariance=covariance[:n_global, :n_global],
        normal_axes=(tuple(b.tolist() for b in bases[0]) if shared
                     else tuple(tuple(b.tolist() for b in basis) for basis in bases)),
        rms_px=rms, rms_px_per=per, poses={usable[i]: (Rs[i], ts[i]) for i in range(P)},
        n_observations=m // 2, uncertainty=uncertainty, port_names=tuple(port_names))


__all__ = ["DEFAULT_FREE", "MultiHousingCalibration", "PARAMETERS", "calibrate_rig_housing"]
