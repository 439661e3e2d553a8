"""Stereo calibrations in the files users already have: calibmar's YAML and the refractive
COLMAP fork's ``cameras.txt`` — written from and read into this project's rig, exactly.

Both come from Kiel's refractive tools (docs/formats.md has the sources, file and line):

* **calibmar** (github MDSKiel/calibmar) saves a stereo calibration as *two* files:
  ``<name>.yaml`` for the first camera and ``<name>_stereo.yaml`` for the second
  (``src/app/ui/main_window.cpp``), each ``model``, ``parameters`` (a COLMAP camera model),
  ``non_svp_model`` (``FLATPORT``, ``DOMEPORT``, or ``NONE`` in air), ``non_svp_parameters``
  ``[Nx, Ny, Nz, int_dist, int_thick, na, ng, nw]`` (``DOMEPORT``: ``[Cx, Cy, Cz, int_radius,
  int_thick, na, ng, nw]``, the dome centre in that camera's frame), ``width``, ``height`` and the stereo pose
  ``cam_to_world_rotation_rowmajor`` (9 numbers) and ``cam_to_world_translation`` (3):
  ``X_world = R·X_cam + t``, the world being the first camera (identity in its file)
  (``src/calibmar/core/report.cpp`` lines 91–152, ``stereo_calibrator.cpp`` lines 93–96).
* **COLMAP fork** (github MDSKiel/colmap_underwater): ``cameras.txt`` lines
  ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS… [FLATPORT Nx Ny Nz int_dist int_thick na ng nw]`` or
  ``… [DOMEPORT Cx Cy Cz int_radius int_thick na ng nw]``
  (``src/colmap/scene/reconstruction.cc`` lines 1854–1893). A ``cameras.txt`` holds no relative
  pose; the fork's rig bundle adjuster reads it from a rig configuration JSON
  (``src/colmap/exe/sfm.cc`` lines 540–583): ``[{"ref_camera_id": 1, "cameras": [{"camera_id",
  "image_prefix", "cam_from_rig_rotation": [w, x, y, z], "cam_from_rig_translation"}…]}]``.
  So this project writes ``cameras.txt`` and, beside it, ``rig_config.json``; reading a
  ``cameras.txt`` needs that file beside it (the left camera is ``ref_camera_id``).

Conventions of both: COLMAP pixels — the centre of the top-left pixel is (0.5, 0.5), so
``cx, cy`` are OpenCV's + 0.5 (calibmar adds 0.5 to OpenCV's corners:
``src/calibmar/extractors/chessboard_extractor.cpp`` lines 61–63); the port normal in each
camera's own frame and its distance from that camera (:mod:`measure.geometry.flatport_format`); lengths
in metres (calibmar: the unit of the target, "expected in meters"). Two FLATPORTs that agree
(:data:`PORT_TOLERANCE`) are one flat port both cameras look through
(:class:`measure.FlatPort`); two that differ are two housings, each camera behind its own port
(:class:`measure.geometry.flat_pair.FlatPair`, written back the same way); a
rig of two domes (:class:`measure.geometry.dome.DomePair`) is one DOMEPORT per camera, each camera's
own (:func:`measure.geometry.flatport_format.to_domeport`); both cameras must have the same
housing; a rig with a skewed K, zero or several port layers cannot be written and raises
:class:`CalibFormatError`.
Camera models read: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV (their
distortion is OpenCV's Brown–Conrady model) and OPENCV_FISHEYE (OpenCV's fisheye model, k1…k4);
written: OPENCV, or FULL_OPENCV when k3 (or k4–k6) is not zero; OPENCV_FISHEYE for a fisheye
camera.
"""

from __future__ import annotations

import os

from measure import Rig

# the formats' modules; their public names are this module's (read and written from here)
from synth.formats.calib_common import (CALIBMAR_NAME, COLMAP_CAMERAS_NAME, COLMAP_MODELS,
                                        COLMAP_PIXEL_OFFSET, COLMAP_RIG_NAME, IMAGE_PREFIXES,
                                        PORT_TOLERANCE, PYCOLMAP_WARNING, CalibFormatError,
                                        calib_dict, calib_format, colmap_camera,
                                        distortion_model_of, opencv_camera, stereo_extrinsics)
from synth.formats.calibmar_file import calibmar_partner, read_calibmar, write_calibmar
from synth.formats.camera_file import (read_covariance_node, read_single_camera,
                                       write_single_camera)
from synth.formats.colmap_files import (colmap_cameras, read_colmap, read_colmap_rig,
                                        write_colmap, write_colmap_rig)


def write_calibration_formats(directory, rig: Rig, has_port: bool = True) -> list[str]:
    """Write ``rig`` beside a ``calib.yaml`` in ``directory`` as calibmar's stereo pair
    (:data:`CALIBMAR_NAME` and its ``_stereo`` partner) and the COLMAP fork's ``cameras.txt``
    with ``rig_config.json``; every file atomically. Returns the paths written (4)."""
    directory = os.fspath(directory)
    written = list(write_calibmar(os.path.join(directory, CALIBMAR_NAME), rig, has_port))
    written += write_colmap(os.path.join(directory, COLMAP_CAMERAS_NAME), rig, has_port)
    return written


__all__ = ["CALIBMAR_NAME", "COLMAP_CAMERAS_NAME", "COLMAP_MODELS", "COLMAP_PIXEL_OFFSET",
           "COLMAP_RIG_NAME", "CalibFormatError", "IMAGE_PREFIXES", "PORT_TOLERANCE",
           "PYCOLMAP_WARNING", "calib_dict", "calib_format", "calibmar_partner", "colmap_camera",
           "distortion_model_of",
           "opencv_camera", "read_calibmar", "read_colmap", "read_single_camera", "stereo_extrinsics",
           "colmap_cameras", "read_colmap_rig", "read_covariance_node", "write_calibmar",
           "write_calibration_formats", "write_colmap", "write_colmap_rig", "write_single_camera"]
