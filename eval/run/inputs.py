"""What a run starts from: the scene (with ``-D`` and the seed), the rig the measurement
believes, the rigs of the error budget, and the two images — rendered now or read from a
``--from`` dataset (:class:`RunInputs`).

Frames and units: the reference frame is the left camera's (OpenCV axes), millimetres, pixels
in the OpenCV convention.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np

from eval.cli import CLIError
from eval.run.config import RunConfig
from eval.core.analytic import visible_targets


@dataclass
class RunInputs:
    """What the pipeline starts from: a rig, two linear images, and (for scoring) the truth.

    ``rig`` is what the measurement believes; ``targets`` ``(N, 3)`` mm the true centres;
    ``left``/``right`` float32 linear images ``(H, W)``; ``params`` the scene's resolved
    parameters; ``seed`` the run's one seed (images, added noise, RANSAC); ``budget_rigs``
    ``{label: rig}``: also measure with these rigs (the error budget); ``rig_covariance`` the
    ``--calib`` file's covariance (:class:`measure.stereo.rig_covariance.RigCovariance`) or None;
    ``absorbed`` the absorbed baseline's calibration
    (:class:`eval.core.absorbed.AbsorbedCalibration`) when the run measures with it; for a rig
    of N cameras (``rig``, ``truth_rig`` of N) ``views`` ``{name: image}`` every view and
    ``depth_port`` the port whose reference axis the default depth window takes (None: the true
    rig's)."""

    scene: str
    rig: object
    has_port: bool
    targets: np.ndarray
    target_ids: np.ndarray
    target_radius: float
    left: np.ndarray
    right: np.ndarray
    params: dict
    variant: str
    spp: int
    render_seconds: float
    seed: int = 0
    extra: dict = field(default_factory=dict)
    target_normals: np.ndarray | None = None
    truth_rig: object = None
    budget_rigs: dict = field(default_factory=dict)
    rig_covariance: object = None
    rig_covariance_source: str | None = None
    absorbed: object = None
    views: dict | None = None
    depth_port: object = None

    @property
    def true_rig(self):
        """The rig the images were rendered with (``rig`` is what the measurement believes)."""
        return self.rig if self.truth_rig is None else self.truth_rig

    def view_images(self) -> dict:
        """``{view name: image}`` in camera order: ``views`` for N cameras (``cam0``, …;
        ``left``/``right`` are then its first two), else ``{"left", "right"}``."""
        return self.views if self.views is not None else {"left": self.left, "right": self.right}


def same_value(a: str, b: str) -> bool:
    """Whether two parameter values (text) mean the same: equal numbers, or equal text."""
    try:
        x = np.array([float(v) for v in str(a).replace(",", " ").split()])
        y = np.array([float(v) for v in str(b).replace(",", " ").split()])
        return x.shape == y.shape and bool(np.array_equal(x, y))
    except ValueError:
        return str(a).strip() == str(b).strip()


def dataset_params(from_dir: str, defines: dict) -> dict:
    """The parameters the dataset ``from_dir`` was rendered with — ``spp`` and ``seed`` as
    rendered (the manifest's ``spp`` and ``seed``; datasets before format 3 recorded the
    scene's defaults among the parameters); a conflicting ``-D`` is an error naming both
    values."""
    from synth.products.dataset import read_manifest

    manifest = read_manifest(from_dir)
    params = {str(k): str(v) for k, v in manifest["scene"]["params"].items()}
    for name in ("spp", "seed"):
        if name in params and manifest.get(name) is not None:
            params[name] = str(manifest[name])
    for name, value in defines.items():
        if name in params and not same_value(value, params[name]):
            raise CLIError(f"-D {name}={value} conflicts with --from {from_dir}, rendered "
                           f"with {name}={params[name]}")
    return params


def measurement_calibration(config: RunConfig, spec):
    """``(rig, covariance)``: the rig the measurement believes — the scene's (the truth), or
    ``--calib``'s, with ``--assume`` applied — and the covariance of ``--calib``'s rig
    (:class:`measure.stereo.rig_covariance.RigCovariance`; None without ``--calib`` or when the file
    holds none). The file is read once; a singular or malformed covariance is refused by
    ``read_calib`` with one line naming the file."""
    from synth.products.dataset import read_calib

    from eval.core.assumption import assumed_rig

    base = covariance = None
    if config.calib:
        calib = read_calib(config.calib)
        _same_kind_of_port(f"--calib {config.calib}", calib["rig"], spec.rig)
        if tuple(calib["size"]) != tuple(spec.size):
            raise CLIError(f"--calib {config.calib}: image size {calib['size'][0]}x"
                           f"{calib['size'][1]} px, but the scene renders {spec.size[0]}x"
                           f"{spec.size[1]} px")
        base, covariance = calib["rig"], calib["covariance"]
    return assumed_rig(spec.rig, spec.has_port, config.assumptions, base), covariance


def absorbed_calibration(config: RunConfig, spec, seed: int, log):
    """The absorbed baseline's calibration (:mod:`eval.core.absorbed`) when ``--methods``
    holds it: ``--absorbed-calib``'s, or computed from the scene's boards; None otherwise."""
    if not config.absorbed:
        return None
    from eval.core.absorbed import analytic_absorbed_calibration, read_absorbed_calibration

    if not spec.has_port:
        raise CLIError(f"the absorbed method does not apply to {config.scene}: the scene has no "
                       f"port (all air), so there is nothing to absorb")
    if config.absorbed_calib:
        try:
            return read_absorbed_calibration(config.absorbed_calib, spec.size)
        except ValueError as exc:
            raise CLIError(str(exc)) from None
    log("absorbed baseline: calibrate the cameras as pinhole cameras from the scene's boards "
        "seen through its port …")
    try:
        return analytic_absorbed_calibration(spec.rig, seed=0)
    except ValueError as exc:
        raise CLIError(f"{config.scene}: the absorbed calibration cannot be made: {exc}") from None


def _same_kind_of_port(what: str, calibrated, scene_rig) -> None:
    """CLIError unless a calibration's rig has the scene's kind of port (a dome pair for a dome
    scene, a flat port otherwise)."""
    if type(calibrated.port) is not type(scene_rig.port):
        raise CLIError(f"{what}: a {calibrated.port.calibration_name}, but the scene has "
                       f"{scene_rig.port.description}")


def load_run_scene(config: RunConfig):
    """The scene of a run with ``-D`` and the seed applied. With ``--from`` the dataset's own
    parameters are used (a conflicting ``-D`` is an error) and the seed seeds only the run's
    noise, but a ``-D seed`` contradicting it is still refused."""
    from synth.scene import SceneError, apply_seed, apply_spp, load_scene

    defines = dict(config.defines)
    if config.from_dir:
        apply_seed(dict(defines), config.seed)
        params = dataset_params(config.from_dir, defines)
        try:
            return load_scene(config.scene, params)
        except SceneError as exc:  # the dataset's parameters are another scene's
            raise another_scene(config, exc) or exc from None
    defines = apply_spp(apply_seed(defines, config.seed), config.spp)
    return load_scene(config.scene, defines).rendered_with(spp=config.spp)


def another_scene(config: RunConfig, exc=None) -> CLIError | None:
    """The error of a ``--from`` dataset rendered from another scene file than ``config.scene``
    (its manifest's scene SHA-256 is not the file's): the scene it was rendered from and its
    cameras named, and ``exc`` (the scene could not be loaded with the dataset's parameters:
    "unknown parameter -D cam3_dist") said; None when the files agree."""
    import hashlib

    from synth.products.dataset import read_manifest

    try:
        with open(config.scene, "rb") as fh:
            digest = hashlib.sha256(fh.read()).hexdigest()
        manifest = read_manifest(config.from_dir)
        scene = manifest["scene"]
    except (OSError, KeyError, TypeError, ValueError):
        return None
    if scene.get("sha256") == digest:
        return None
    cameras = manifest.get("cameras")
    why = ("" if exc is None else ", whose parameters it does not fit ("
           + str(exc).removeprefix(f"{config.scene}: ").split(" (the scene's defaults")[0] + ")")
    return CLIError(f"--from {config.from_dir}: the dataset was rendered from another scene "
                    f"({scene.get('path')}, "
                    + (f"{len(cameras)} cameras" if isinstance(cameras, list) else "a pair")
                    + f") than {config.scene}{why}")


def read_run_dataset(config: RunConfig, spec):
    """The ``--from`` dataset, refused when it holds more than two cameras or was rendered from
    another scene than ``spec``."""
    from synth.products.dataset import DatasetError, ViewsDataset, read_dataset

    data = read_dataset(config.from_dir)
    if isinstance(data, ViewsDataset):
        raise DatasetError(f"{config.from_dir}: a dataset of {len(data.names)} cameras "
                           f"({', '.join(f'{c}/' for c in data.names)}), not a stereo pair "
                           f"(left.png, right.png): this reads two views (synth check, synth "
                           f"photos and eval run --from read every camera)")
    if data.manifest["scene"].get("sha256") != spec.sha256:
        raise another_scene(config) or CLIError(
            f"--from {config.from_dir}: the dataset was rendered from another scene than "
            f"{config.scene}")
    from eval.core.assumption import rig_difference

    difference = rig_difference(spec.rig, data.rig)
    if difference:
        raise CLIError(f"--from {config.from_dir}: calib.yaml disagrees with the scene rendered "
                       f"with manifest.json's parameters (in {', '.join(difference)}); the run "
                       f"takes the scene as the truth: render the dataset again, or measure "
                       f"with --calib {os.path.join(config.from_dir, 'calib.yaml')} to believe it")
    sensor = data.manifest.get("sensor")
    if config.sensor is not None and sensor:
        name = (sensor.get("model") or {}).get("name", "a") if isinstance(sensor, dict) else "a"
        raise CLIError(f"--sensor does not apply with --from {config.from_dir}: its images "
                       f"already hold the raw codes of the {name} sensor (synth dataset "
                       f"--sensor); it would be applied twice")
    return data


def budget_rigs(config: RunConfig, true_rig, measured_rig) -> dict:
    """``{label: rig}`` of the error budget: the exact calibration (when the measurement's rig
    differs from the truth) and every ``--compare-calib`` file."""
    from synth.products.dataset import read_calib

    from eval.core.assumption import rig_difference

    rigs = {}
    if config.compare_calib or rig_difference(true_rig, measured_rig):
        rigs["exact calibration"] = true_rig
    for path in config.compare_calib:
        calib = read_calib(path)
        _same_kind_of_port(f"--compare-calib {path}", calib["rig"], true_rig)
        if tuple(calib["size"]) != tuple(true_rig.left.size):
            raise CLIError(f"--compare-calib {path}: image size {calib['size'][0]}x"
                           f"{calib['size'][1]} px, but the scene renders "
                           f"{true_rig.left.size[0]}x{true_rig.left.size[1]} px")
        rigs[path] = calib["rig"]
    return rigs


def refuse_flat_only(config: RunConfig, port=None) -> None:
    """CLIError for an option of one flat port given for a scene whose port does not
    self-calibrate (each camera inside its own dome, or behind its own flat port): the
    self-calibration estimates one flat port's parameters. (``--assume`` of a flat port's
    parameter is refused by :func:`eval.core.assumption.assumed_rig`.)"""
    if config.self_calibrate:
        kind = "dome" if port is None else port.kind
        raise CLIError(f"--self-calibrate does not apply to the {kind} scene {config.scene}: it "
                       f"estimates the parameters of one flat port")


def load_inputs(config: RunConfig, log) -> RunInputs:
    """The scene (rig and truth) and its two images, rendered now or read from ``--from``."""
    spec = load_run_scene(config).require_two_cameras(
        "a stereo run (eval sweep's render cells; eval run itself measures N cameras)")
    if config.self_calibrate and not spec.has_port:
        raise CLIError(f"--self-calibrate does not apply to {config.scene}: it estimates the "
                       f"port's parameters, and the scene has no port (all air)")
    if not spec.rig.port.self_calibrates:
        refuse_flat_only(config, spec.rig.port)
    seed = spec.seed if config.seed is None else config.seed
    measured_rig, rig_covariance = measurement_calibration(config, spec)
    in_left = visible_targets(spec.rig.left, spec.rig.view_port(0), spec.targets,
                              spec.target_radius)[1]
    in_right = visible_targets(spec.rig.right, spec.rig.view_port(1), spec.targets,
                               spec.target_radius)[1]
    if not (in_left & in_right).any():
        raise CLIError(f"{config.scene}: no target is visible in both views")
    budget = budget_rigs(config, spec.rig, measured_rig)
    absorbed = absorbed_calibration(config, spec, seed, log)
    scene_part = dict(scene=config.scene, rig=measured_rig, has_port=spec.has_port,
                      targets=spec.targets, target_ids=spec.target_ids,
                      target_radius=spec.target_radius, params=spec.params, seed=seed,
                      target_normals=spec.target_normals, truth_rig=spec.rig,
                      budget_rigs=budget, rig_covariance=rig_covariance,
                      rig_covariance_source=(f"--calib {config.calib}" if config.calib
                                             else None), absorbed=absorbed)
    if config.from_dir:
        data = read_run_dataset(config, spec)
        log(f"reusing the images of {config.from_dir}")
        return RunInputs(left=data.left, right=data.right,
                         variant=data.manifest.get("variant", "?"),
                         spp=int(data.manifest.get("spp", 0)), render_seconds=0.0,
                         extra={"from": os.path.abspath(config.from_dir),
                                "spp_rendered": data.manifest.get("spp_rendered"),
                                "from_seed": data.manifest.get("seed")}, **scene_part)
    from eval.run import preload
    from synth.rendering.render import render_stereo, render_summary

    preloading = preload.start(figures=not config.no_figures)
    log(f"render both views ({spec.size[0]}x{spec.size[1]} px, {config.spp or spec.spp} spp, "
        f"{'full film' if config.full_film else 'adaptive'}) …")
    start = time.perf_counter()
    left, right, info = render_stereo(spec, spp=config.spp, variant=config.variant,
                                      progress=config.progress, adaptive=not config.full_film)
    timings = {"render_left": info["seconds"]["left"], "render_right": info["seconds"]["right"],
               "render_samples_per_second": info["samples_per_second"],
               **{f"render_samples_per_second_{view}": speed
                  for view, speed in info["samples_per_second_per_view"].items()}}
    render = {k: v for k, v in info.items()
              if k not in ("seconds", "samples_per_second", "samples_per_second_per_view")}
    log("rendered: " + ", ".join(f"{view} {info['seconds'][view]:.1f} s at {speed / 1e6:.2f} M "
                                 f"samples/s ({'+'.join(map(str, info['passes'][view]))} spp)"
                                 for view, speed in info["samples_per_second_per_view"].items()))
    for view in ("left", "right"):
        log(f"  {view}: {render_summary(info['render'][view])}")
    preloading.join()  # before anything forks (the figures) or imports what it imports
    return RunInputs(left=left, right=right, variant=info["variant"], spp=info["spp"],
                     render_seconds=time.perf_counter() - start,
                     extra={"render": render, "timings": timings}, **scene_part)


def expose_views(left, right, sensor, seed):
    """Both views through the ``sensor`` model (seeded by ``seed``) and back to radiance:
    ``(left, right, the sensor's report entry)``; unchanged with None when there is no
    sensor."""
    if sensor is None:
        return left, right, None
    from synth.rendering.sensor_model import sensor_views, to_radiance

    codes_left, codes_right, sensor_info = sensor_views(left, right, sensor, seed)
    left, right = (to_radiance(codes, sensor, sensor_info["electrons_per_unit"])
                   for codes in (codes_left, codes_right))
    return left, right, sensor_info


def expose_on_sensor(inputs: RunInputs, sensor, log):
    """Pass both views of ``inputs`` through the ``sensor`` model (seeded by the run's seed), in
    place; returns the sensor's report entry (None without a sensor)."""
    if sensor is not None:
        log(f"expose both views on the {sensor.name} sensor …")
    inputs.left, inputs.right, sensor_info = expose_views(inputs.left, inputs.right, sensor,
                                                          inputs.seed)
    return sensor_info


def nothing_matched_message(inputs: RunInputs, detections, window) -> str:
    """The error of a pair run with no match: what was detected and what to check."""
    near, far = window
    window_text = ("no depth window" if near is None
                   else f"the depth window {near:g}-{far:g} mm")
    found = {name: detections[name].n_found for name in ("left", "right")}
    if min(found.values()) == 0:
        cause = ("check that targets are lit and large enough (target_radius), that the scene "
                 "renders (max_depth >= 2 through a port) and spp")
    else:
        cause = (f"check the water index (n_water) and port the measurement assumes, "
                 f"{window_text} (--depth-range) and --gate-mm")
    return (f"{inputs.scene}: no target was matched between the views (detected {found['left']} "
            f"left, {found['right']} right): {cause}")


__all__ = ["RunInputs", "another_scene", "budget_rigs", "dataset_params", "expose_on_sensor", "expose_views",
           "load_inputs", "refuse_flat_only", "load_run_scene", "measurement_calibration",
           "nothing_matched_message", "read_run_dataset", "same_value"]
