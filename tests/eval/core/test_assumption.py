"""The water index from temperature and salinity where the command lines take one:
``eval run --assume n_water=T=…,S=…`` and ``synth scene --n-water T=…,S=…`` (the argparse type
:func:`synth.infra.cli.water_index_argument`); the computed index is shown to the user once."""

from __future__ import annotations

import argparse

import pytest

from eval.cli import build_parser
from eval.core.assumption import parse_assumptions
from eval.run.config import RunConfig
from measure.calibration.water_index import water_index
from synth.infra.cli import WaterIndex, water_index_argument
from synth.commands import main as synth_main


def test_assume_n_water_from_temperature_and_salinity():
    notes = []
    values = parse_assumptions(["n_water=T=12,S=35,wavelength=500", "n_glass=1.5"], notes)
    assert float(values["n_water"][0]) == water_index(12, 35, 500)
    assert float(values["n_glass"][0]) == 1.5
    assert notes == [f"n_water = {water_index(12, 35, 500):.5f} from T=12 °C, S=35 PSU, 500 nm "
                     f"(Quan & Fry 1995)"]
    assert float(parse_assumptions(["n_water=1.34"])["n_water"][0]) == 1.34


@pytest.mark.parametrize("item, word", [("n_water=T=35,S=35", "temperature 35"),
                                        ("n_water=T=12", "salinity missing")])
def test_assume_n_water_refused(item, word):
    with pytest.raises(ValueError, match=f"--assume '{item}': .*{word}"):
        parse_assumptions([item])


def test_run_config_carries_the_note():
    args = build_parser().parse_args(["run", "scenes/paper_plane.xml",
                                      "--assume", "n_water=T=12,S=35"])
    config = RunConfig.from_args(args)
    assert config.assumptions["n_water"][0] == water_index(12, 35)
    assert config.assumption_notes == (
        "n_water = 1.34152 from T=12 °C, S=35 PSU, 550 nm (Quan & Fry 1995)",)


def test_water_index_argument():
    plain = water_index_argument("1.339")
    assert plain == 1.339 and isinstance(plain, WaterIndex) and plain.note is None
    computed = water_index_argument("T=4,S=0")
    assert computed == water_index(4, 0) and "T=4 °C, S=0 PSU" in computed.note
    with pytest.raises(argparse.ArgumentTypeError, match="wavelength 800"):
        water_index_argument("T=4,S=0,wavelength=800")


def test_synth_scene_n_water_prints_the_index_once(tmp_path, capsys):
    out = tmp_path / "scene.xml"
    assert synth_main(["scene", "--layout", "grid", "--half-width", "50", "--n-water",
                       "T=12,S=35", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.count("n_water = 1.34152 from T=12 °C, S=35 PSU") == 1
    assert f'name="n_water" value="{water_index(12, 35)!r}"' in out.read_text()
