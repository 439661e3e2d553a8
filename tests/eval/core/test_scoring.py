"""eval.core.scoring's readers of user files."""

from __future__ import annotations

import numpy as np
import pytest

from eval.core.scoring import read_pixel_pairs
from synth.infra.cli import CLIError


def test_pixel_pairs_with_a_byte_order_mark_are_read(tmp_path):
    """Excel's "CSV UTF-8" starts with a UTF-8 byte-order mark: the first column is still
    ``u_left`` (it was "missing column(s) u_left")."""
    text = "u_left,v_left,u_right,v_right\n1.5,2,3,4\n5,6,7,8.25\n"
    with_bom = tmp_path / "bom.csv"
    with_bom.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    plain = tmp_path / "plain.csv"
    plain.write_text(text, encoding="utf-8")
    expected = np.array([[1.5, 2, 3, 4], [5, 6, 7, 8.25]])
    np.testing.assert_array_equal(read_pixel_pairs(str(with_bom)), expected)
    np.testing.assert_array_equal(read_pixel_pairs(str(plain)), expected)


def test_pixel_pairs_missing_a_column_are_still_refused(tmp_path):
    path = tmp_path / "bom.csv"
    path.write_bytes(b"\xef\xbb\xbfv_left,u_right,v_right\n2,3,4\n")
    with pytest.raises(CLIError, match="missing column.s. u_left"):
        read_pixel_pairs(str(path))
