"""The white squares' brightness across each rendered chessboard of a ``synth boards`` folder:
per pose and view the ratio of the brightest white square to the darkest (the mean over the
middle half of each square, located with the forward model from the folder's truth,
:func:`synth.products.board_light.white_square_levels`), and its spread over the folder.

    python tools/board_light_ratio.py BOARDS_FOLDER [--sheet sheet.png]

Prints one line per pose and view and a summary line ``ratio min/median/max``; ``--sheet``
writes a contact sheet of the left views (sRGB previews). The ratio is of linear values (the
rendered radiance), unlike a photo's stored 8-bit values (tools/ouc_twin.py measures both).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def ratios(folder) -> np.ndarray:
    """``(poses, views)`` max/min white-square level of every image of a boards folder."""
    from synth.products.board_light import white_square_levels
    from synth.products.boards import read_boards

    data = read_boards(folder)
    rig = data.calib["rig"]
    out = np.full((len(data.images), len(rig.cameras)), np.nan)
    for k, (pair, pose) in enumerate(zip(data.images, data.poses)):
        for v, (image, camera) in enumerate(zip(pair, rig.cameras)):
            levels = white_square_levels(image, camera, rig.view_port(v), data.board, pose)
            out[k, v] = np.nanmax(levels) / np.nanmin(levels)
    return out


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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder")
    parser.add_argument("--sheet", default=None, help="write the left views' contact sheet")
    args = parser.parse_args(argv)
    try:
        r = ratios(args.folder)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for k, row in enumerate(r):
        print(f"pose {k:2d}: " + "  ".join(f"{v:.2f}" for v in row))
    finite = r[np.isfinite(r)]
    print(f"white squares max/min: min {finite.min():.2f}, median {np.median(finite):.2f}, "
          f"max {finite.max():.2f} over {finite.size} views")
    if args.sheet:
        contact_sheet(args.folder, args.sheet)
    return 0


if __name__ == "__main__":
    sys.exit(main())
