"""``python -m eval interface``'s ``--media`` and ``--free``: what cannot describe layers in
front of a camera is refused with one ``error:`` line naming it, exit 2, nothing written."""

from __future__ import annotations

import pytest

from eval.__main__ import main as eval_main


@pytest.mark.parametrize("media, free, message", [
    ("air,water", None, "at least three media"),
    ("air,glass,water", None, "'glass' needs a thickness"),
    ("air:5,glass:10,water", None, "take no thickness"),
    ("air,glass:-3,water", None, "thickness must be positive"),
    ("air,steel:10,water", None, "'steel' is not a medium"),
    ("air,0.8:10,water", None, "not a refractive index"),
    ("air,glass:10,glass:5,water", None, "have one index"),
    ("air,glass:10,water:300,glass:10,air", "normal,distance", "only shift a ray"),
    ("air,glass:10,water:300,glass:10,air", "normal,thickness:glass", "2 layers of 'glass'"),
    ("air,glass:10,water:300,glass:10,air", "normal,thickness:3", "are 0 … 2"),
    ("air,glass:10,water", "distance", "the normal is always estimated"),
    ("air,glass:10,water", "normal,index", "choose from normal, distance"),
])
def test_layers_that_are_not_layers(tmp_path, capsys, media, free, message):
    argv = ["interface", str(tmp_path), "--intrinsics", str(tmp_path / "camera.yaml"),
            "--squares", "7x6", "--square-mm", "60", "--media", media,
            "--out", str(tmp_path / "out"), "--no-progress"]
    code = eval_main(argv + (["--free", free] if free else []))
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert message in err[0], err[0]
    assert not (tmp_path / "out").exists()
