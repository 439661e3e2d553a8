"""Messages of eval calibrate that name the cause. What a housing calibration that found no
housing says (eval.calibrate.causes): the adjustment's reason in words a user can act on, with
the likely causes — the --intrinsics file, water with the index of air — and the cure of two
parameters the boards cannot tell apart kept for that case alone; folders that are not a pair
given to --model absorbed."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from eval.calibrate.causes import housing_failure


def test_the_likely_causes_are_named():
    args = SimpleNamespace(intrinsics="air/calib.yaml", n_water=1.0)
    text = str(housing_failure("water", ValueError(
        "cam1 centre lies on the water side of the port's first interface (normal·centre = "
        "0 mm >= distance = -4.98e+14 mm)"), args))
    assert text.startswith("water: the adjustment moved the port behind a camera"), text
    assert "--intrinsics air/calib.yaml is the in-air calibration of another camera" in text
    assert "--n-water 1 is no water" in text and "e+14" not in text
    text = str(housing_failure("water", np.linalg.LinAlgError("Singular matrix"),
                               SimpleNamespace(intrinsics="a.yaml", n_water=1.33)))
    assert "singular normal equations" in text and "the design port" in text, text
    assert not text.startswith("water: Singular matrix")


def test_a_correlation_keeps_its_own_cure():
    text = str(housing_failure("water", "port.distance and port.thickness[0] are correlated at "
                               "+0.9999: these boards cannot tell them apart",
                               SimpleNamespace(intrinsics="a.yaml", n_water=1.33), "render"))
    assert "likely" not in text and "render more varied poses" in text, text


def test_model_absorbed_names_a_folder_that_is_not_a_pair(tmp_path, capsys):
    """``--model absorbed`` of one camera's photos or of photos of three cameras: named for
    what they are, with the command that takes them (it said "no left and no right folder")."""
    import cv2

    from eval.cli import main as eval_main

    image = np.zeros((20, 20), np.uint8)
    for folder in ("one", "three/cam0", "three/cam1", "three/cam2"):
        (tmp_path / folder).mkdir(parents=True)
        cv2.imwrite(str(tmp_path / folder / "00.jpg"), image)
    board = ["--squares", "7x6", "--square-mm", "60", "--model", "absorbed"]
    for folder, fragment in (("one", "holds one camera's photos"),
                             ("three", "holds photos of 3 cameras (cam0/, cam1/, cam2/)")):
        assert eval_main(["calibrate", str(tmp_path / folder), *board, "--out",
                          str(tmp_path / "out"), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and fragment in err[0] and "left/ and right/" in err[0], err
    assert not (tmp_path / "out").exists()


def test_the_help_names_every_kind_of_folder(capsys):
    """``eval calibrate --help`` named a pair's folders only (issue 53): one camera's folder and
    N cameras' cam0/ cam1/ … are read too."""
    from eval.cli import main as eval_main

    assert eval_main(["calibrate", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "DIR/cam0/ DIR/cam1/" in text and "one camera's photos in DIR" in text, text
