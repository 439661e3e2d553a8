"""What ``eval measure`` starts from, checked before any work: the calibration
(:func:`synth.formats.calib_yaml.read_calib`) and the photo pairs (one pair of files, or two folders
paired by file name: :func:`eval.core.photos.pair_folders`).

Every problem is a :class:`eval.cli.CLIError` (one ``error:`` line, exit 2) naming the file:
a calibration that cannot be read, a photo that is missing or unreadable, a photo without a
partner, photos of different sizes, photos whose size differs from the calibration's.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from eval.cli import CLIError


@dataclass(frozen=True)
class MeasureInputs:
    """The calibration and the pairs to measure: ``calib_path``, ``rig``
    (:class:`measure.Rig` of two), ``size`` ``(width, height)`` px, and per pair its ``names``
    (the file stems), ``left`` and ``right`` file paths; ``encoding`` how the stored values
    are read (:data:`eval.core.photos.PHOTO_ENCODINGS`); ``rig_covariance`` the calibration's
    :class:`measure.stereo.rig_covariance.RigCovariance` (None: it holds none)."""

    calib_path: str
    rig: object
    size: tuple
    names: tuple
    left: tuple
    right: tuple
    encoding: str = "auto"
    has_port: bool = True
    rig_covariance: object = None

    def read(self, index: int):
        """Pair ``index`` as linear grey float32 arrays (:func:`eval.core.photos.read_photo`
        with the run's ``encoding``)."""
        from eval.core.photos import read_photo

        return (read_photo(self.left[index], self.encoding),
                read_photo(self.right[index], self.encoding))


def read_calibration(path):
    """``(rig, (width, height), has_port, covariance)`` of a calibration file (``has_port``
    false for an in-air calibration, whose port is index-matched air; ``covariance`` None when
    it holds none); CLIError when it cannot be read (a singular covariance included)."""
    from synth.products.dataset import DatasetError, read_calib

    if os.path.isdir(path):
        inside = os.path.join(path, "calib.yaml")
        raise CLIError(f"--calib {path}: a folder; give the calibration file"
                       + (f", e.g. --calib {inside}" if os.path.isfile(inside) else ""))
    if not os.path.isfile(path):
        raise CLIError(f"--calib {path}: no such file")
    try:
        calib = read_calib(path)
    except DatasetError as exc:
        raise CLIError(f"--calib {exc}") from None
    return (calib["rig"], tuple(int(v) for v in calib["size"]), bool(calib["has_port"]),
            calib.get("covariance"))


def photo_pairs(left, right):
    """``(names, left files, right files)`` of the positional LEFT RIGHT: two files (one pair,
    named after the left file's stem) or two folders (paired by file name)."""
    from eval.core.photos import PhotoError, pair_folders

    if os.path.isdir(left) and os.path.isdir(right):
        try:
            pairs = pair_folders(left, right)
        except PhotoError as exc:
            raise CLIError(str(exc)) from None
        return pairs.names, pairs.left, pairs.right
    for path in (left, right):
        if not os.path.exists(path):
            raise CLIError(f"{path}: no such file or folder")
    if os.path.isdir(left) or os.path.isdir(right):
        raise CLIError(f"{left}, {right}: give two photos (one pair) or two folders (pairs by "
                       f"file name), not a photo and a folder")
    return (os.path.splitext(os.path.basename(left))[0],), (left,), (right,)


def load_inputs(calib_path, left, right, encoding: str = "auto") -> MeasureInputs:
    """The checked inputs: every photo is read once here (and again when measured), so that an
    unreadable photo or a wrong size is refused before any work."""
    from eval.core.photos import PhotoError, read_photo

    rig, calib_size, has_port, covariance = read_calibration(calib_path)
    names, lefts, rights = photo_pairs(left, right)
    for files in zip(lefts, rights):
        for file in files:
            try:
                image = read_photo(file, encoding)
            except PhotoError as exc:
                raise CLIError(str(exc)) from None
            size = (image.shape[1], image.shape[0])
            if size != calib_size:
                raise CLIError(f"{file}: {size[0]}x{size[1]} px, but the calibration "
                               f"{calib_path} is for {calib_size[0]}x{calib_size[1]} px images "
                               f"(photos must be measured at the calibrated size)")
    return MeasureInputs(os.fspath(calib_path), rig, calib_size, tuple(names), tuple(lefts),
                         tuple(rights), encoding, has_port, covariance)


__all__ = ["MeasureInputs", "load_inputs", "photo_pairs", "read_calibration"]
