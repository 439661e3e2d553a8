"""Port deviations between truth and design: a dataset rendered with the TRUE port that also
states the DESIGN port a user would believe (the drawing of the housing, the catalogue's water
index).

The deviations are named after the quantities of ``eval run --assume``
(:mod:`eval.core.assumption`) and are always *truth − design*:

``port_distance`` (mm, D), ``glass_thickness`` (mm, the first layer), ``n_glass`` (the first
layer's index), ``n_water``, ``port_tilt_x`` and ``port_tilt_y`` (degrees added to the port's tilt
about x and about y, :func:`synth.scene.rig.tilted_port_normal`).

A dataset with a design (``synth suite``'s ``error.<name>`` parameters) holds, besides the truth
(``calib.yaml``, ``cameras.json``, ``colmap/``: the rig that was rendered, what scoring uses),
``calib_design.yaml`` and ``cameras_design.json``: the same cameras with the design port, in the
same formats; ``manifest.json``'s ``design`` records the deviations and the design values.
"""

from __future__ import annotations

import numpy as np

from measure import FlatPort, Rig, StereoRig
from measure.geometry.port import require_flat_port

#: The deviations a suite may give (``error.<name>``), with their units.
ERRORS = {"port_distance": "mm", "port_tilt_x": "deg", "port_tilt_y": "deg",
          "glass_thickness": "mm", "n_glass": "index", "n_water": "index"}
#: The design port's quantities a design may set (:func:`design_rig`).
DESIGN_PORT = ("port_distance", "port_normal", "glass_thickness", "n_glass", "n_water")
#: What ``calib_design.yaml`` says it is (its ``design: note``).
DESIGN_NOTE = ("the DESIGN port a user would believe; calib.yaml holds the truth that was "
               "rendered (deviations truth - design in manifest.json: design)")
#: The files a dataset with a design adds (:func:`synth.products.dataset.write_dataset`).
CALIB_DESIGN = "calib_design.yaml"
CAMERAS_DESIGN = "cameras_design.json"


def design_rig(truth: Rig, port: dict) -> Rig:
    """The rig a user would believe: ``truth``'s cameras with its port's quantities replaced by
    ``port`` (``{name: value}``, names of :data:`DESIGN_PORT`; ``port_normal`` 3 numbers, the
    others numbers in mm or index units). ValueError for an unknown name, a glass quantity of a
    port without glass, or a port the values make invalid."""
    require_flat_port(truth.port, "design port: a rig of domes has no flat port to deviate")
    p = truth.port
    normal, distance = np.asarray(p.normal, float), float(p.distance)
    thicknesses, indices = list(p.thicknesses), list(p.indices)
    for name, value in port.items():
        if name not in DESIGN_PORT:
            raise ValueError(f"design port: unknown quantity {name!r} (known: "
                             f"{', '.join(DESIGN_PORT)})")
        if name in ("glass_thickness", "n_glass") and not thicknesses:
            raise ValueError(f"design port: {name}: the port has no glass layer")
        if name == "port_distance":
            distance = float(value)
        elif name == "port_normal":
            normal = np.asarray(value, dtype=float)
        elif name == "glass_thickness":
            thicknesses[0] = float(value)
        elif name == "n_glass":
            indices[1] = float(value)
        else:
            indices[-1] = float(value)
    return StereoRig(truth.left, truth.right,
                     FlatPort(normal, distance, tuple(thicknesses), tuple(indices)))


__all__ = ["CALIB_DESIGN", "CAMERAS_DESIGN", "DESIGN_NOTE", "DESIGN_PORT", "ERRORS",
           "design_rig"]
