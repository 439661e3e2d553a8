"""The white squares' brightness across each rendered chessboard of a ``synth boards`` folder:
per pose and view the ratio of the brightest white square to the darkest (the mean over the
middle half of each square, located with the forward model from the folder's truth,
:func:`synth.products.board_light.white_square_levels`), and its spread over the folder.

    python tools/board_light_ratio.py BOARDS_FOLDER [--sheet sheet.png] [--white-dn 230]

Prints one line per pose and view and a summary line ``ratio min/median/max``; ``--sheet``
writes a contact sheet of the left views (sRGB previews). The ratio is of linear values (the
rendered radiance), unlike a photo's stored 8-bit values (tools/ouc_twin.py measures both).
``--white-dn W`` also gives them as one exposure for the whole folder would store them in 8
bits: the views' median white square at W DN, clipped at 255
(:func:`synth.products.board_light.stored_white_ratios`), and how many views saturate.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # the repository


def white_levels(folder) -> list:
    """Every image's white-square levels (linear), pose by pose and view by view: a list over
    the poses of lists over the views of ``(S,)`` arrays."""
    from synth.products.board_light import white_square_levels
    from synth.products.boards import read_boards

    data = read_boards(folder)
    rig = data.calib["rig"]
    return [[white_square_levels(image, camera, rig.view_port(v), data.board, pose)
             for v, (image, camera) in enumerate(zip(pair, rig.cameras))]
            for pair, pose in zip(data.images, data.poses)]


def ratios(folder, levels=None) -> np.ndarray:
    """``(poses, views)`` max/min white-square level of every image of a boards folder."""
    levels = white_levels(folder) if levels is None else levels
    return np.array([[np.nanmax(v) / np.nanmin(v) for v in pose] for pose in levels])


def contact_sheet(folder, path, columns: int = 4) -> None:
    """The left views of a boards folder side by side (sRGB previews, each to its own white)."""
    import cv2

    from synth.products.boards import read_boards
    from synth.rendering.image_files import srgb_preview

    images = [srgb_preview(pair[0]) for pair in read_boards(folder).images]
    blank = np.zeros_like(images[0])
    images += [blank] * (-len(images) % columns)
    rows = [np.hstack(images[i:i + columns]) for i in range(0, len(images), columns)]
    cv2.imwrite(str(path), np.vstack(rows))


def print_stored(levels, white_dn: float) -> None:
    """The stored 8-bit ratios (``--white-dn``): per pose and view, then a summary line."""
    from synth.products.board_light import stored_white_ratios

    views = [v for pose in levels for v in pose]
    ratio, clipped = stored_white_ratios(views, white_dn)
    n_views = len(levels[0])
    print(f"stored in 8 bits (the views' median white square at {white_dn:g} DN, clipped at "
          f"255; * a view with a clipped white square):")
    for k in range(len(levels)):
        cells = [f"{ratio[k * n_views + v]:.2f}{'*' if clipped[k * n_views + v] else ' '}"
                 for v in range(n_views)]
        print(f"pose {k:2d}: " + "  ".join(cells))
    print(f"stored white squares max/min: min {ratio.min():.2f}, median {np.median(ratio):.2f}, "
          f"max {ratio.max():.2f} over {ratio.size} views; {int(clipped.sum())} views saturate")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder")
    parser.add_argument("--sheet", default=None, help="write the left views' contact sheet")
    parser.add_argument("--white-dn", type=float, default=None, metavar="W",
                        help="also the ratios as stored in 8 bits by one exposure that puts the "
                             "views' median white square at W DN (clipped at 255)")
    args = parser.parse_args(argv)
    try:
        levels = white_levels(args.folder)
        r = ratios(args.folder, levels)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for k, row in enumerate(r):
        print(f"pose {k:2d}: " + "  ".join(f"{v:.2f}" for v in row))
    finite = r[np.isfinite(r)]
    print(f"white squares max/min: min {finite.min():.2f}, median {np.median(finite):.2f}, "
          f"max {finite.max():.2f} over {finite.size} views")
    if args.white_dn is not None:
        print_stored(levels, args.white_dn)
    if args.sheet:
        contact_sheet(args.folder, args.sheet)
    return 0


if __name__ == "__main__":
    sys.exit(main())
