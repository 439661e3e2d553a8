"""Lengths given per camera on the command line (``--port-distance D0,D1,…``, mm): the
argparse type, and the check that there is one per camera (or one for all)."""

from __future__ import annotations

from eval.cli import CLIError, positive_float


def per_camera_lengths(text: str) -> tuple:
    """An argparse type: positive lengths (mm) separated by commas, one per camera
    (``LEFT,RIGHT``; a rig of N cameras ``D0,D1,…``), or one for every camera; as given
    (:func:`lengths_for` spreads one number over the cameras)."""
    return tuple(positive_float(part) for part in str(text).split(","))


def lengths_for(values, cameras: int, option: str = "--port-distance") -> tuple:
    """``values`` of :func:`per_camera_lengths` for ``cameras`` cameras: one number is every
    camera's; CLIError for any other count than one per camera."""
    if len(values) == 1:
        return tuple(values) * cameras
    if len(values) != cameras:
        names = "LEFT,RIGHT" if cameras == 2 else ",".join(f"D{k}" for k in range(cameras))
        raise CLIError(f"{option} {','.join(f'{v:g}' for v in values)}: {len(values)} values "
                       f"for {cameras} cameras (give {names}, or one for all)")
    return tuple(values)
