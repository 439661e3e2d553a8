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
from ..stereo.rig import Rig
from .air import CalibrationError, Detections
from .board import Board
from .multi_air import DISTORTION_NAMES, INTRINSIC_NAMES
from .flat import FlatPortsProblem
from .problem import MAX_INDEX, MIN_LENGTH_MM, parameter_offset

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

    rig: Rig
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


def calibrate_rig_housing(rig: Rig, board: Board, detections: Detections, free=DEFAULT_FREE,
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
    ports0, shared = _starting_ports(rig, per_camera)
    names = tuple(dict.fromkeys(free))
    unknown = [n for n in names if n not in PARAMETERS]
    if not names or unknown:
        raise CalibrationError(f"--free {','.join(free) or '(nothing)'}: the housing calibration "
                               f"of N cameras estimates {', '.join(PARAMETERS)}")
    if "thickness" in names and not all(p.thicknesses for p in ports0):
        raise CalibrationError("--free thickness: a port has no glass layer")
    problem = _RigHousingProblem(rig, board, detections, names, ports0, shared)
    fit = least_squares(problem.residuals, problem.x0, jac=problem.jacobian, method="trf",
                        x_scale="jac", bounds=(problem.lower, problem.upper), xtol=1e-12,
                        ftol=1e-12, gtol=1e-12, max_nfev=300, tr_solver="lsmr",
                        tr_options={"atol": 1e-14, "btol": 1e-14})
    r = fit.fun
    J = fit.jac.toarray()
    s2 = float(r @ r) / max(r.size - problem.x0.size, 1)
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
        G = np.linalg.solve(N, J.T @ _air_jacobian(problem, fit.x, rig.names, air_names))
        covariance = conditional + G @ np.asarray(air_covariance) @ G.T
        uncertainty = "propagate"
    return _result(problem, fit, rig.names, covariance, conditional, rms, uncertainty)


def _starting_ports(rig: Rig, per_camera) -> tuple[list, bool]:
    """``(ports, shared)``: the starting flat ports (one when they are shared) and whether
    they are; CalibrationError for a camera not behind a flat port or a shared port asked of
    different ones."""
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
    return (ports0[:1] if shared else ports0), shared


class _PortsSeen:
    """A housing of N cameras: camera ``v`` sees ``ports[slot[v]]``."""

    def __init__(self, ports, slot):
        self.ports, self.slot = ports, slot

    def view(self, view: int) -> FlatPort:
        return self.ports[self.slot[view]]


class _RigHousingProblem(FlatPortsProblem):
    """The bundle adjustment of :func:`calibrate_rig_housing`: the free port numbers (each
    port's in turn), then 6 per usable pose; every camera's corners through its port."""

    def __init__(self, rig, board, detections, names, ports0, shared):
        cameras = rig.cameras
        start_rig = SimpleNamespace(cameras=cameras, port=ports0[0],
                                    depth_axis=ports0[0].normal, left=cameras[0])
        super().__init__(start_rig, board, detections, names, tuple(range(len(cameras))),
                         _widths(len(ports0)))
        if self.m == 0:
            raise CalibrationError("no camera found the board in the underwater images")
        self.cameras, self.shared = cameras, shared
        self.set_ports(ports0, [0 if shared else v for v in range(len(cameras))])
        self.x0, self.lower, self.upper = self._start()

    def _start(self):
        """``(x0, lower, upper)``: the starting ports and poses; a port per camera's distance
        in the reference frame may be negative, a shared one's and thicknesses not."""
        ports0, S, names = self.ports0, self.S, self.names
        x0 = []
        for name in names:
            x0 += {"distance": [p.distance for p in ports0], "normal": [0.0, 0.0] * S,
                   "thickness": [p.thicknesses[0] for p in ports0 if p.thicknesses],
                   "n_water": [ports0[0].n_water]}[name]
        x0 = np.asarray(x0 + self.start_poses(), dtype=np.float64)
        lower, upper = np.full(x0.size, -np.inf), np.full(x0.size, np.inf)
        for name in names:
            at = parameter_offset(names, name, self.table)
            if name == "thickness" or (name == "distance" and self.shared):
                lower[at:at + S] = MIN_LENGTH_MM
            elif name == "n_water":
                lower[at], upper[at] = 1.0, MAX_INDEX
        return x0, lower, upper

    def ports_at(self, x) -> list:
        """The ports at ``x`` (one n_water for all)."""
        names, table = self.names, self.table
        at = {name: parameter_offset(names, name, table) for name in names}
        n_water = x[at["n_water"]] if "n_water" in at else self.ports0[0].n_water
        ports = []
        for s, p in enumerate(self.ports0):
            thick = list(p.thicknesses)
            if "thickness" in at:
                thick[0] = x[at["thickness"] + s]
            ports.append(FlatPort(self.normal_vector(x, s) if "normal" in at else p.normal,
                                  x[at["distance"] + s] if "distance" in at else p.distance,
                                  tuple(thick), p.indices[:-1] + (float(n_water),)))
        return ports

    def unpack(self, x):
        return (_PortsSeen(self.ports_at(x), self.slot), self.cameras, *self.poses(x))

    def housing_columns(self, x, name, view, jac, d_points, cameras) -> list:
        return self.port_columns(x, name, view, jac)


def _air_jacobian(problem, x, camera_names, air_names) -> np.ndarray:
    """``(m, len(air_names))``: d residuals / d the in-air camera parameters (``camera.name``)
    at ``x``, by central differences of the residuals."""
    cameras = problem.cameras
    J_air = np.zeros((problem.m, len(air_names)))
    by_name = {c: i for i, c in enumerate(camera_names)}
    for j, full in enumerate(air_names):
        camera_name, parameter = full.split(".", 1)
        v = by_name[camera_name]
        h = _step(parameter)
        plus = list(cameras)
        minus = list(cameras)
        plus[v] = _camera_moved(cameras[v], parameter, h)
        minus[v] = _camera_moved(cameras[v], parameter, -h)
        J_air[:, j] = (problem.residuals(x, plus) - problem.residuals(x, minus)) / (2 * h)
    return J_air


def _result(problem, fit, camera_names, covariance, conditional, rms,
            uncertainty) -> MultiHousingCalibration:
    """The calibration of :func:`calibrate_rig_housing` from its problem and fit."""
    names, S, shared, n_global = problem.names, problem.S, problem.shared, problem.n_global
    ports = problem.ports_at(fit.x)
    Rs, ts = problem.poses(fit.x)
    port_names = ["port"] if shared else [f"{n}.port" for n in camera_names]
    labels = []
    for name in names:
        for s in range(S if name != "n_water" else 1):
            prefix = "" if shared or name == "n_water" else f"{camera_names[s]}."
            labels += ([f"{prefix}normal[0]", f"{prefix}normal[1]"] if name == "normal"
                       else [f"{prefix}{name}"])
    estimates, sigmas, sigmas_c = _estimates(problem, ports, covariance, conditional)
    per, offset = {}, 0
    for view, pose_idx, _, _ in problem.obs:
        rv = fit.fun[offset:offset + 2 * pose_idx.size].reshape(-1, 2)
        offset += 2 * pose_idx.size
        if rv.size:
            per[camera_names[view]] = float(np.sqrt(np.mean(rv ** 2) * 2))
    cameras, bases = problem.cameras, problem.bases
    return MultiHousingCalibration(
        rig=Rig(cameras, [ports[problem.slot[v]] for v in range(len(cameras))],
                     camera_names),
        estimates=estimates, sigmas=sigmas, sigmas_conditional=sigmas_c, labels=tuple(labels),
        covariance=covariance[:n_global, :n_global],
        normal_axes=(tuple(b.tolist() for b in bases[0]) if shared
                     else tuple(tuple(b.tolist() for b in basis) for basis in bases)),
        rms_px=rms, rms_px_per=per,
        poses={problem.usable[i]: (Rs[i], ts[i]) for i in range(problem.P)},
        n_observations=problem.m // 2, uncertainty=uncertainty, port_names=tuple(port_names))


def _estimates(problem, ports, covariance, conditional) -> tuple[dict, dict, dict]:
    """``(estimates, σ, conditional σ)`` by free parameter: one value of a shared port or of
    the water, else a list with one per camera."""
    names, S, shared, table = problem.names, problem.S, problem.shared, problem.table
    sig = np.sqrt(np.diag(covariance))[:problem.n_global]
    sig_c = np.sqrt(np.diag(conditional))[:problem.n_global]

    def value(name, port):
        return {"distance": port.distance, "normal": port.normal.tolist(),
                "thickness": port.thicknesses[0] if port.thicknesses else None,
                "n_water": port.n_water}[name]

    estimates, sigmas, sigmas_c = {}, {}, {}
    for name in names:
        k, w = parameter_offset(names, name, table), table[name] // (S if name != "n_water" else 1)
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
    return estimates, sigmas, sigmas_c


__all__ = ["DEFAULT_FREE", "MultiHousingCalibration", "PARAMETERS", "calibrate_rig_housing"]
