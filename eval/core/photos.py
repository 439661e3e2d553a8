"""A user's photos: read one image as grey, and pair a left and a right folder by file name.

Formats: whatever ``cv2.imread`` reads (PNG 8- or 16-bit, JPEG, TIFF, BMP, …), turned as their
EXIF orientation says (as ``cv2.imread``'s defaults do; one camera's photos must share one
orientation: :func:`check_orientations`). Colour images (a 24-bit BMP holding grey too) become
grey with ``cv2.cvtColor(…, COLOR_BGR2GRAY)`` (0.299 R + 0.587 G + 0.114 B on the stored
values: what an OpenCV user gets from ``cv2.imread(path, cv2.IMREAD_GRAYSCALE)``, but keeping
16 bits where the file has them). The grey values are then made **linear** (float32, 1 = the
file's white), because the target detector's intensity centroids assume linear radiometry:
``encoding="auto"`` decodes 8-bit files as sRGB (what cameras and image editors store; on the
paper plane's JPEG the sRGB-encoded centroids were 0.040 px RMS off, the decoded ones 0.015 px,
the same as the 16-bit linear render's 0.014 px) and takes 16-bit and float files as linear
(scientific cameras, raw conversions, this project's renders); ``"srgb"`` and ``"linear"``
force one reading.

Layout of a photo folder: ``DIR/left/`` and ``DIR/right/``, files paired by name (``0001.jpg``
↔ ``0001.jpg``; the extension may differ, the stem may not). Every problem is one
:class:`PhotoError` naming the file or folder.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np
from synth.infra.images import imread

#: File extensions taken as photos (lower case); anything else in a folder is ignored.
PHOTO_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm")


class PhotoError(ValueError):
    """A photo or photo folder that cannot be used."""


#: How the stored values of a photo are read (module docs).
PHOTO_ENCODINGS = ("auto", "srgb", "linear")


ENCODING_HELP = ("how the photos' values are read: auto (default: 8-bit files are sRGB and "
                 "decoded to linear, 16-bit and float files are linear), srgb, linear")


def add_encoding_option(parser) -> None:
    """``--encoding auto|srgb|linear`` of the commands that read a user's photos."""
    parser.add_argument("--encoding", choices=PHOTO_ENCODINGS, default="auto", help=ENCODING_HELP)


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding of values in [0, 1]."""
    x = np.asarray(values, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def read_photo(path, encoding: str = "auto") -> np.ndarray:
    """The photo at ``path`` as a 2D linear grey ``float32`` array, 1 = the file's white
    (colour converted by ``cv2.cvtColor``, alpha dropped; ``encoding`` in
    :data:`PHOTO_ENCODINGS`, module docs). :class:`PhotoError` if it is missing or
    unreadable."""
    import cv2

    if encoding not in PHOTO_ENCODINGS:
        raise PhotoError(f"photo encoding {encoding!r}: choose from {', '.join(PHOTO_ENCODINGS)}")

    path = os.fspath(path)
    if os.path.isdir(path):
        raise PhotoError(f"{path}: a folder, not a photo")
    if not os.path.isfile(path):
        raise PhotoError(f"{path}: no such file")
    # ANYDEPTH | ANYCOLOR: 16-bit and float kept, and the EXIF orientation applied as
    # cv2.imread's defaults apply it (IMREAD_UNCHANGED would ignore it)
    image = imread(path, cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if image is None or image.size == 0:
        raise PhotoError(f"{path}: not an image OpenCV can read")
    truncated = jpeg_truncation(path)
    if truncated:
        raise PhotoError(f"{path}: {truncated}")
    if image.ndim == 3:
        channels = image.shape[2]
        if channels == 1:
            image = image[:, :, 0]
        elif channels in (3, 4):
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY if channels == 4 else cv2.COLOR_BGR2GRAY)
        else:
            raise PhotoError(f"{path}: {channels} channels; expected grey, BGR or BGRA")
    if image.dtype in (np.uint8, np.uint16):
        white = float(np.iinfo(image.dtype).max)
        srgb = encoding == "srgb" or (encoding == "auto" and image.dtype == np.uint8)
        levels = np.arange(int(white) + 1) / white  # a lookup table: one decode per level
        table = (srgb_to_linear(levels) if srgb else levels).astype(np.float32)
        return table[image]
    image = image.astype(np.float32)
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise PhotoError(f"{path}: {bad} pixel(s) are NaN or infinite (a float image must hold "
                         f"finite values)")
    return np.ascontiguousarray(srgb_to_linear(np.clip(image, 0, 1)).astype(np.float32)
                                if encoding == "srgb" else image)


def _photos_in(folder: str) -> dict:
    """``{stem: file name}`` of the photos in ``folder``; two files with one stem are refused."""
    if not os.path.isdir(folder):
        raise PhotoError(f"{folder}: no such folder")
    out = {}
    for name in sorted(os.listdir(folder)):
        stem, ext = os.path.splitext(name)
        if ext.lower() not in PHOTO_EXTENSIONS or name.startswith("."):
            continue
        if stem in out:
            raise PhotoError(f"{folder}: two photos named {stem} ({out[stem]}, {name})")
        out[stem] = name
    return out


#: Bytes at a JPEG's end searched for its end-of-image marker before the file is decoded again
#: to tell a truncated file from one with data after the marker.
JPEG_TAIL_BYTES = 4096


def jpeg_truncation(path) -> str | None:
    """Why a JPEG file is cut short, or None (also for other formats): OpenCV decodes a truncated
    JPEG with a warning on stderr only (libjpeg's "Premature end of JPEG file"), the missing
    rows grey. A file whose last :data:`JPEG_TAIL_BYTES` bytes hold no end-of-image marker
    (FF D9) is decoded again with Pillow, which refuses a truncated file."""
    with open(path, "rb") as fh:
        if fh.read(2) != b"\xff\xd8":
            return None
        fh.seek(0, os.SEEK_END)
        size = fh.tell()
        fh.seek(max(0, size - JPEG_TAIL_BYTES))
        if b"\xff\xd9" in fh.read():
            return None
    from PIL import Image

    try:
        with Image.open(path) as image:
            image.load()
    except (OSError, ValueError, SyntaxError) as exc:
        return f"a truncated JPEG ({' '.join(str(exc).split()) or 'cut short'}; {size} bytes)"
    return None


def encoding_note(path, encoding: str) -> str | None:
    """A note when ``encoding`` ``auto`` takes the photo at ``path`` (the first of a set) as
    linear because it has 16 bits: some converters store sRGB-encoded values in 16-bit files,
    and nothing in the file says which (``--encoding srgb`` reads those)."""
    import cv2

    if encoding != "auto":
        return None
    image = imread(os.fspath(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if image is None or image.dtype != np.uint16:
        return None
    return (f"note: 16-bit photos ({os.path.basename(os.fspath(path))} …) are read as linear "
            f"values; if they hold sRGB-encoded values (as some raw converters write), give "
            f"--encoding srgb")


def exif_orientation(path) -> int:
    """The EXIF orientation tag of a photo (1 = as stored; 3 turned 180°; 6 and 8 turned 90°;
    2, 4, 5, 7 mirrored), 1 when it has none."""
    from PIL import Image

    try:
        with Image.open(path) as image:
            return int(image.getexif().get(0x0112, 1) or 1)
    except (OSError, ValueError, SyntaxError):
        return 1


def check_orientations(files) -> None:
    """:class:`PhotoError` when one camera's photos carry different EXIF orientations: each
    is turned as its tag says (as ``cv2.imread`` does), so photos of one sensor would be
    calibrated in differently turned frames."""
    tags = {f: exif_orientation(f) for f in files}
    if len(set(tags.values())) > 1:
        common = max(set(tags.values()), key=list(tags.values()).count)
        odd = [f for f, t in tags.items() if t != common]
        more = f" and {len(odd) - 3} more" if len(odd) > 3 else ""
        raise PhotoError(f"{', '.join(odd[:3])}{more}: EXIF orientation "
                         f"{tags[odd[0]]}, but the other photos of this camera have "
                         f"{common}; photos are turned as their EXIF orientation says (as "
                         f"cv2.imread does), so one camera's photos must share it (remove the "
                         f"tag, e.g. exiftool -Orientation= FILE)")


def photo_files(folder) -> list[str]:
    """The photos of one camera's ``folder``, sorted by name (two files with one stem are
    refused, and photos whose EXIF orientations differ: :func:`check_orientations`);
    :class:`PhotoError` when it holds none."""
    folder = os.fspath(folder)
    found = _photos_in(folder)
    if not found:
        raise PhotoError(f"{folder}: no photos (expected {', '.join(PHOTO_EXTENSIONS)} files)")
    files = [os.path.join(folder, found[stem]) for stem in sorted(found)]
    check_orientations(files)
    return files


@dataclass(frozen=True)
class PhotoPairs:
    """Pairs of a photo folder: ``names`` (the shared stems, sorted), ``left`` / ``right`` the
    file paths, ``size`` ``(width, height)`` px of each camera's photos."""

    path: str
    names: tuple
    left: tuple
    right: tuple

    def read(self, index: int, encoding: str = "auto") -> tuple[np.ndarray, np.ndarray]:
        """The pair ``index`` as linear grey arrays (:func:`read_photo`)."""
        return read_photo(self.left[index], encoding), read_photo(self.right[index], encoding)


def pair_folders(left_dir, right_dir, what: str = "photo") -> PhotoPairs:
    """Pair the photos of ``left_dir`` and ``right_dir`` by stem. :class:`PhotoError` when a
    folder has no photos or a photo has no partner (the first few are named)."""
    left_dir, right_dir = os.fspath(left_dir), os.fspath(right_dir)
    left, right = _photos_in(left_dir), _photos_in(right_dir)
    if not left and not right:
        raise PhotoError(f"{left_dir}, {right_dir}: no {what}s (expected "
                         f"{', '.join(PHOTO_EXTENSIONS)} files)")
    alone = ([f"{left_dir}/{left[s]}" for s in sorted(set(left) - set(right))]
             + [f"{right_dir}/{right[s]}" for s in sorted(set(right) - set(left))])
    if alone:
        more = f" and {len(alone) - 3} more" if len(alone) > 3 else ""
        raise PhotoError(f"{', '.join(alone[:3])}{more}: no {what} of the same name in the other "
                         f"camera's folder (pairs are matched by file name)")
    names = tuple(sorted(left))
    check_orientations([os.path.join(left_dir, left[s]) for s in names])
    check_orientations([os.path.join(right_dir, right[s]) for s in names])
    return PhotoPairs(os.path.dirname(left_dir.rstrip("/")) or ".", names,
                      tuple(os.path.join(left_dir, left[s]) for s in names),
                      tuple(os.path.join(right_dir, right[s]) for s in names))


def photo_folder(path) -> PhotoPairs:
    """The pairs of a photo folder ``path`` (``path/left``, ``path/right``)."""
    path = os.fspath(path)
    if not os.path.isdir(path):
        raise PhotoError(f"{path}: no such folder")
    missing = [sub for sub in ("left", "right") if not os.path.isdir(os.path.join(path, sub))]
    if missing:
        raise PhotoError(f"{path}: no {' and no '.join(missing)} folder (a photo folder holds "
                         f"left/ and right/, photos paired by name)")
    pairs = pair_folders(os.path.join(path, "left"), os.path.join(path, "right"))
    return PhotoPairs(path, pairs.names, pairs.left, pairs.right)


#: The folders of one camera each in a photo folder of N cameras: ``cam0``, ``cam1``, …
CAMERA_FOLDER = re.compile(r"^cam(\d+)$")


def camera_folder_names(path) -> tuple:
    """The camera folders of a photo folder of N cameras (``cam0/``, ``cam1/``, … in order; an
    empty tuple when it holds none). :class:`PhotoError` when their numbers do not run 0, 1, …
    without a gap (``cam3/`` with no ``cam2/``) or there is one only."""
    path = os.fspath(path)
    numbers = sorted(int(m.group(1)) for m in (CAMERA_FOLDER.match(n) for n in os.listdir(path))
                     if m and os.path.isdir(os.path.join(path, m.group(0))))
    if not numbers:
        return ()
    missing = [k for k in range(numbers[-1] + 1) if k not in numbers]
    if missing:
        raise PhotoError(f"{path}/cam{numbers[-1]}: there is no cam{missing[0]}/ folder (the "
                         f"cameras are cam0/, cam1/, … without a gap)")
    if len(numbers) < 2:
        raise PhotoError(f"{path}: one camera folder (cam0/); a rig needs two or more (one "
                         f"camera's photos: give the folder that holds them)")
    return tuple(f"cam{k}" for k in numbers)


def read_camera_photos(path, names, encoding: str = "auto") -> tuple[list, tuple, tuple]:
    """Every capture of a photo folder of N cameras (one folder per camera, photos matched by
    file name): ``([(cam0, cam1, …), …], (width, height), stems)``. :class:`PhotoError` when a
    camera's folder has no photos, a photo has no partner of the same name in every other
    camera's folder (the camera and file named), or the photos differ in size."""
    path = os.fspath(path)
    found = {name: _photos_in(os.path.join(path, name)) for name in names}
    for name, photos in found.items():
        if not photos:
            raise PhotoError(f"{path}/{name}: no photos (expected "
                             f"{', '.join(PHOTO_EXTENSIONS)} files)")
    stems = sorted(set().union(*found.values()))
    for name, photos in found.items():
        lacking = [s for s in stems if s not in photos]
        if lacking:
            other = next(n for n in names if lacking[0] in found[n])
            raise PhotoError(f"{path}/{name}: {len(photos)} photos, {len(stems)} captures; no "
                             f"photo {lacking[0]}.* beside {path}/{other}/{found[other][lacking[0]]}"
                             f" (captures are matched by file name)")
    for name in names:
        check_orientations([os.path.join(path, name, found[name][s]) for s in stems])
    images, size = [], None
    for stem in stems:
        views = []
        for name in names:
            file = os.path.join(path, name, found[name][stem])
            image = read_photo(file, encoding)
            shape = (image.shape[1], image.shape[0])
            if size is None:
                size = (shape, file)
            elif shape != size[0]:
                raise PhotoError(f"{file}: {shape[0]}x{shape[1]} px, but {size[1]} is "
                                 f"{size[0][0]}x{size[0][1]} px (the rig model needs one size)")
            views.append(image)
        images.append(tuple(views))
    return images, size[0], tuple(stems)


def read_pairs(pairs: PhotoPairs, encoding: str = "auto") -> tuple[list, tuple]:
    """Every pair read: ``([(left, right), …], (width, height))``. :class:`PhotoError` when one
    camera's photos differ in size (the first that differs is named)."""
    images, size = [], {}
    for index in range(len(pairs.names)):
        pair = pairs.read(index, encoding)
        for view, (image, file) in enumerate(zip(pair, (pairs.left[index], pairs.right[index]))):
            shape = (image.shape[1], image.shape[0])
            first = size.setdefault(view, (shape, file))
            if shape != first[0]:
                raise PhotoError(f"{file}: {shape[0]}x{shape[1]} px, but {first[1]} is "
                                 f"{first[0][0]}x{first[0][1]} px (one camera's photos must all "
                                 f"have one size)")
        images.append(pair)
    if size and size[0][0] != size[1][0]:
        raise PhotoError(f"{pairs.path}: the left photos are {size[0][0][0]}x{size[0][0][1]} px, the "
                         f"right {size[1][0][0]}x{size[1][0][1]} px; the rig model needs one size")
    return images, size[0][0] if size else (0, 0)


__all__ = ["CAMERA_FOLDER", "ENCODING_HELP", "PHOTO_ENCODINGS", "PHOTO_EXTENSIONS", "PhotoError",
           "PhotoPairs",
           "JPEG_TAIL_BYTES", "add_encoding_option", "check_orientations", "encoding_note",
           "exif_orientation",
           "jpeg_truncation", "pair_folders",
           "photo_files", "photo_folder", "read_camera_photos", "camera_folder_names", "read_pairs",
           "read_photo", "srgb_to_linear"]
