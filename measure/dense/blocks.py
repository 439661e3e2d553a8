"""Window means and the partition of an image into blocks, shared by the dense sweep
(:mod:`measure.dense.match`) and its refinement (:mod:`measure.dense.refine`).

Windows are ``window × window`` pixels (odd), means by OpenCV's box filter with reflected borders;
a block is a rectangle of output pixels and the halo of rows and columns its window sums read;
work on blocks and chunks of pixels runs on a thread per core (OpenCV and NumPy release the GIL).
Pixels ``(u, v)`` are OpenCV's (integer = pixel centre).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

#: Variance floor of a window (intensity units², images scaled to [0, 1]): flat windows fail.
MIN_WINDOW_VARIANCE = 1e-8
#: Pixels kept clear of the right image border by the interpolated samples (cubic: 2 px).
RIGHT_MARGIN_PX = 2.0


def window_mean(image: np.ndarray, window: int) -> np.ndarray:
    return cv2.boxFilter(image, -1, (window, window), normalize=True,
                         borderType=cv2.BORDER_REFLECT)


def window_inside(mask: np.ndarray, window: int) -> np.ndarray:
    """Pixels whose whole window lies where ``mask`` (bool ``(H, W)``) holds."""
    kernel = np.ones((window, window), np.uint8)
    return cv2.erode(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT,
                     borderValue=0).astype(bool)


def right_inside(map_u, map_v, size) -> np.ndarray:
    width, height = size
    m = RIGHT_MARGIN_PX
    with np.errstate(invalid="ignore"):
        return (map_u >= m) & (map_u <= width - 1 - m) & (map_v >= m) & (map_v <= height - 1 - m)


def row_bands(height: int, halo: int, workers: int):
    """Row bands ``(r0, r1, lo, hi)`` covering ``height`` rows: band rows ``[r0, r1)`` and the
    rows ``[lo, hi)`` their window filters read (``halo`` rows more on each side, clipped)."""
    count = min(height, max(1, 4 * workers))
    edges = np.linspace(0, height, count + 1).round().astype(int)
    return [(r0, r1, max(r0 - halo, 0), min(r1 + halo, height))
            for r0, r1 in zip(edges[:-1], edges[1:]) if r1 > r0]


def split_in_chunks(items: np.ndarray, workers: int, chunk: int) -> list[np.ndarray]:
    """``items`` split into at most ``4 · workers`` pieces of at least ``chunk`` items."""
    return np.array_split(items, max(1, min(4 * workers, len(items) // chunk)))


def in_chunks(function, items: np.ndarray, workers: int, chunk: int = 100_000):
    """``function(items)`` (a tuple of arrays, each with a row per item) evaluated on chunks of
    at least ``chunk`` items on ``workers`` threads and concatenated."""
    with ThreadPoolExecutor(max_workers=workers) as pool:
        parts = list(pool.map(function, split_in_chunks(items, workers, chunk)))
    return tuple(np.concatenate(column) for column in zip(*parts))


@dataclass(frozen=True)
class Block:
    """A rectangle of output pixels, rows ``[r0, r1)`` × columns ``[c0, c1)``, and the
    rectangle rows ``[lo, hi)`` × columns ``[clo, chi)`` its window filters read (half a window
    more on each side, clipped to the image)."""

    r0: int
    r1: int
    lo: int
    hi: int
    c0: int
    c1: int
    clo: int
    chi: int

    @property
    def out(self):
        return np.s_[self.r0:self.r1, self.c0:self.c1]

    @property
    def read(self):
        return np.s_[self.lo:self.hi, self.clo:self.chi]

    @property
    def inner(self):
        return np.s_[self.r0 - self.lo:self.r1 - self.lo, self.c0 - self.clo:self.c1 - self.clo]


#: Rows and columns of the blocks in which the refinement computes its window sums: blocks this
#: small keep their arrays in the caches (full-size slanted step 0.48 s against 0.62 s for
#: full-width row bands on the 2-core machine).
SUM_BLOCK_SHAPE = (128, 612)


def tiled_blocks(shape, halo: int, block_shape=SUM_BLOCK_SHAPE) -> list[Block]:
    """:class:`Block` s of ``block_shape`` (rows, columns; smaller at the far edges) tiling an
    image of ``shape`` (H, W), each reading ``halo`` px more on every side (clipped)."""
    height, width = shape
    rows, columns = block_shape
    return [Block(r0, min(r0 + rows, height), max(r0 - halo, 0), min(r0 + rows + halo, height),
                   c0, min(c0 + columns, width), max(c0 - halo, 0),
                   min(c0 + columns + halo, width))
            for r0 in range(0, height, rows) for c0 in range(0, width, columns)]


#: Side (px) of the tiles in which the refinement recomputes only the window sums near the
#: pixels that moved; when more than :data:`SUM_TILE_FULL_SHARE` of the tiles hold such pixels
#: it recomputes the whole image (:func:`tiled_blocks`).
SUM_TILE_PX = 64
SUM_TILE_FULL_SHARE = 0.5


def dirty_blocks(moved: np.ndarray, halo: int) -> list[Block]:
    """Blocks covering every pixel within ``halo`` px (the window's half side) of a ``moved``
    pixel (bool ``(H, W)``): the runs of such :data:`SUM_TILE_PX` tiles along each row of
    tiles, or the whole image (:func:`tiled_blocks`) when most tiles are."""
    height, width = moved.shape
    tile = SUM_TILE_PX
    near = cv2.dilate(moved.astype(np.uint8), np.ones((2 * halo + 1, 2 * halo + 1), np.uint8))
    tiles_v, tiles_u = -(-height // tile), -(-width // tile)
    padded = np.zeros((tiles_v * tile, tiles_u * tile), np.uint8)
    padded[:height, :width] = near
    dirty = padded.reshape(tiles_v, tile, tiles_u, tile).any(axis=(1, 3))
    if dirty.mean() > SUM_TILE_FULL_SHARE:
        return tiled_blocks(moved.shape, halo)
    blocks = []
    for i in np.flatnonzero(dirty.any(axis=1)):
        run = np.flatnonzero(dirty[i])
        breaks = np.flatnonzero(np.diff(run) > 1)
        r0, r1 = i * tile, min((i + 1) * tile, height)
        for s, e in zip(np.r_[run[0], run[breaks + 1]], np.r_[run[breaks], run[-1]] + 1):
            c0, c1 = s * tile, min(e * tile, width)
            blocks.append(Block(r0, r1, max(r0 - halo, 0), min(r1 + halo, height),
                                 c0, c1, max(c0 - halo, 0), min(c1 + halo, width)))
    return blocks


def worker_count() -> int:
    return max(1, os.cpu_count() or 1)
