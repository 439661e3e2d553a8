"""Suites whose scenes are generated from ``python -m synth scene`` options (layouts, surfaces,
water presets) and whose port deviates from its design (``error.*``): the spec's checks (one
line naming the key and the file, exit 2, nothing written), the truth rendered and the design
stated beside it (calib_design.yaml, cameras_design.json, the manifest's design, the index's
columns), the generated files in DIR/scenes/ and a rerun that renders nothing. Images 96 px wide
at 2 spp; nothing is timed."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from synth.commands import main
from synth.infra.grid import SpecError
from synth.products.suite import load_suite_spec
from tests.conftest import REPO

TARGETS = """
name = "made"
seed = 3
render = "targets"
render_width = 96

[[scenes]]
name = "grid"
layout = "grid"
z = 1000
half_width = 300
spacing = 100
target_radius = 12

[fixed]
spp = 2

[zip]
"scene.water" = ["clear", "coastal"]
"error.port_distance" = [0, 2]
"error.port_tilt_y" = [0, 0.5]
"error.n_water" = [0.004, 0]
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "suite.toml"
    path.write_text(text.replace("{scene}", str(REPO / "scenes" / "small_grid.xml")))
    return path


def test_generated_scenes_and_deviations_expand_into_truth_and_design(tmp_path):
    from synth.scene.rig import tilted_port_normal
    from synth.scene import load_scene

    spec = load_suite_spec(_write(tmp_path, TARGETS))
    first, second = spec.entries
    assert spec.swept == ["scene.water", "error.port_distance", "error.port_tilt_y",
                          "error.n_water"]
    assert first.scene_id != second.scene_id and len(spec.generated) == 2
    assert first.design == {"error": {"n_water": 0.004, "port_distance": 0, "port_tilt_y": 0},
                            "port": {"port_distance": 100.0, "port_normal": [0.0, 0.0, 1.0],
                                     "n_water": 1.33}}
    assert first.defines["n_water"] == "1.334"  # the truth: design + error
    made = spec.generated[second.scene_id]
    assert sorted(made.files) == ["scene.xml"] and made.folder.startswith("scenes/grid_")
    path = tmp_path / "second.xml"
    path.write_bytes(made.files["scene.xml"])
    truth = load_scene(str(path), second.defines).rig.port
    assert truth.distance == pytest.approx(102.0, abs=1e-9)  # 2 mm further than designed
    assert np.allclose(truth.normal, tilted_port_normal(0.0, 0.5), atol=1e-12)
    assert b"water coastal" in made.files["scene.xml"]
    assert not np.allclose(truth.normal, second.design["port"]["port_normal"])


def test_a_generated_surface_carries_its_mesh_and_texture(tmp_path):
    spec = load_suite_spec(_write(tmp_path, """
render = "surface"
render_width = 96
[[scenes]]
layout = "surface"
surface = "wavy"
speckle_size = 20
"""))
    made = next(iter(spec.generated.values()))
    assert spec.entries[0].scene == "surface_wavy"
    assert "scene_surface.ply" in made.files and any(n.startswith("speckle_") for n in made.files)


@pytest.mark.parametrize("text, fragment", [
    ('scenes = [{layout = "grid", foo = 1}]', "scene 'grid': unknown option 'foo'"),
    ('scenes = [{layout = "grid", tilt = [0, 30]}]', "--tilt does not apply to --layout grid"),
    ('scenes = [{layout = "grid", water = "murky"}]', "invalid choice: 'murky'"),
    ('scenes = [{layout = "grid", seed = 2}]', "seed: every entry has its own seed"),
    ('scenes = [{layout = "grid"}, {layout = "grid"}]', "two scenes are called 'grid'"),
    ('scenes = [{layout = "grid"}]\n[grid]\n"error.port_foo" = [1]',
     "unknown parameter 'error.port_foo'"),
    ('scenes = [{layout = "grid"}]\n[grid]\n"error.port_distance" = ["far"]',
     "error.port_distance = 'far': expected a number"),
    ('scenes = ["{scene}"]\n[grid]\n"error.port_distance" = [1]',
     "error.port_distance: the port of a scene file is drawn in its geometry"),
    ('scenes = ["{scene}"]\n[grid]\n"scene.water" = ["clear"]',
     "scene.water: varies the options of generated scenes"),
    ('scenes = [{layout = "grid"}]\n[grid]\n"scene.colour" = ["red"]',
     "unknown parameter 'scene.colour'"),
    ('scenes = [{layout = "grid"}]\n[grid]\n"D.nothing" = [1]',
     "unknown parameter D.nothing: scene 'grid' has no default 'nothing'"),
    ('scenes = [{layout = "grid", port = "none"}]\n[grid]\n"error.port_distance" = [1]',
     "port deviations need a port"),
    ('render = "boards"\nscenes = [{layout = "grid"}]\n[grid]\n"error.n_water" = [0.01]',
     "board sequences state no design port"),
    ('scenes = [{layout = "grid", port = "dome", cameras = 3, size = [320, 268]}]\n[grid]\n'
     '"error.n_water" = [0.01]', "error.n_water: scene grid looks through domes"),
    ('scenes = [{layout = "surface", speckle_size = 20}]',
     "render = 'targets' but scene surface_plane is a surface"),
])
def test_spec_errors_name_the_key_and_the_file(tmp_path, text, fragment):
    path = _write(tmp_path, text)
    with pytest.raises(SpecError) as info:
        load_suite_spec(path)
    message = str(info.value)
    assert message.startswith(str(path)) and fragment in message and "\n" not in message


def test_a_bad_generated_scene_is_one_line_and_nothing_is_written(tmp_path, capsys):
    path = _write(tmp_path, 'scenes = [{layout = "grid", foo = 1}]')
    assert main(["suite", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {path}: scene 'grid': unknown option 'foo'")
    assert "\n" not in err and not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_suite_renders_the_truth_and_states_the_design(tmp_path, capsys):
    from synth.products.dataset import read_calib, read_dataset

    spec_path, out = _write(tmp_path, TARGETS), tmp_path / "out"
    assert main(["suite", str(spec_path), "--out", str(out), "--workers", "1",
                 "--no-progress"]) == 0
    rows = pq.read_table(out / "index.parquet").to_pylist()
    for name in ("scene_file", "scene.water", "error.port_distance", "error.port_tilt_y",
                 "error.n_water"):
        assert name in rows[0]
    assert [r["error.port_distance"] for r in rows] == [0, 2]
    assert "D.n_water" not in rows[0]  # the spec set none; the truth is 1.33 + error.n_water
    for row in rows:
        folder = out / row["folder"]
        assert (out / row["scene_file"]).is_file()
        data = read_dataset(folder)  # the request key, the design included, checks out
        manifest = data.manifest
        assert manifest["scene"]["path"] == str(out / row["scene_file"])
        design = read_calib(str(folder / "calib_design.yaml"))["rig"]
        cameras = json.loads((folder / "cameras_design.json").read_text())
        assert "calib_design.yaml" in manifest["sha256"]
        assert manifest["design"]["error"]["port_distance"] == row["error.port_distance"]
        assert design.port.distance == 100.0 and cameras["port"]["distance"] == 100.0
        assert data.rig.port.distance == pytest.approx(100.0 + row["error.port_distance"], abs=1e-9)
        assert np.allclose(design.left.K, data.rig.left.K)
    first = read_dataset(out / rows[0]["folder"])
    assert first.rig.port.n_water == pytest.approx(1.334, abs=1e-12)
    assert read_calib(str(out / rows[0]["folder"] / "calib_design.yaml"))["rig"].port.n_water == 1.33
    capsys.readouterr()
    assert main(["suite", str(spec_path), "--out", str(out), "--no-progress"]) == 0
    assert "0 rendered now" in capsys.readouterr().out


@pytest.mark.slow
def test_a_generated_surface_in_coastal_water_renders(tmp_path):
    spec_path, out = _write(tmp_path, """
render = "surface"
render_width = 96
[[scenes]]
name = "wavy"
layout = "surface"
surface = "wavy"
speckle_size = 20
water = "coastal"
[fixed]
spp = 2
"""), tmp_path / "out"
    assert main(["suite", str(spec_path), "--out", str(out), "--workers", "1",
                 "--no-progress"]) == 0
    row = pq.read_table(out / "index.parquet").to_pylist()[0]
    scene_folder = (out / row["scene_file"]).parent
    assert (scene_folder / "scene_surface.ply").is_file()
    assert (out / row["folder"] / "left_truth_zdepth.pfm").is_file()
    assert not (out / row["folder"] / "calib_design.yaml").exists()  # no deviation, no design


@pytest.mark.slow
def test_a_worker_that_does_not_see_the_folder_renders_a_generated_scene(tmp_path, monkeypatch):
    """A generated target scene travels as bytes, like a scene file; the design files come back
    with the dataset's."""
    from synth.infra import cluster
    from synth.products.suite_folder import render_task

    spec = load_suite_spec(_write(tmp_path, TARGETS))
    entry = spec.entries[1]
    scene = spec.generated[entry.scene_id].placed(str(tmp_path / "not-here"))
    monkeypatch.setattr(cluster, "_SETUP_DONE", True)  # keep this process's thread counts
    result = render_task({"key": entry.key, "render": "targets", "scene_sha": scene.sha256,
                          "scene_data": scene.data, "scene_path": scene.path,
                          "params": entry.params, "defines": entry.defines,
                          "design": entry.design, "seed": entry.seed,
                          "out": str(tmp_path / "elsewhere" / entry.folder), "token": "other"})
    assert result["status"] == "ok", result["error"]
    assert {"calib_design.yaml", "cameras_design.json", "left.png"} <= set(result["files"])
    manifest = json.loads(result["files"]["manifest.json"])
    assert manifest["design"] == entry.design


def test_a_water_deviation_behind_domes_is_a_spec_error(tmp_path):
    """A design port deviates a flat port: error.n_water on a dome scene is refused when the
    spec is read, not after the render."""
    path = tmp_path / "suite.toml"
    path.write_text(f'scenes = ["{REPO / "scenes" / "dome_decentred.xml"}"]\n'
                    'render = "targets"\n[fixed]\n"error.n_water" = 0.01\n')
    with pytest.raises(SpecError, match="error.n_water: scene .* looks through domes"):
        load_suite_spec(str(path))
