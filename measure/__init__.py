"""measure — from stereo pixels to 3D points through a flat refractive port.

The field library of the project: numpy, scipy and OpenCV only (no Mitsuba, no Open3D).
Units are millimetres; the reference frame is the left camera's (OpenCV axes).

The public names below are loaded on first use (PEP 562): ``import measure`` itself imports
no numpy, OpenCV or SciPy, and ``from measure import Camera`` loads only what ``Camera`` needs.
"""

from __future__ import annotations

import importlib

#: Each public name and the module (relative to this package) that defines it.
_PUBLIC = {
    "Camera": ".geometry.camera",
    "REJECTION_REASONS": ".images.detect", "Detections": ".images.detect",
    "Rejection": ".images.detect", "detect_targets": ".images.detect",
    "CommonPerpendicular": ".geometry.lines", "common_perpendicular": ".geometry.lines",
    "FlatPort": ".geometry.port",
    "Reason": ".reasons",
    "WaterRays": ".geometry.refraction", "intersect_plane": ".geometry.refraction",
    "refract": ".geometry.refraction", "trace_through_port": ".geometry.refraction",
    "Rig": ".stereo.rig", "StereoRig": ".stereo.rig",
    "METHODS": ".stereo.triangulate",
    "Triangulation": ".stereo.triangulate", "triangulate": ".stereo.triangulate",
    "triangulate_rays": ".stereo.triangulate",
    "RigTriangulation": ".stereo.rig_triangulation", "triangulate_rig": ".stereo.rig_triangulation",
}

__all__ = [
    "Camera", "FlatPort", "Rig", "StereoRig", "Triangulation", "triangulate", "triangulate_rays",
    "RigTriangulation", "triangulate_rig",
    "METHODS", "Reason", "refract", "intersect_plane", "trace_through_port",
    "WaterRays", "common_perpendicular", "CommonPerpendicular", "detect_targets", "Detections",
    "REJECTION_REASONS", "Rejection",
]


def __getattr__(name: str):
    """Load a public name from its module on first access and keep it here."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
