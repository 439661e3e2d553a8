"""A straightforward per-point Fermat solver: the baseline the vectorized solver is measured against.

It follows the paper's section 2.2 as written, one point at a time: build the refraction plane,
the interface lines ``r_k(μ_k) = J_k + μ_k ε`` in 3D, the travel time ``t(μ) = Σ n_i |I_{i+1} −
I_i|`` (times c), and minimize it with ``scipy.optimize.minimize`` (BFGS with the analytic
gradient). Used by ``python -m eval bench`` only; the product uses :mod:`synth.project`.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from measure import Camera, FlatPort


def _plane_lines(center, port: FlatPort, point):
    """Points J_k where O→P crosses each interface and the in-plane interface direction ε."""
    phi = (point - center) / np.linalg.norm(point - center)  # equation 15
    chi = np.cross(phi, port.normal)
    if np.linalg.norm(chi) < 1e-15:  # the point lies on the normal through the camera
        chi = np.cross([1.0, 0.0, 0.0], port.normal)
        if np.linalg.norm(chi) < 1e-12:
            chi = np.cross([0.0, 1.0, 0.0], port.normal)
    chi /= np.linalg.norm(chi)  # equation 16
    epsilon = np.cross(chi, port.normal)
    epsilon /= np.linalg.norm(epsilon)  # equation 17
    h = (port.offsets - center @ port.normal) / (phi @ port.normal)  # equation 4 for each J_k
    return center + h[:, None] * phi, epsilon


def fermat_pixel_scipy(camera: Camera, port: FlatPort, point, gtol: float = 1e-11) -> np.ndarray:
    """Pixel ``(2,)`` of one point ``(3,)`` by minimizing the travel time with SciPy."""
    point = np.asarray(point, dtype=np.float64)
    center = camera.center
    j_points, epsilon = _plane_lines(center, port, point)
    n = np.asarray(port.indices)

    def vertices(mu):
        return np.vstack([center, j_points + mu[:, None] * epsilon, point])

    def travel_time_and_gradient(mu):
        v = vertices(mu)
        segments = np.diff(v, axis=0)
        lengths = np.linalg.norm(segments, axis=1)
        units = n[:, None] * segments / lengths[:, None]
        gradient = (units[:-1] - units[1:]) @ epsilon  # ∂t/∂μ_k, equation 23
        return float(n @ lengths), gradient

    result = minimize(travel_time_and_gradient, np.zeros(port.n_interfaces), jac=True,
                      method="BFGS", options=dict(gtol=gtol))
    first_interface_point = vertices(result.x)[1]
    return camera.project(first_interface_point[None])[0]
