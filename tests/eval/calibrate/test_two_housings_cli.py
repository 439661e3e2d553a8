"""``python -m eval calibrate`` of photos behind two housings (``--port-distance LEFT,RIGHT``):
the options that give one shared port's distance are refused with one line before any photo
is read."""

from __future__ import annotations

import pytest

from eval.__main__ import main as eval_main

PHOTOS = ["--intrinsics", "calib.yaml", "--squares", "7x6", "--square-mm", "60"]


@pytest.mark.parametrize("extra, fragment", [
    (["--port-distance", "60,80", "--start-distance", "90"],
     "--start-distance does not apply to two housings: give each port's distance with "
     "--port-distance LEFT,RIGHT"),
    (["--port-distance", "60,80", "--design-port", "thickness=6,distance=90"],
     "--design-port distance= does not apply to two housings"),
    (["--port-distance", "60,80,90"], "3 values for 2 cameras"),
])
def test_one_ports_distance_is_refused_for_two_housings(tmp_path, monkeypatch, capsys, extra,
                                                         fragment):
    for side in ("left", "right"):
        (tmp_path / "photos" / side).mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    try:
        code = eval_main(["calibrate", "photos", *PHOTOS, *extra, "--out", "out",
                          "--no-progress"])
    except SystemExit as exc:  # argparse's own refusal of a bad value
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
    assert not (tmp_path / "out").exists()
