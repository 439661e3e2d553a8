"""Two housings: each camera of a stereo rig behind its own flat port.

Conventions (docs/architecture.md): millimetres, reference frame = the left camera's frame.
A :class:`FlatPair` holds two :class:`measure.geometry.port.FlatPort` instances, ``left`` (the
port the left camera looks through) and ``right``, both in the reference frame; each may have
its own normal, distance, glass and indices (one water: the pair's ``n_water`` is the left
port's). The ports are modelled as infinite planes like the shared port; that each camera's
rays cross only its own window is a property of the physical windows (their size and place),
checked where a scene is written (:mod:`synth.scene.windows`).

Everything that traces, projects or differentiates goes through :meth:`FlatPair.view` — a
plain ``FlatPort`` per camera — so the flat port's tracing, Fermat projection and Jacobians
serve both cameras unchanged. The refractive COLMAP fork and calibmar describe such a rig with
a ``FLATPORT`` per camera (:mod:`measure.geometry.flatport_format`).

Rig-covariance names (:mod:`measure.stereo.rig_covariance`): ``left.port.distance``,
``left.port.tilt[0/1]``, ``left.port.thickness[k]``, ``left.port.index[k]`` (and ``right.``)
move that camera's port; ``port.index[k]`` moves medium k of both ports.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import ValueEquality
from .port import FlatPort, RigPort

#: The two cameras, in the order of :meth:`FlatPair.view`.
VIEWS = ("left", "right")


@dataclass(frozen=True, eq=False)
class FlatPair(RigPort, ValueEquality):
    """The two flat ports of a rig of two housings: ``left`` in front of the left camera,
    ``right`` in front of the right one (reference frame)."""

    left: FlatPort
    right: FlatPort

    def __post_init__(self):
        if not isinstance(self.left, FlatPort) or not isinstance(self.right, FlatPort):
            raise ValueError("a FlatPair holds two measure.FlatPort instances (left, right)")

    def __getitem__(self, view: int) -> FlatPort:
        """The port of camera ``view`` (0 left, 1 right)."""
        return (self.left, self.right)[view]

    @property
    def n_water(self) -> float:
        """The water index (the left port's; both look into the same water)."""
        return self.left.n_water

    def water_side(self, points: np.ndarray) -> np.ndarray:
        """Whether points ``(N, 3)`` lie in the water of both ports (beyond both last
        interfaces): where both cameras can see them."""
        return self.left.water_side(points) & self.right.water_side(points)

    # the port interface (RigPort) ---------------------------------------------------------
    kind = "flat pair"
    housing = "FLATPORT"
    description = "a flat port per camera"
    name = "the two ports"
    calibration_name = "two-housing calibration (a FLATPORT per camera)"
    glass_name = "both ports' last interfaces"
    axis_name = "the left port's normal"

    def view(self, view: int) -> FlatPort:
        """Each camera looks through its own port."""
        return self[view]

    @property
    def refracts(self) -> bool:
        return self.left.refracts or self.right.refracts

    def check_cameras(self, left, right) -> None:
        """Each camera on the air side of its own port, and neither inside the other's glass
        (between the other port's first and last interfaces)."""
        self.left.check_camera(left.center, "left camera")
        self.right.check_camera(right.center, "right camera")
        for name, camera, other_name, other in (("left", left, "right", self.right),
                                                ("right", right, "left", self.left)):
            height = float(other.normal @ camera.center)
            first, last = other.offsets[0], other.offsets[-1]
            if first <= height <= last:
                raise ValueError(f"{name} camera centre lies inside the {other_name} port's glass "
                                 f"(normal·centre = {height:.6g} mm, between its interfaces at "
                                 f"{first:.6g} and {last:.6g} mm)")

    def depth_axis(self, left) -> np.ndarray:
        """The left port's normal."""
        return self.left.normal

    @property
    def reference_axis(self) -> np.ndarray:
        return self.left.normal

    def glass_depth(self, left) -> float:
        """The farther of the two ports' last interfaces where the depth axis through the left
        camera's centre meets them (mm from that centre)."""
        axis = self.depth_axis(left)
        return max(port.glass_reach(left.center, axis) for port in (self.left, self.right))

    def describe(self) -> dict:
        return {"kind": self.kind, "left": self.left.describe(), "right": self.right.describe()}

    def difference(self, other, differs, diff) -> None:
        for view in VIEWS:
            part = {}
            getattr(self, view).difference(getattr(other, view), differs, part)
            diff.update({f"{view}_{name}": value for name, value in part.items()})

    assumable = ("n_water", "n_glass")
    rig_name = "a rig of two housings"
    rig_detail = "each camera behind its own flat port"

    def check_assumption(self, name: str) -> None:
        if name == "n_glass" and not (self.left.thicknesses and self.right.thicknesses):
            raise ValueError(f"{name}: a port of the pair has no glass layer")

    def assumed(self, values: dict) -> FlatPair:
        """``n_water``, ``n_glass``: the water's or the first layer's index of both ports."""
        return FlatPair(self.left.assumed(values), self.right.assumed(values))

    def check_parameter_names(self, names) -> None:
        domes = [n for n in names if ".dome_center" in n]
        if domes:
            raise ValueError(f"{', '.join(domes)}: dome parameters, but the rig has a flat port "
                             f"per camera")
        shared = [n for n in names if n.startswith("port.") and not n.startswith("port.index")]
        if shared:
            raise ValueError(f"{', '.join(shared)}: parameters of one shared port, but each camera "
                             f"has its own (left.port.…, right.port.…)")

    def moved(self, changes, normal_axes=None) -> FlatPair:
        """``left.port.…`` / ``right.port.…`` move that camera's port (the names of
        :meth:`FlatPort.moved` after the camera's name); ``port.index[k]`` medium k of both."""
        per_view = {view: [] for view in VIEWS}
        for name, d in changes:
            head, _, tail = name.partition(".")
            if head in per_view:
                per_view[head].append((tail, d))
            else:
                for view in VIEWS:
                    per_view[view].append((name, d))
        return FlatPair(*(getattr(self, view).moved(per_view[view], normal_axes)
                          for view in VIEWS))


__all__ = ["FlatPair", "VIEWS"]
