"""A user's own detections files (eval.core.detections) and the views that repeat another's
(eval.calibrate.sources.repeated_views)."""

from __future__ import annotations

import numpy as np
import pytest

from eval.calibrate.sources import repeat_lines, repeated_views
from eval.core.detections import (DetectionError, detection_layout, read_detection_file,
                                  read_detections)
from measure.calibration.air import Detections


def test_both_line_forms_and_the_pixel_origin(tmp_path):
    plain = tmp_path / "plain.txt"
    plain.write_text("# u v\n10.5\t20.25\n\n11.5 21.25  # the second point\n")
    ids, uv = read_detection_file(plain, 4)
    np.testing.assert_array_equal(ids, [0, 1])
    np.testing.assert_allclose(uv, [[10.5, 20.25], [11.5, 21.25]])
    numbered = tmp_path / "numbered.csv"
    numbered.write_text("id,u,v\n3,5.0,6.0\n1,7.0,8.0\n")
    ids, uv = read_detection_file(numbered, 4, origin=1.0)  # MATLAB: top-left centre at 1, 1
    np.testing.assert_array_equal(ids, [1, 3])
    np.testing.assert_allclose(uv, [[6.0, 7.0], [4.0, 5.0]])


@pytest.mark.parametrize("text, message", [
    ("1 2\n3\n", "line 2: expected 'u v' or 'id u v'"),
    ("1 x\n", "line 1: not a number"),
    ("0.5 1 2\n", "line 1: the point id must be an integer"),
    ("7 1 2\n", "point 7 is not on the board"),
    ("1 1 2\n1 3 4\n", "point 1 is given twice"),
    ("1 nan\n", "line 1: u and v must be finite"),
    ("", "no detections"),
])
def test_bad_files_are_named_with_their_line(tmp_path, text, message):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(DetectionError, match=message) as caught:
        read_detection_file(path, 4)
    assert str(path) in str(caught.value)


def test_layouts(tmp_path):
    (tmp_path / "one").mkdir()
    (tmp_path / "one" / "a.txt").write_text("1 2\n")
    assert detection_layout(tmp_path / "one") == ()
    for side in ("left", "right"):
        (tmp_path / "pair" / side).mkdir(parents=True)
        (tmp_path / "pair" / side / "01.txt").write_text("1 2\n3 4\n")
    (tmp_path / "pair" / "right" / "02.txt").write_text("1 2\n")
    names, views, per_view = read_detections(tmp_path / "pair", 4)
    assert views == ("left", "right") and names == ["01", "02"]
    assert len(per_view[1][0][0]) == 0 and len(per_view[1][1][0]) == 1  # no left 02
    (tmp_path / "half" / "left").mkdir(parents=True)
    with pytest.raises(DetectionError, match="no right/"):
        detection_layout(tmp_path / "half")


def test_repeated_views_are_named_per_pose():
    rng = np.random.default_rng(0)
    a, b, c = (rng.uniform(0, 100, (6, 2)) for _ in range(3))
    ids = np.arange(6)
    detections = Detections(
        [[ids, ids]] * 5,
        [[a, b], [c, a + 1], [a.copy(), b.copy()], [c + 2, a + 1], [b, b]])
    repeats = repeated_views(detections)
    names = ["p0", "p1", "p2", "p3", "p4"]
    assert repeat_lines(repeats, names) == [
        "p2 repeats p0 (both photos)", "p3's right photo repeats p1's",
        "p4's right photo is its left (the same photo twice)"]
    one = Detections([[ids, np.empty(0, int)]] * 3,
                     [[a, np.empty((0, 2))], [b, np.empty((0, 2))], [a, np.empty((0, 2))]])
    assert repeat_lines(repeated_views(one, (0,)), ["x", "y", "z"], ("",)) == ["z repeats x"]
