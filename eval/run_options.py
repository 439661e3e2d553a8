"""Options of ``python -m eval run`` shared by its target pipeline (:mod:`eval.run`) and its
dense pipeline on surface scenes (:mod:`eval.dense_run`): the depth range, the sensor, the
parameters of a ``--from`` dataset, the rig the measurement believes, number formatting."""

from __future__ import annotations

import math

from eval.cli import CLIError

DEFAULT_METHODS = ("optical_path", "su", "regular")
COMMAND = "eval run"


def _parse_sensor(text):
    """The ``--sensor`` model, or None; CLIError names what is wrong."""
    if text is None:
        return None
    from synth.sensor_model import SensorError, sensor_from_spec

    try:
        return sensor_from_spec(text)
    except SensorError as exc:
        raise CLIError(f"--sensor {text}: {exc}") from None


def _parse_range(text):
    if text is None:
        return None
    try:
        near, far = (float(v) for v in text.split(","))
    except ValueError:
        raise CLIError(f"--depth-range must be NEAR,FAR in mm, got {text!r}") from None
    if not (math.isfinite(near) and math.isfinite(far) and 0 <= near < far):
        raise CLIError(f"--depth-range must satisfy 0 <= NEAR < FAR (finite), got {text!r}")
    return near, far


def _same_value(a: str, b: str) -> bool:
    """Whether two parameter values (text) mean the same: equal numbers, or equal text."""
    import numpy as np

    try:
        x = np.array([float(v) for v in str(a).replace(",", " ").split()])
        y = np.array([float(v) for v in str(b).replace(",", " ").split()])
        return x.shape == y.shape and bool(np.array_equal(x, y))
    except ValueError:
        return str(a).strip() == str(b).strip()


def _dataset_params(args, defines: dict) -> dict:
    """The parameters the dataset of ``--from`` was rendered with; a conflicting ``-D`` is an
    error naming both values."""
    from synth.dataset import read_manifest

    params = {str(k): str(v) for k, v in read_manifest(args.from_dir)["scene"]["params"].items()}
    for name, value in defines.items():
        if name in params and not _same_value(value, params[name]):
            raise CLIError(f"-D {name}={value} conflicts with --from {args.from_dir}, rendered "
                           f"with {name}={params[name]}")
    return params


def _measurement_rig(args, spec):
    """The rig the measurement believes: the scene's (the truth), or ``--calib``, with
    ``--assume`` applied."""
    from synth.dataset import read_calib

    from .assumption import assumed_rig, parse_assumptions

    assumptions = parse_assumptions(args.assume)
    base = None
    if args.calib:
        calib = read_calib(args.calib)
        if tuple(calib["size"]) != tuple(spec.size):
            raise CLIError(f"--calib {args.calib}: image size {calib['size'][0]}x{calib['size'][1]} "
                           f"px, but the scene renders {spec.size[0]}x{spec.size[1]} px")
        base = calib["rig"]
    return assumed_rig(spec.rig, spec.has_port, assumptions, base)


def _fmt(value, digits=3):
    if value is None or (isinstance(value, float) and value != value):
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def load_run_scene(args):
    """The scene of a run with ``-D`` and ``--seed`` applied. With ``--from`` the dataset's own
    parameters are used (a conflicting ``-D`` is an error) and ``--seed`` seeds only the
    run's noise, but a ``-D seed`` contradicting it is still refused."""
    from synth.scene import apply_seed, load_scene, parse_defines

    defines = parse_defines(args.defines)
    if args.from_dir:
        apply_seed(dict(defines), args.seed)
        return load_scene(args.scene, _dataset_params(args, defines))
    return load_scene(args.scene, apply_seed(defines, args.seed))


def read_run_dataset(args, spec):
    """The ``--from`` dataset, refused when it was rendered from another scene than ``spec``."""
    from synth.dataset import read_dataset

    data = read_dataset(args.from_dir)
    if data.manifest["scene"].get("sha256") != spec.sha256:
        raise CLIError(f"--from {args.from_dir}: the dataset was rendered from another scene "
                       f"than {args.scene}")
    return data
