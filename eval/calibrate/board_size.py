"""Whether the board the user named is the board in the photos: when it was found in none, which
chessboard one square more or fewer each way is (:func:`board_hint`); when it was found, whether
the photos show a larger one, of which OpenCV found a part — a different part in each photo
(:func:`larger_board`). Images are linear ``(H, W)`` or ``(H, W, 3)`` arrays, pairs
``(left, right)``; only the left ones are searched."""

from __future__ import annotations

import numpy as np

#: Photos tried per candidate board when the board is found in no photo.
HINT_PHOTOS = 3
#: Photos searched for a board larger than --squares (:func:`larger_board`), and how many
#: squares larger each way a board is looked for once one is found.
LARGER_PHOTOS, LARGER_SEARCH = 2, 4


def small_left(images) -> list:
    """The left images of ``images`` (linear) halved to at most
    :data:`measure.calibration.board.DETECTION_WIDTH_PX` wide: enough to tell which board they
    show."""
    import cv2

    from measure.calibration.board import DETECTION_WIDTH_PX

    smalls = []
    for left, _ in images:
        small = np.asarray(left, np.float32)
        while small.shape[1] > DETECTION_WIDTH_PX:
            small = cv2.pyrDown(small)
        smalls.append(small)
    return smalls


def whole_board_in(squares, image) -> bool:
    """Whether a chessboard of ``squares`` is in ``image`` with every corner checked
    (:meth:`measure.calibration.board.Board.detect`: the grid refined and validated; OpenCV's
    ``findChessboardCornersSB`` alone also returns grids one row larger than the board, onto its
    edge)."""
    from measure.calibration.board import Board

    ids, _ = Board("chessboard", squares).detect(image)
    return len(ids) == (squares[0] - 1) * (squares[1] - 1)


def boards_found(patterns, smalls) -> dict:
    """``{(c, r): [whether a chessboard of c × r squares is in each of smalls]}`` for every
    pattern of ``patterns``: each detection on a thread of its own, as many at once as there
    are cores (OpenCV's detectors release the GIL; a pattern that is not there is the slow
    case, 0.2-0.4 s a photo)."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    tasks = [(tuple(cr), k) for cr in patterns for k in range(len(smalls))]
    workers = max(1, min(os.cpu_count() or 1, len(tasks)))
    with ThreadPoolExecutor(workers) as pool:
        results = list(pool.map(lambda task: whole_board_in(task[0], smalls[task[1]]), tasks))
    found = {tuple(cr): [] for cr in patterns}
    for (cr, _), result in zip(tasks, results):
        found[cr].append(bool(result))
    return found


def larger_board(board, images, found_left) -> str:
    """Empty, or why ``--squares`` is smaller than the chessboard in the photos: OpenCV finds a
    smaller pattern inside a board (an 8x5 inside an 11x8, a 6x5 inside a 7x6), whose corners
    are a different part of the board in each photo, and the calibration is then nonsense. The
    first :data:`LARGER_PHOTOS` left photos where the board was found are searched for the
    pattern one square larger (each way, and both); when one is found, the largest pattern up to
    :data:`LARGER_SEARCH` squares larger each way is named (a pattern larger than the board is
    never found, either way round)."""
    import functools

    if board.kind != "chessboard" or not found_left:
        return ""
    smalls = small_left([images[k] for k in found_left[:LARGER_PHOTOS]])

    @functools.cache
    def seen(c, r):
        return any(boards_found([(c, r)], smalls)[(c, r)])

    cols, rows = board.squares
    if not any(seen(c, r) for c, r in ((cols + 1, rows), (cols, rows + 1), (cols + 1, rows + 1))):
        return ""
    bigger = sorted(((c, r) for c in range(cols, cols + LARGER_SEARCH + 1)
                     for r in range(rows, rows + LARGER_SEARCH + 1) if (c, r) != (cols, rows)),
                    key=lambda cr: (-cr[0] * cr[1], (cr[0] >= cr[1]) != (cols >= rows)))
    c, r = next(cr for cr in bigger if seen(*cr))
    return (f"the photos show a chessboard of at least {c}x{r} squares, not {cols}x{rows} (OpenCV "
            f"also finds a part of a board, a different part in each photo): give the whole "
            f"board, e.g. --squares {c}x{r}")


def board_hint(board, images) -> str:
    """When the board was found in no photo: the chessboard (one square more or fewer each way)
    that is found in the first :data:`HINT_PHOTOS` left photos, said as a sentence (empty when
    none is). OpenCV also finds a smaller pattern inside a larger board (a 10x6 inside an 11x8),
    so every candidate is tried and the largest one found is named (then the one found in more
    photos): a pattern larger than the board is never found."""

    if board.kind != "chessboard":
        return (" (check --squares, --marker-mm and --dictionary: no ChArUco corners of this "
                "board were found)")
    cols, rows = board.squares
    candidates = [(c, r) for c, r in ((cols + 1, rows), (cols - 1, rows), (cols, rows + 1),
                                      (cols, rows - 1), (cols + 1, rows + 1),
                                      (cols - 1, rows - 1), (cols + 1, rows - 1),
                                      (cols - 1, rows + 1))
                  if c >= 3 and r >= 3]
    smalls = small_left(images[:HINT_PHOTOS])
    found = {cr: sum(seen) for cr, seen in boards_found(candidates, smalls).items()}
    seen = [cr for cr in candidates if found[cr]]
    if seen:
        c, r = max(seen, key=lambda cr: (cr[0] * cr[1], found[cr]))
        return (f"; the photos show a chessboard of {c}x{r} squares ({c - 1}x{r - 1} inner "
                f"corners), not {cols}x{rows} squares ({cols - 1}x{rows - 1} inner corners; "
                f"found in {found[(c, r)]} of the first {len(smalls)} left photos with "
                f"--squares {c}x{r}, that is --inner-corners {c - 1}x{r - 1})")
    return (f" (no chessboard of {cols}x{rows} squares, nor one square more or fewer, in the "
            f"first {len(smalls)} left photos: check --board and --squares)")
