"""Provenance of results: the versions of everything a dataset or a report depends on."""

from __future__ import annotations

import importlib.metadata as metadata
import platform

#: Distributions whose versions go into every manifest and report (those installed).
TRACKED_DISTRIBUTIONS = ("refractive-stereo", "numpy", "scipy", "opencv-python-headless",
                         "opencv-python", "mitsuba", "drjit", "open3d-cpu", "open3d",
                         "matplotlib", "tqdm")


def package_versions() -> dict:
    """``{"python", "platform", <distribution>: version…, "cv2"}`` for manifests and reports."""
    import cv2

    out = {"python": platform.python_version(), "platform": platform.platform()}
    for dist in TRACKED_DISTRIBUTIONS:
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    out["cv2"] = cv2.__version__
    return out
