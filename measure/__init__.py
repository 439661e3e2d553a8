"""measure — from stereo pixels to 3D points through a flat refractive port.

The field library of the project: numpy, scipy and OpenCV only (no Mitsuba, no Open3D).
Units are millimetres; the reference frame is the left camera's (OpenCV axes).
"""

from .geometry.camera import Camera
from .images.detect import REJECTION_REASONS, Detections, Rejection, detect_targets
from .geometry.lines import CommonPerpendicular, common_perpendicular
from .geometry.port import FlatPort
from .reasons import Reason
from .geometry.refraction import WaterRays, intersect_plane, refract, trace_through_port
from .stereo.triangulate import METHODS, StereoRig, Triangulation, triangulate, triangulate_rays

__all__ = [
    "Camera", "FlatPort", "StereoRig", "Triangulation", "triangulate", "triangulate_rays",
    "METHODS", "Reason", "refract", "intersect_plane", "trace_through_port",
    "WaterRays", "common_perpendicular", "CommonPerpendicular", "detect_targets", "Detections",
    "REJECTION_REASONS", "Rejection",
]
