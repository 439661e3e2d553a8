"""Tests of eval.core.photos: a user's photos read as linear grey, folders paired by name."""

import cv2
import numpy as np
import pytest

from eval.core.photos import PhotoError, photo_folder, read_pairs, read_photo, srgb_to_linear


def test_8bit_is_decoded_as_srgb_and_16bit_taken_as_linear(tmp_path):
    levels = np.arange(256, dtype=np.uint8).reshape(16, 16)
    cv2.imwrite(str(tmp_path / "a.png"), levels)
    decoded = read_photo(tmp_path / "a.png")
    assert decoded.dtype == np.float32
    np.testing.assert_allclose(decoded, srgb_to_linear(levels / 255.0), rtol=1e-6, atol=1e-7)
    assert decoded[8, 0] == pytest.approx(((128 / 255 + 0.055) / 1.055) ** 2.4, rel=1e-6)
    np.testing.assert_allclose(read_photo(tmp_path / "a.png", "linear"), levels / 255.0, rtol=1e-6)
    wide = (np.arange(256, dtype=np.uint16) * 257).reshape(16, 16)
    cv2.imwrite(str(tmp_path / "b.png"), wide)
    np.testing.assert_allclose(read_photo(tmp_path / "b.png"), wide / 65535.0, rtol=1e-6)


def test_colour_becomes_grey_as_opencv_does(tmp_path):
    rng = np.random.default_rng(1)
    bgr = rng.integers(0, 256, (8, 9, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "c.png"), bgr)
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    np.testing.assert_allclose(read_photo(tmp_path / "c.png", "linear"), grey / 255.0, rtol=1e-6)


def test_unreadable_and_missing(tmp_path):
    (tmp_path / "x.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(PhotoError, match="x.jpg: not an image"):
        read_photo(tmp_path / "x.jpg")
    with pytest.raises(PhotoError, match="no such file"):
        read_photo(tmp_path / "y.jpg")
    (tmp_path / "z.jpg").mkdir()  # a folder with a photo's name is not "no such file"
    with pytest.raises(PhotoError, match="z.jpg: a folder, not a photo"):
        read_photo(tmp_path / "z.jpg")
    with pytest.raises(PhotoError, match="encoding"):
        read_photo(tmp_path / "x.jpg", "gamma")


def _folder(root, left, right, size=(10, 8)):
    for view, names in (("left", left), ("right", right)):
        (root / view).mkdir(parents=True, exist_ok=True)
        for name in names:
            w, h = size[name] if isinstance(size, dict) else size
            cv2.imwrite(str(root / view / name), np.zeros((h, w), np.uint8))
    return root


def test_pairs_by_stem_ignore_other_files(tmp_path):
    root = _folder(tmp_path / "p", ["1.png", "2.jpg"], ["1.tif", "2.png"])
    (root / "left" / "notes.txt").write_text("ignored")
    pairs = photo_folder(root)
    assert pairs.names == ("1", "2")
    images, size = read_pairs(pairs)
    assert size == (10, 8) and len(images) == 2


def test_folder_problems_are_named(tmp_path):
    with pytest.raises(PhotoError, match="no right folder"):
        photo_folder(_only_left(tmp_path / "a"))
    with pytest.raises(PhotoError, match="3.png: no photo of the same name"):
        photo_folder(_folder(tmp_path / "b", ["1.png", "3.png"], ["1.png"]))
    with pytest.raises(PhotoError, match="no photos"):
        photo_folder(_folder(tmp_path / "c", [], []))
    mixed = _folder(tmp_path / "d", ["1.png", "2.png"], ["1.png", "2.png"],
                    {"1.png": (10, 8), "2.png": (12, 8)})
    with pytest.raises(PhotoError, match="12x8 px, but .*1.png is 10x8 px"):
        read_pairs(photo_folder(mixed))


def _only_left(root):
    (root / "left").mkdir(parents=True)
    return root


def test_photo_files_as_they_come(tmp_path):
    """One grey picture stored as a 24-bit BMP, a grey and a colour PNG, a 16-bit TIFF and a
    JPEG whose EXIF orientation says 'turned by 180°': every one reads as the same linear grey
    picture, the JPEG turned as cv2.imread's defaults turn it."""
    from PIL import Image

    from eval.core.photos import exif_orientation, srgb_to_linear

    rng = np.random.default_rng(5)
    grey = np.kron(rng.integers(20, 236, (6, 8)), np.ones((8, 8))).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "bgr.bmp"), cv2.merge([grey] * 3))
    cv2.imwrite(str(tmp_path / "grey.png"), grey)
    cv2.imwrite(str(tmp_path / "colour.png"), cv2.merge([grey] * 3))
    cv2.imwrite(str(tmp_path / "deep.tif"), grey.astype(np.uint16) * 257)
    stored = Image.fromarray(grey[::-1, ::-1].copy())  # the sensor's pixels, upside down
    exif = stored.getexif()
    exif[0x0112] = 3
    stored.save(tmp_path / "turned.jpg", exif=exif.tobytes(), quality=100, subsampling=0)
    expected = srgb_to_linear(grey / 255.0)
    for name in ("bgr.bmp", "grey.png", "colour.png"):
        np.testing.assert_allclose(read_photo(tmp_path / name), expected, atol=1e-6)
    np.testing.assert_allclose(read_photo(tmp_path / "deep.tif"), grey / 255.0, atol=1e-6)
    assert exif_orientation(tmp_path / "turned.jpg") == 3
    turned = read_photo(tmp_path / "turned.jpg")
    assert turned.shape == grey.shape
    assert np.abs(turned - expected).max() < 0.05  # JPEG, turned back upright


def test_one_cameras_photos_share_one_orientation(tmp_path):
    from PIL import Image

    from eval.core.photos import photo_files

    for k, tag in enumerate((1, 1, 6)):
        image = Image.fromarray(np.full((16, 24), 100, np.uint8))
        exif = image.getexif()
        exif[0x0112] = tag
        image.save(tmp_path / f"{k}.jpg", exif=exif.tobytes())
    with pytest.raises(PhotoError, match=r"2\.jpg: EXIF orientation 6, but the other photos"):
        photo_files(tmp_path)


def test_a_truncated_jpeg_and_a_float_image_with_nan_are_refused(tmp_path):
    """OpenCV reads a JPEG cut short with a warning on stderr only (the missing rows grey), and
    NaN pixels of a float TIFF went on into the measurement: both are one PhotoError."""
    rng = np.random.default_rng(2)
    image = rng.integers(0, 256, (120, 160), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "whole.jpg"), image)
    data = (tmp_path / "whole.jpg").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 2])
    assert read_photo(tmp_path / "whole.jpg").shape == image.shape
    assert cv2.imread(str(tmp_path / "cut.jpg")) is not None  # what OpenCV alone accepts
    with pytest.raises(PhotoError, match=r"cut\.jpg: a truncated JPEG"):
        read_photo(tmp_path / "cut.jpg")
    floats = rng.random((30, 40)).astype(np.float32)
    floats[3, 4], floats[5, 6] = np.nan, np.inf
    cv2.imwrite(str(tmp_path / "nan.tiff"), floats)
    with pytest.raises(PhotoError, match=r"nan\.tiff: 2 pixel\(s\) are NaN or infinite"):
        read_photo(tmp_path / "nan.tiff")


def test_16bit_photos_read_as_linear_are_said(tmp_path):
    """16-bit files that hold sRGB were read as linear without a word."""
    from eval.core.photos import encoding_note

    cv2.imwrite(str(tmp_path / "deep.png"), np.full((8, 8), 30000, np.uint16))
    cv2.imwrite(str(tmp_path / "flat.png"), np.full((8, 8), 100, np.uint8))
    assert "--encoding srgb" in encoding_note(tmp_path / "deep.png", "auto")
    assert encoding_note(tmp_path / "deep.png", "linear") is None
    assert encoding_note(tmp_path / "flat.png", "auto") is None
