"""A dataset's manifest and the request key that names it, for a pair and N cameras alike
(:mod:`synth.products.dataset` writes both): the key (everything a dataset's content depends
on), the manifest's own SHA-256, reading a manifest back whole (its digest and key checked),
every file's SHA-256 checked against it, and the resume rule (:func:`existing_output`)."""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np

from synth.formats.calib_yaml import DatasetError
from synth.infra.fileio import OutputDir, file_sha256, read_marker
from synth.rendering.integrator import RENDERER
from synth.scene import SceneSpec

FORMAT_VERSION = 4  # 2: targets.ply in binary doubles (was ASCII, 6 digits); 3: hashes;
#                    4: cameras.json, colmap/, surfaces' PFM / PNG depth and .flo (synth.formats.exchange)


def image_stats(image: np.ndarray) -> dict:
    return {"min": float(image.min()), "max": float(image.max()), "mean": float(image.mean()),
            "lit_fraction": float(np.mean(image > 0))}


def request_key(spec: SceneSpec, spp: int, seed: int, variant: str | None, exr: bool,
                sensor=None, adaptive: bool = True, design: dict | None = None) -> str:
    """Hash of everything that determines a dataset's content."""
    return _request_key(FORMAT_VERSION, spec.sha256, spec.params, spp, seed, variant, exr,
                        None if sensor is None else sensor.to_dict(), RENDERER,
                        adaptive_settings() if adaptive else None, design)


def adaptive_settings() -> dict:
    """What an adaptive render's content depends on beyond the scene, spp and seed (the
    ``render`` entry of the manifest and request key; :func:`synth.rendering.render.render_view_counted`)."""
    from synth.rendering import render

    return {"mode": "adaptive", "pilot_spp": render.ADAPTIVE_PILOT_SPP,
            "margin_px": render.ADAPTIVE_MARGIN_PX,
            "max_lit_fraction": render.ADAPTIVE_MAX_LIT_FRACTION}


def _request_key(format_version, scene_sha256, params, spp, seed, variant, exr, sensor,
                 renderer, adaptive: dict | None = None, design: dict | None = None) -> str:
    """The key; ``adaptive`` (the settings of an adaptive render) is part of it only when given,
    so that a full-film dataset — what every dataset was before adaptive rendering, with the
    same seeds and bytes — keeps its key."""
    request = {"format": format_version, "scene": scene_sha256, "params": params,
               "spp": spp, "seed": seed, "variant": variant, "exr": bool(exr),
               "sensor": sensor, "renderer": renderer}
    if adaptive is not None:
        request["adaptive"] = adaptive
    if design is not None:  # a port that deviates from its design (synth.scene.design)
        request["design"] = design
    blob = json.dumps(request, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def manifest_request_key(manifest: dict) -> str:
    """The request key recomputed from a manifest's own fields (scene hash and parameters,
    spp, seed, requested variant, EXR files, sensor model, this renderer)."""
    sensor = manifest.get("sensor")
    files = manifest.get("files") or []
    render = manifest.get("render")  # absent before adaptive rendering: the full film
    settings = render.get("settings") if isinstance(render, dict) else None
    return _request_key(manifest.get("format_version"), manifest["scene"].get("sha256"),
                        manifest["scene"]["params"], manifest.get("spp"), manifest.get("seed"),
                        manifest.get("variant_requested"),
                        "left.exr" in files or "cam0/image.exr" in files,
                        sensor.get("model") if isinstance(sensor, dict) else None, RENDERER,
                        settings, manifest.get("design"))


def manifest_digest(manifest: dict) -> str:
    """SHA-256 of a manifest's content: its JSON with sorted keys, without ``manifest_sha256``
    itself (and the ``skipped`` / ``rendered_again`` flags
    :func:`synth.products.dataset.write_dataset` returns)."""
    content = {k: v for k, v in manifest.items()
               if k not in ("manifest_sha256", "skipped", "rendered_again")}
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def write_manifest(directory, manifest: dict) -> None:
    """``manifest.json`` into ``directory`` with the manifest's own SHA-256 added
    (:func:`manifest_digest`; ``manifest`` gains ``manifest_sha256``)."""
    manifest["manifest_sha256"] = manifest_digest(manifest)
    with open(os.path.join(directory, "manifest.json"), "w") as fh:
        json.dump(manifest, fh, indent=2, sort_keys=False)
        fh.write("\n")


def read_manifest(path) -> dict:
    """The ``manifest.json`` of dataset directory ``path`` (DatasetError if absent or malformed)."""
    path = os.fspath(path)
    if not os.path.isdir(path):
        raise DatasetError(f"{path}: not a dataset directory")
    manifest_path = os.path.join(path, "manifest.json")
    try:
        with open(manifest_path) as fh:
            manifest = json.load(fh)
    except OSError as exc:
        raise DatasetError(f"{path}: not a dataset ({exc.strerror or exc}: manifest.json)") from None
    except ValueError as exc:
        raise DatasetError(f"{manifest_path}: malformed JSON ({exc})") from None
    if not isinstance(manifest, dict) or not isinstance(manifest.get("scene"), dict) \
            or not isinstance(manifest["scene"].get("params"), dict):
        raise DatasetError(f"{manifest_path}: not a dataset manifest (no scene parameters)")
    again = ("a dataset's truth is what was rendered: render it again with python -m synth "
             "dataset (-D changes the scene; eval run --assume what the measurement believes)")
    if "manifest_sha256" in manifest and manifest["manifest_sha256"] != manifest_digest(manifest):
        raise DatasetError(f"{manifest_path} was changed after synth dataset wrote it (its "
                           f"content no longer matches its manifest_sha256); {again}")
    try:
        key = manifest_request_key(manifest)
    except (TypeError, ValueError, AttributeError):
        key = None
    if manifest.get("request_key") != key:
        raise DatasetError(f"{manifest_path}: its scene parameters, spp, seed, variant or sensor "
                           f"disagree with its request key (edited by hand, or written by "
                           f"another renderer than {RENDERER}); {again}")
    return manifest


def check_files(path, manifest: dict, command: str = "synth dataset") -> None:
    """DatasetError unless every file of the folder ``path`` that ``manifest["sha256"]`` lists
    is there with that SHA-256 (a manifest before format 3 lists none), and the manifest's
    ``manifest_sha256``, when it has one, is its content's. ``command`` wrote the folder."""
    if "manifest_sha256" in manifest and manifest["manifest_sha256"] != manifest_digest(manifest):
        raise DatasetError(f"{os.path.join(path, 'manifest.json')} was changed after {command} "
                           f"wrote it (its content no longer matches its manifest_sha256): "
                           f"render it again with python -m {command}")
    digests = manifest.get("sha256")
    if not isinstance(digests, dict):
        return
    for name in sorted(digests):
        file = os.path.join(path, name)
        if not os.path.isfile(file):
            raise DatasetError(f"{file}: no such file (manifest.json lists it)")
        if file_sha256(file) != digests[name]:
            raise DatasetError(f"{file}: changed since {command} wrote it (its SHA-256 is not "
                               f"the one manifest.json records): render it again with "
                               f"python -m {command}")


def dataset_files(directory: str) -> list:
    """Every file below ``directory`` (paths relative to it, ``/``-separated, sorted), hidden
    files left out."""
    out = []
    for root, dirs, files in os.walk(directory):
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        rel = os.path.relpath(root, directory)
        out += [name if rel == "." else f"{rel}/{name}" for name in files
                if not name.startswith(".")]
    return sorted(out)


def existing_output(out_dir, key: str):
    """``(output, old, damage)`` for a dataset of request ``key`` about to be written to
    ``out_dir``: the :class:`synth.infra.fileio.OutputDir` (not yet claimed); ``old`` the
    manifest already there (``old["skipped"]`` True) when that output holds the same request,
    whole — nothing is to be done —, else None; ``damage`` why an output of the same request is
    not whole (a file missing or changed), or None."""
    output = OutputDir(out_dir, "synth dataset")
    damage = None
    if output.exists_as_output():
        marker = read_marker(output.path) or {}
        if marker.get("request_key") == key:
            damage = output.damage()  # up to date only when every file is whole
            try:
                if damage is None:
                    with open(os.path.join(output.path, "manifest.json")) as fh:
                        old = json.load(fh)
                    old["skipped"] = True
                    return output, old, None
            except (OSError, ValueError):
                damage = "manifest.json cannot be read"
    return output, None, damage


__all__ = ["FORMAT_VERSION", "adaptive_settings", "check_files", "dataset_files",
           "existing_output", "image_stats", "manifest_digest", "manifest_request_key",
           "read_manifest", "request_key", "write_manifest"]
