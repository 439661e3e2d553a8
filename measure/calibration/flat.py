"""The housing problem of a flat port (:func:`housing_problem`): its free parameters
(:data:`HOUSING_PARAMETERS`), residuals and analytic Jacobian, and the free numbers as
:mod:`measure.stereo.rig_covariance` names (:func:`flat_rig_parameters`)."""

from __future__ import annotations

from functools import partial
from types import SimpleNamespace

import numpy as np

from ..geometry.camera import Camera
from ..geometry.flat_pair import FlatPair
from ..geometry.port import FlatPort
from ..stereo.rig import Rig
from .air import CalibrationError, Detections
from .board import Board
from .covariance import left_jacobian
from .problem import (MAX_INDEX, MIN_LENGTH_MM, HousingProblem, parameter_offset,
                      pose_left_jacobians)
from .selfcal import tilt_basis

#: Free housing parameters and how many numbers each is.
HOUSING_PARAMETERS = {"distance": 1, "normal": 2, "thickness": 1, "n_water": 1, "extrinsics": 6}


def parameters_of(views=(0, 1), pair: bool = False) -> dict:
    """:data:`HOUSING_PARAMETERS` of the cameras ``views``: behind two housings (``pair``) a
    ``distance``, ``normal`` and ``thickness`` per camera (left first), one ``n_water``; the
    ``extrinsics`` only with both cameras."""
    ports = len(tuple(views)) if pair else 1
    table = {"distance": ports, "normal": 2 * ports, "thickness": ports, "n_water": 1}
    if tuple(views) == (0, 1):
        table["extrinsics"] = 6
    return table


def housing_problem(rig: Rig, board: Board, detections: Detections, names,
                    views=(0, 1), pair: bool = False):
    """The bundle adjustment of :func:`calibrate_housing` as functions of the unknowns ``x``
    (free housing numbers, then 6 per usable pose): ``residuals``, its analytic ``jacobian``,
    ``unpack``, the start ``x0`` and its ``lower`` / ``upper`` bounds, and the bookkeeping.
    ``views``: the cameras whose corners enter (``(0,)``: one camera behind its port,
    :func:`measure.calibration.housing.calibrate_camera_housing`). ``pair``: ``rig.port`` is a
    :class:`measure.geometry.flat_pair.FlatPair` (two housings) and each camera of ``views``
    has its own port's ``distance``, ``normal`` and ``thickness`` (:func:`parameters_of`; the
    same flat-port residuals and Jacobian, each camera's rows touching its own port's
    columns); ``unpack`` then returns the pair."""
    return _FlatHousingProblem(rig, board, detections, tuple(names), tuple(views), pair)


class FlatPortsProblem(HousingProblem):
    """A housing of flat ports: ``S`` ports (one shared, or one per camera; camera ``v`` sees
    port ``slot[v]``), each with its free ``distance`` (mm), ``normal`` (two tilts, rad, about
    the axes ``bases`` ⟂ its starting normal) and first ``thickness`` (mm); one ``n_water``."""

    def set_ports(self, ports0, slot) -> None:
        """The starting ports and which one each camera sees."""
        self.ports0, self.slot, self.S = list(ports0), slot, len(ports0)
        self.bases = [tilt_basis(p.normal) for p in self.ports0]

    def normal_vector(self, x, s) -> np.ndarray:
        """Port ``s``'s normal at ``x`` before normalization: ``N0 + a·x_a + b·x_b``."""
        k = parameter_offset(self.names, "normal", self.table) + 2 * s
        return self.ports0[s].normal + x[k] * self.bases[s][0] + x[k + 1] * self.bases[s][1]

    def _own(self, values, s, width=1):
        """``values`` ``(n, 2, width)`` in port ``s``'s place among the ports' columns."""
        out = np.zeros(values.shape[:2] + (self.S * width,))
        out[..., s * width:(s + 1) * width] = values
        return out

    def port_columns(self, x, name, view, jac):
        """The columns of port number ``name`` (``distance``, ``normal``, ``thickness``,
        ``n_water``) for camera ``view``'s rows; None for another name."""
        s = self.slot[view]
        if name == "distance":
            return [self._own(jac.distance[..., None], s)]
        if name == "normal":  # normal = m / |m|, m = N0 + a·x_a + b·x_b
            length = np.linalg.norm(self.normal_vector(x, s))
            return [self._own(np.stack([jac.normal @ axis / length for axis in self.bases[s]],
                                       -1), s, 2)]
        if name == "thickness":
            return [self._own(jac.thicknesses[..., :1], s)]
        if name == "n_water":
            return [jac.indices[..., -1:]]
        return None


class _FlatHousingProblem(FlatPortsProblem):
    """:func:`housing_problem`: the free housing numbers are each port's in turn (``S`` ports:
    one shared, or one per camera of ``views`` with ``pair``)."""

    def __init__(self, rig, board, detections, names, views, pair):
        super().__init__(rig, board, detections, names, views, parameters_of(views, pair))
        self.pair = pair
        self.set_ports([rig.port.view(v) for v in views] if pair else [rig.port],
                       {v: (i if pair else 0) for i, v in enumerate(views)})
        self.x0, self.lower, self.upper = self._start()
        self.basis = np.array(self.bases) if pair else self.bases[0]

    def _start(self):
        """``(x0, lower, upper)``: the design port and the poses' starts, and bounds that keep
        the port physical on the way (a layer, indices >= 1)."""
        ports0, S = self.ports0, self.S
        x0 = []
        for name in self.names:
            x0 += {"distance": [p.distance for p in ports0], "normal": [0.0, 0.0] * S,
                   "thickness": [p.thicknesses[0] for p in ports0 if p.thicknesses],
                   "n_water": [ports0[0].n_water], "extrinsics": [0.0] * 6}[name]
        x0 = np.asarray(x0 + self.start_poses(), dtype=np.float64)
        lower = np.full(x0.size, -np.inf)
        upper = np.full(x0.size, np.inf)
        k = 0
        for name in self.names:
            if name in ("distance", "thickness"):
                lower[k:k + S] = MIN_LENGTH_MM
            elif name == "n_water":
                lower[k], upper[k] = 1.0, MAX_INDEX
            k += self.table[name]
        g = self.n_global
        x0[:g] = np.clip(x0[:g], lower[:g] + 1e-9, upper[:g] - 1e-9)
        return x0, lower, upper

    def unpack(self, x):
        """``(port, (left, right), Rs, ts)`` at ``x``: the port (a FlatPair with ``pair``; a
        camera not in ``views`` keeps its port, in the same water), the cameras (the right
        one moved with ``extrinsics``) and the poses."""
        from scipy.spatial.transform import Rotation

        rig, ports0, S = self.rig, self.ports0, self.S
        distances = [p.distance for p in ports0]
        normals = [p.normal for p in ports0]
        thick = [list(p.thicknesses) for p in ports0]
        n_water, right = None, rig.right
        k = 0
        for name in self.names:
            if name == "distance":
                distances = list(x[k:k + S])
            elif name == "normal":
                normals = [p.normal + x[k + 2 * s] * b[0] + x[k + 2 * s + 1] * b[1]
                           for s, (p, b) in enumerate(zip(ports0, self.bases))]
            elif name == "thickness":
                for s in range(S):
                    thick[s][0] = x[k + s]
            elif name == "n_water":
                n_water = x[k]
            elif name == "extrinsics":
                dR = Rotation.from_rotvec(x[k:k + 3]).as_matrix()
                right = Camera(rig.right.K, rig.right.size, rig.right.dist,
                               dR @ rig.right.R, rig.right.t + x[k + 3:k + 6])
            k += self.table[name]
        water = {} if n_water is None else {"n_water": float(n_water)}
        ports = [FlatPort(normals[s], distances[s], tuple(thick[s]),
                          p.indices[:-1] + (water.get("n_water", p.indices[-1]),))
                 for s, p in enumerate(ports0)]
        if not self.pair:
            port = ports[0]
        else:
            both = [rig.port.view(v).assumed(water) for v in (0, 1)]
            for v in self.views:
                both[v] = ports[self.slot[v]]
            port = FlatPair(*both)
        return (port, (rig.left, right), *self.poses(x))

    def housing_columns(self, x, name, view, jac, d_points, cameras) -> list:
        columns = self.port_columns(x, name, view, jac)
        if columns is not None:
            return columns
        if view == 1:  # extrinsics, the right camera: R = exp(ω) R0, t = t0 + δt
            k = parameter_offset(self.names, name, self.table)
            return [jac.rotation @ pose_left_jacobians(x[None, k:k + 3])[0], jac.center]
        return [np.zeros(d_points.shape[:2] + (6,))]


def flat_rig_parameters(names, x, basis, start_normal, port, n_global, views=None):
    """The housing's free numbers as :mod:`measure.stereo.rig_covariance` names, the ``(g, g)``
    Jacobian of those parameters with respect to the free numbers at ``x``, and the tilt axes
    (⟂ the estimated normal; None without a free normal). ``views``: two housings — the
    cameras whose ports are free (``basis`` and ``start_normal`` one per port, ``port`` the
    pair); their numbers are named ``left.port.…`` / ``right.port.…`` and both ports' tilts
    are about the first port's tilt axes (``n → normalize(n + a₀e₀ + a₁e₁)``: the tilts
    that move each normal as its own two numbers do, by the pseudo-inverse of the axes
    projected ⟂ that normal)."""
    pair = views is not None
    prefixes = [f"{('left', 'right')[v]}." for v in views] if pair else [""]
    bases = list(basis) if pair else [basis]
    starts = list(start_normal) if pair else [start_normal]
    S = len(prefixes)
    table = parameters_of(views if pair else (0, 1), pair)
    out, T, axes, k = [], np.zeros((n_global, n_global)), None, 0
    for name in names:
        if name == "distance":
            out += [f"{p}port.distance" for p in prefixes]
            T[k:k + S, k:k + S] = np.eye(S)
        elif name == "normal":  # n = m/|m|, m = n0 + a e0 + b e1; new tilts about the axes
            for s in range(S):
                j = k + 2 * s
                m = starts[s] + bases[s][0] * x[j] + bases[s][1] * x[j + 1]
                length = np.linalg.norm(m)
                n = m / length
                if axes is None:
                    axes = np.array(tilt_basis(n))
                away = np.eye(3) - np.outer(n, n)
                T[j:j + 2, j:j + 2] = (np.linalg.pinv(away @ axes.T) @ away
                                       @ np.array(bases[s]).T / length)
                out += [f"{prefixes[s]}port.tilt[0]", f"{prefixes[s]}port.tilt[1]"]
        elif name == "thickness":
            out += [f"{p}port.thickness[0]" for p in prefixes]
            T[k:k + S, k:k + S] = np.eye(S)
        elif name == "n_water":
            out.append(f"port.index[{len(port.view(0).indices) - 1}]")
            T[k, k] = 1.0
        else:  # R = exp(ω) R0: φ = J_l(ω) δω; the centre t = t0 + δt
            out += [f"right.rotation[{i}]" for i in range(3)]
            out += [f"right.center[{i}]" for i in range(3)]
            T[k:k + 3, k:k + 3] = left_jacobian(x[k:k + 3])
            T[k + 3:k + 6, k + 3:k + 6] = np.eye(3)
        k += table[name]
    return tuple(out), T, axes




def check_free(rig: Rig, names) -> None:
    """CalibrationError for a free parameter this port does not have (two housings: each
    port)."""
    if "thickness" in names and not all(rig.port.view(v).thicknesses for v in (0, 1)):
        raise CalibrationError(f"--free thickness: {rig.port.name} has no glass layer"
                               if rig.port.view(0) is rig.port.view(1) else
                               "--free thickness: a port of the pair has no glass layer")


def estimate(name, port, cameras, views=(0, 1)):
    """The estimate of free parameter ``name`` (:attr:`HousingCalibration.estimates`) of the
    calibrated shared ``port``."""
    if name == "distance":
        return port.distance
    if name == "normal":
        return port.normal.tolist()
    if name == "thickness":
        return port.thicknesses[0]
    if name == "n_water":
        return port.n_water
    return {"R": cameras[1].R.tolist(), "t": cameras[1].t.tolist()}


def pair_estimate(name, port, cameras, views=(0, 1)):
    """:func:`estimate` of two housings: ``distance``, ``normal``, ``thickness`` as
    ``{"left": …, "right": …}`` (the ports of ``views``), each its port's."""
    if name in ("n_water", "extrinsics"):
        return estimate(name, port.view(0), cameras)
    return {("left", "right")[v]: estimate(name, port.view(v), cameras) for v in views}


def for_views(views, pair: bool = False):
    """The flat port's housing calibration from the corners of the cameras ``views`` only:
    ``(0,)`` is one camera behind its port (no second camera, so no ``extrinsics``). ``pair``:
    two housings (:data:`FLAT_PAIR_HOUSING`), the port of each camera in ``views`` free."""
    views = tuple(views)
    if views == (0, 1):
        return FLAT_PAIR_HOUSING if pair else FLAT_HOUSING
    return SimpleNamespace(parameters=parameters_of(views, pair),
                           default_free=FLAT_HOUSING.default_free,
                           label="of one camera ", check_free=check_free,
                           problem=partial(housing_problem, views=views, pair=pair),
                           rig_parameters=partial(rig_parameters, views=views if pair else None),
                           estimate=partial(pair_estimate if pair else estimate, views=views),
                           views=views, for_views=partial(for_views, pair=pair))


def rig_parameters(names, air, x, basis, rig: Rig, port, cameras, n_global, views=None):
    """:func:`flat_rig_parameters` as the ``(a + g, a + g)`` Jacobian of (in-air parameters
    ``air``, the names) with respect to (``air``, the free numbers). ``views``: two housings,
    the cameras whose ports are free."""
    a = len(air)
    start = rig.port.normal if views is None else [rig.port.view(v).normal for v in views]
    rig_names, transform, axes = flat_rig_parameters(names, x, basis, start, port, n_global,
                                                     views)
    T = np.eye(a + n_global)
    T[a:, a:] = transform
    return rig_names, T, axes


#: The flat port's housing calibration (:data:`measure.calibration.housing.HOUSINGS`).
FLAT_HOUSING = SimpleNamespace(parameters=HOUSING_PARAMETERS, default_free=("distance", "normal"),
                               label="", check_free=check_free, problem=housing_problem,
                               rig_parameters=rig_parameters, estimate=estimate, views=(0, 1),
                               for_views=for_views)
#: Two housings (a :class:`measure.geometry.flat_pair.FlatPair`): the flat port's problem with
#: a ``distance``, ``normal`` and ``thickness`` per camera (:func:`parameters_of`).
FLAT_PAIR_HOUSING = SimpleNamespace(parameters=parameters_of((0, 1), True),
                                    default_free=("distance", "normal"),
                                    label="of two housings ", check_free=check_free,
                                    problem=partial(housing_problem, pair=True),
                                    rig_parameters=partial(rig_parameters, views=(0, 1)),
                                    estimate=pair_estimate, views=(0, 1),
                                    for_views=partial(for_views, pair=True))
