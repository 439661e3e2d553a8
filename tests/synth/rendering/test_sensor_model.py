"""The camera sensor applied to rendered radiance: the EMVA 1288 linear model, seeded."""

from __future__ import annotations

import json

import numpy as np
import pytest

from synth.rendering.sensor_model import (PRESETS, SensorError, SensorModel, expose, sensor_from_spec,
                                sensor_views, to_radiance)


def test_photon_transfer_of_a_flat_field():
    """Mean and variance of a flat field are those of Poisson + read noise + quantization."""
    sensor = SensorModel("test", full_well_e=20000.0, read_noise_e=5.0, bit_depth=12,
                         dark_level_dn=16.0, exposure=0.5)
    flat = np.full((1000, 1000), 3.0)
    dn, info = expose(flat, sensor, np.random.default_rng(1))
    assert dn.dtype == np.uint16 and info["peak"] == 3.0 and info["saturated_pixels"] == 0
    mean_e = 0.5 * 20000.0
    gain = sensor.gain_e_per_dn
    assert gain == pytest.approx(20000.0 / (4095 - 16))
    expected_var = (mean_e + 5.0 ** 2) / gain ** 2 + 1 / 12
    n = dn.size
    assert abs(dn.mean() - (mean_e / gain + 16)) < 5 * np.sqrt(expected_var / n)
    # The variance of the sample variance of ~normal data is 2σ⁴/(n − 1).
    assert abs(dn.var() - expected_var) < 5 * expected_var * np.sqrt(2 / (n - 1))
    back = to_radiance(dn, sensor, info["electrons_per_unit"])
    assert abs(back.mean() - 3.0) < 5 * np.sqrt(expected_var / n) * gain / info["electrons_per_unit"]


def test_saturation_dark_level_and_clipping():
    sensor = SensorModel("test", full_well_e=1000.0, read_noise_e=0.0, bit_depth=8,
                         dark_level_dn=5.0, exposure=1.0)
    image = np.array([[0.0, 1.0, 2.0]])
    dn, info = expose(image, sensor, np.random.default_rng(0), peak=1.0)
    assert dn[0, 0] == 5 and dn[0, 2] == 255 and info["saturated_pixels"] >= 1


def test_same_seed_same_bytes_and_views_differ():
    rng = np.random.default_rng(5)
    left, right = rng.uniform(0, 1, (40, 50)), rng.uniform(0, 2, (40, 50))
    a = sensor_views(left, right, PRESETS["imx174"], seed=3)
    b = sensor_views(left, right, PRESETS["imx174"], seed=3)
    c = sensor_views(left, right, PRESETS["imx174"], seed=4)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0]) and not np.array_equal(a[0], a[1])
    assert json.dumps(a[2]) == json.dumps(b[2])
    # One exposure for the pair: the brighter view's peak sets it.
    assert a[2]["peak"] == right.max()
    assert a[2]["electrons_per_unit"] == pytest.approx(0.8 * 32691.0 / right.max())


def test_specs_and_bad_values():
    s = sensor_from_spec("imx174,read_noise_e=2.5,bit_depth=10")
    assert (s.read_noise_e, s.bit_depth, s.full_well_e) == (2.5, 10, 32691.0)
    for text, fragment in [("nikon", "unknown sensor"), ("imx174,gain=3", "expected name=value"),
                           ("imx174,bit_depth=7", "bit_depth"), ("imx174,bit_depth=12.5",
                                                                 "integer"),
                           ("imx174,read_noise_e=-1", "read_noise_e"),
                           ("imx174,exposure=1.5", "exposure"),
                           ("imx174,full_well_e=nan", "full_well_e"),
                           ("imx174,dark_level_dn=5000", "dark_level_dn"),
                           ("imx174,exposure=x", "not a number")]:
        with pytest.raises(SensorError, match=fragment):
            sensor_from_spec(text)
    with pytest.raises(SensorError, match="no positive radiance"):
        expose(np.zeros((3, 3)), PRESETS["imx174"], np.random.default_rng(0))


@pytest.mark.slow
def test_eval_run_with_a_sensor(small_scene, tmp_path, capsys):
    from eval.cli import main

    out = tmp_path / "run"
    assert main(["run", small_scene, "--out", str(out), "--spp", "16", "--no-progress",
                 "--methods", "optical_path", "--sensor", "imx174"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["sensor"]["model"]["name"] == "imx174"
    assert report["sensor"]["electrons_per_unit"] > 0 and report["sensor"]["left"]["saturated_pixels"] >= 0
    assert report["matching"]["wrong"] == 0
    assert report["matching"]["visible_in_both_matched"] == report["matching"]["visible_in_both"]
    assert "Sensor `imx174`" in (out / "report.md").read_text()
    assert main(["run", small_scene, "--out", str(tmp_path / "bad"), "--sensor",
                 "imx174,bit_depth=20"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: --sensor imx174,bit_depth=20: sensor bit_depth")
    assert not (tmp_path / "bad").exists()


@pytest.mark.slow
def test_dataset_with_a_sensor_stores_raw_codes(small_scene, tmp_path):
    from synth.products.crosscheck import check_dataset
    from synth.products.dataset import read_dataset, write_dataset

    plain = write_dataset(small_scene, tmp_path / "plain", spp=16, progress=False, exr=True)
    noisy = write_dataset(small_scene, tmp_path / "noisy", spp=16, progress=False, exr=True,
                          sensor=PRESETS["imx174"])
    assert plain["png_offset"] == 0.0 and plain["sensor"] is None
    assert noisy["png_offset"] == 16.0 and noisy["sensor"]["model"]["name"] == "imx174"
    import cv2
    codes = cv2.imread(str(tmp_path / "noisy" / "left.png"), cv2.IMREAD_UNCHANGED)
    assert codes.dtype == np.uint16 and codes.max() <= 4095
    # The dark background reads as the dark level with the read noise (6.83 e⁻ ≈ 0.86 DN).
    background = codes[codes < 40]
    assert abs(np.median(background) - 16) <= 1 and 0.5 < background.std() < 1.5
    a, b = read_dataset(tmp_path / "plain"), read_dataset(tmp_path / "noisy")
    assert a.left.max() == pytest.approx(b.left.max(), rel=0.05)
    report = check_dataset(str(tmp_path / "noisy"))
    assert report["all_found"] and report["rms_px"] < 0.1
