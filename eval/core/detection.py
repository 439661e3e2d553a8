"""The target detector's command-line options and how they are applied, shared by ``eval run``
and ``eval measure``: ``--threshold-fraction``, ``--max-elongation``, ``--max-area-ratio`` and
``--median-filter`` (:func:`add_detector_options`), and one view detected with them
(:func:`detect_view`).

Units: image units (whatever the image stores: linear radiance, 8- or 16-bit codes), pixels.
"""

from __future__ import annotations

import argparse

import numpy as np

from synth.infra.cli import finite_float

#: argparse type of --max-elongation and --max-area-ratio (a blob's axis or area ratio).
ABOVE_ONE = finite_float(1.0, strict=True, description="finite (> 1)")
#: ``args`` attributes of the detector options, with their defaults (nothing given).
DETECTOR_OPTIONS = {"threshold_fraction": None, "max_elongation": None, "max_area_ratio": None,
                    "median_filter": 0}


def fraction(text: str) -> float:
    """argparse type: a number strictly between 0 and 1."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1 (exclusive), got {text}")
    return value


def add_detector_options(parser) -> None:
    """The target detector's four options (defaults: the detector's own; see
    :data:`DETECTOR_OPTIONS`)."""
    parser.add_argument("--threshold-fraction", type=fraction, default=None, metavar="F",
                        help="detect with a fixed threshold F of the way from the background "
                             "(median) to the targets' level (99.99th percentile) instead of the "
                             "automatic one (median + 5 noise sigmas, or a quarter of the "
                             "targets' level on a speckled background such as scattering water)")
    parser.add_argument("--max-elongation", type=ABOVE_ONE, default=None, metavar="E",
                        help="blobs more elongated than E (major/minor axis) are examined for "
                             "merged targets (default 1.6): merged when their outline has a "
                             "waist or a hole; a single target seen obliquely has neither")
    parser.add_argument("--median-filter", type=int, choices=(3, 5), default=0, metavar="K",
                        help="median-filter each view (K×K, 3 or 5) before detection: removes "
                             "the fireflies of lights seen through scattering water (lit "
                             "targets) that pull the centroids; default: no filter")
    parser.add_argument("--max-area-ratio", type=ABOVE_ONE, default=None, metavar="A",
                        help="blobs larger than A times the median blob are examined for merged "
                             "targets (default 2.5): merged when their outline has a waist or a "
                             "hole; a near target, larger than the others, has neither")


def median_filtered(image, size: int) -> np.ndarray:
    """``image`` median-filtered ``size`` × ``size`` (3 or 5; ``cv2.medianBlur``): 8- and 16-bit
    images keep their type (the detector then still knows their levels are integers), anything
    else becomes float32; ``size`` 0 returns the image unchanged."""
    if not size:
        return image
    import cv2

    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16):
        image = np.asarray(image, dtype=np.float32)
    return cv2.medianBlur(np.ascontiguousarray(image), int(size))


def detect_view(image, threshold_fraction: float | None = None,
                max_elongation: float | None = None, max_area_ratio: float | None = None,
                median_filter: int = 0, floor_fraction: float = 0.0,
                return_labels: bool = False):
    """The targets of one view (:func:`measure.detect_targets`) with the detector options:
    ``median_filter`` first (:func:`median_filtered`), a fixed threshold at
    ``threshold_fraction`` of the way from the background to the targets' level
    (:func:`measure.images.detect.fractional_threshold`) or the automatic one (None), and the merge
    tests' limits (None: the detector's defaults); ``floor_fraction``: the automatic threshold
    is at least that fraction of the way to the targets' level (JPEG ringing; see
    :func:`measure.detect_targets`)."""
    from measure import detect_targets
    from measure.images.detect import MERGE_AREA_RATIO, MERGE_ELONGATION, fractional_threshold

    image = median_filtered(image, median_filter)
    threshold = (None if threshold_fraction is None
                 else fractional_threshold(image, threshold_fraction))
    return detect_targets(image, threshold=threshold,
                          merge_elongation=MERGE_ELONGATION if max_elongation is None
                          else max_elongation,
                          merge_area_ratio=MERGE_AREA_RATIO if max_area_ratio is None
                          else max_area_ratio, floor_fraction=floor_fraction,
                          return_labels=return_labels)


__all__ = ["ABOVE_ONE", "DETECTOR_OPTIONS", "add_detector_options", "detect_view", "fraction",
           "median_filtered"]
