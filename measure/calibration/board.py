"""Calibration boards: their geometry in the board frame, the pattern OpenCV draws, and the
detection of their corners with OpenCV.

Board frame (mm): origin at the pattern's top-left corner as OpenCV draws it, x along the image
columns (right), y along the rows (down), z = x × y, pointing *away* from whoever looks at the
printed side. A board pose ``(R, t)`` maps board to reference coordinates,
``X_ref = R @ X_board + t``.

Two kinds (``kind``):

* ``"chessboard"``: ``cols × rows`` squares, the top-left one black; the inner corners are
  numbered row by row, ``id = i·(cols − 1) + j`` at ``((j + 1)·s, (i + 1)·s, 0)``. Detected with
  ``cv2.findChessboardCornersSB``; its 180° ambiguity (one of ``cols``, ``rows`` must be odd,
  the other even) is resolved by the colours of all the squares the corners enclose
  (:func:`square_parity_contrast`: the top-left square is black; a board printed with its
  top-left square white is the same board turned by 180°, and is measured in that frame).
  The corners are then refined to the saddle point of the blurred image
  (:func:`refine_saddle_points`), which is what makes them accurate.
* ``"charuco"``: OpenCV's ``cv2.aruco.CharucoBoard`` (``dictionary``, default ``DICT_5X5_1000``,
  any of OpenCV's predefined ``DICT_…`` names; markers ``marker_ratio`` of a square); corner
  ids and positions are OpenCV's (``getChessboardCorners``). Detected with
  ``cv2.aruco.CharucoDetector``; partial views work.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

BOARD_KINDS = ("chessboard", "charuco")
CHARUCO_DICTIONARY = "DICT_5X5_1000"
#: Texels per square of the printed pattern as renderers use it (ChArUco marker bits stay whole
#: texels).
PATTERN_TEXELS_PER_SQUARE = 140
#: Corners fewer than this in a view do not count as a detection of the board.
MIN_CORNERS = 6
#: Chessboards are found on the image halved until it is at most this wide (OpenCV's search
#: takes ~3 s on a 2448 px image with CALIB_CB_ACCURACY, 0.14 s at 1224 px without it); the
#: corners are then refined on the full image (:func:`refine_saddle_points`). Where nothing is
#: found there, the full image is searched as well (small, steep boards).
DETECTION_WIDTH_PX = 1300


#: :meth:`Board.charuco_problem`: the largest RMS distance (a fraction of the corner spacing)
#: of a photo's ChArUco corners from one homography of the board's plane, and the largest
#: relative difference between the markers' side seen and the one given.
LAYOUT_TOLERANCE, MARKER_TOLERANCE = 0.25, 0.08


class BoardError(ValueError):
    """A board definition that cannot be used."""


@dataclass(frozen=True)
class Board:
    """A planar calibration board (see module docs). ``squares`` = (cols, rows);
    ``square_mm`` the side of one square; ``marker_ratio`` the ArUco marker side over the
    square side and ``dictionary`` OpenCV's predefined ArUco dictionary (ChArUco only)."""

    kind: str = "chessboard"
    squares: tuple = (11, 8)
    square_mm: float = 40.0
    marker_ratio: float = 0.5
    dictionary: str = CHARUCO_DICTIONARY

    def __post_init__(self):
        if self.kind not in BOARD_KINDS:
            raise BoardError(f"board kind {self.kind!r}: choose from {', '.join(BOARD_KINDS)}")
        try:
            cols, rows = (int(v) for v in self.squares)
        except (TypeError, ValueError):
            raise BoardError(f"board squares must be two integers (cols, rows), got "
                             f"{self.squares!r}") from None
        if cols < 3 or rows < 3 or cols > 100 or rows > 100:
            raise BoardError(f"board squares must be 3..100 each, got {cols}x{rows}")
        if self.kind == "chessboard" and (cols + rows) % 2 == 0:
            raise BoardError(f"a {cols}x{rows} chessboard looks the same turned by 180°: one of "
                             f"the two numbers of squares must be odd and the other even")
        if not (np.isfinite(self.square_mm) and self.square_mm > 0):
            raise BoardError(f"square size must be positive, got {self.square_mm!r} mm")
        if not 0.1 <= self.marker_ratio <= 0.9:
            raise BoardError(f"marker ratio must lie in [0.1, 0.9], got {self.marker_ratio!r}")
        if not (str(self.dictionary).startswith("DICT_") and hasattr(cv2.aruco, self.dictionary)):
            raise BoardError(f"ArUco dictionary {self.dictionary!r}: not one of OpenCV's "
                             f"predefined dictionaries (e.g. {CHARUCO_DICTIONARY}, DICT_4X4_50, "
                             f"DICT_6X6_250, DICT_APRILTAG_36h11)")
        object.__setattr__(self, "squares", (cols, rows))
        object.__setattr__(self, "square_mm", float(self.square_mm))
        object.__setattr__(self, "marker_ratio", float(self.marker_ratio))

    # --- geometry -----------------------------------------------------------------------------
    @property
    def size_mm(self) -> tuple[float, float]:
        """(width, height) of the pattern, mm."""
        return self.squares[0] * self.square_mm, self.squares[1] * self.square_mm

    @property
    def n_corners(self) -> int:
        return (self.squares[0] - 1) * (self.squares[1] - 1)

    def corners(self) -> np.ndarray:
        """Inner corners ``(n_corners, 3)`` in the board frame (mm), in id order."""
        if self.kind == "charuco":
            return np.asarray(self._charuco().getChessboardCorners(), dtype=np.float64)
        cols, rows = self.squares
        j, i = np.meshgrid(np.arange(1, cols), np.arange(1, rows))
        return np.column_stack([j.ravel(), i.ravel(), np.zeros(j.size)]) * self.square_mm

    @property
    def margin_mm(self) -> float:
        """Width of the white border printed around the squares (one square), mm."""
        return self.square_mm

    def outline(self) -> np.ndarray:
        """The printed sheet's four corners ``(4, 3)`` in the board frame (mm): the squares and
        the white border around them."""
        w, h = self.size_mm
        m = self.margin_mm
        return np.array([[-m, -m, 0], [w + m, -m, 0], [w + m, h + m, 0], [-m, h + m, 0]],
                        dtype=np.float64)

    # --- the pattern --------------------------------------------------------------------------
    def pattern(self, px_per_square: int) -> np.ndarray:
        """The printed sheet, uint8 ``(rows·p + 2p, cols·p + 2p)`` (black 0, white 255): the
        squares inside a white border one square wide (the corners on the outer rows stay
        X-junctions, not T-junctions against a dark background); pixel edges fall on the
        squares' edges."""
        p = int(px_per_square)
        cols, rows = self.squares
        size = ((cols + 2) * p, (rows + 2) * p)
        if self.kind == "charuco":
            return self._charuco().generateImage(size, marginSize=p, borderBits=1)
        i, j = np.mgrid[0:rows * p, 0:cols * p] // p
        squares = np.where((i + j) % 2 == 1, 255, 0).astype(np.uint8)
        return cv2.copyMakeBorder(squares, p, p, p, p, cv2.BORDER_CONSTANT, value=255)

    def charuco_problem(self, image: np.ndarray) -> str | None:
        """Whether a photo of a ChArUco board contradicts this board's geometry (None when it
        does not, or when no board is found): the detected corners are fitted with one
        homography from the board's plane (least squares); corners farther from it than
        :data:`LAYOUT_TOLERANCE` of their spacing say that the squares are numbered for
        another board (``--squares``), and markers whose side, mapped back onto the board,
        differs from ``marker_ratio × square_mm`` by more than :data:`MARKER_TOLERANCE` say
        that the marker size is wrong (``--marker-mm``). Both were calibrated silently before
        (a wrong marker size: 2.2–2.9 px RMS, cx 12 px off)."""
        if self.kind != "charuco":
            return None
        corners, ids, markers, _ = cv2.aruco.CharucoDetector(self._charuco()).detectBoard(
            to_uint8(image))
        if ids is None or len(ids) < MIN_CORNERS or markers is None or not len(markers):
            return None
        board_xy = self.corners()[ids.ravel()][:, :2]
        uv = corners.reshape(-1, 2).astype(np.float64)
        H, _ = cv2.findHomography(board_xy, uv, 0)
        if H is None:
            return None
        fitted = cv2.perspectiveTransform(board_xy.reshape(-1, 1, 2), H).reshape(-1, 2)
        spacing = float(np.median(saddle_scales(uv)[0]))
        miss = float(np.sqrt(np.mean(np.sum((fitted - uv) ** 2, axis=1))))
        if miss > LAYOUT_TOLERANCE * spacing:
            return (f"the ChArUco corners found do not lie on a {self.squares[0]}x"
                    f"{self.squares[1]} board's grid (RMS {miss:.1f} px from one plane's "
                    f"homography, the corners {spacing:.0f} px apart): check --squares and "
                    f"--dictionary")
        on_board = cv2.perspectiveTransform(
            np.concatenate([m.reshape(-1, 1, 2) for m in markers]).astype(np.float64),
            np.linalg.inv(H)).reshape(-1, 4, 2)
        side = float(np.median(np.linalg.norm(on_board - np.roll(on_board, 1, axis=1), axis=2)))
        expected = self.marker_ratio * self.square_mm
        if abs(side / expected - 1) > MARKER_TOLERANCE:
            return (f"the markers measure about {side:.0f} mm on the board, not {expected:g} "
                    f"mm: check --marker-mm (the side of a marker's black square; measured "
                    f"through the corners' homography, a few % small on blurred photos)")
        return None

    def _charuco(self):
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square_mm,
                                      self.marker_ratio * self.square_mm, dictionary)

    # --- files --------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        out = asdict(self)
        out["squares"] = list(self.squares)
        out["frame"] = ("origin at the pattern's top-left corner, x right, y down, z away from "
                        "the printed side; mm")
        if self.kind != "charuco":  # a chessboard has no markers: its file says nothing of them
            del out["dictionary"]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> Board:
        try:
            return cls(kind=data["kind"], squares=tuple(data["squares"]),
                       square_mm=float(data["square_mm"]),
                       marker_ratio=float(data.get("marker_ratio", 0.5)),
                       dictionary=str(data.get("dictionary", CHARUCO_DICTIONARY)))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, BoardError):
                raise
            raise BoardError(f"not a board definition ({exc})") from None

    # --- detection ----------------------------------------------------------------------------
    def detect(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Corners of the board in a single-channel image (any dtype, linear): ``(ids (M,),
        pixels (M, 2))`` in OpenCV pixel coordinates; empty when the board is not found (or
        fewer than :data:`MIN_CORNERS` corners)."""
        gray = to_uint8(image)
        if self.kind == "charuco":
            corners, ids, _, _ = cv2.aruco.CharucoDetector(self._charuco()).detectBoard(gray)
            if ids is None or len(ids) < MIN_CORNERS:
                return np.empty(0, int), np.empty((0, 2))
            return ids.ravel().astype(int), corners.reshape(-1, 2).astype(np.float64)
        cols, rows = self.squares
        pattern = (cols - 1, rows - 1)
        levels = 0  # find the board on a reduced image: the saddle refinement gives accuracy
        small = gray
        while small.shape[1] > DETECTION_WIDTH_PX:
            small, levels = cv2.pyrDown(small), levels + 1
        found, corners = _find_chessboard_sb(small, pattern)
        if not found:  # the classic detector finds some steep views SB misses
            found, corners = cv2.findChessboardCorners(
                small, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:  # photos as stored (sRGB): SB finds real boards there it missed
            found, corners = _find_chessboard_sb(srgb_uint8(small), pattern)
        if not found and levels:  # small, steep boards: the full image (about 1 s more)
            found, corners = _find_chessboard_sb(gray, pattern)
            levels = 0 if found else levels
        if not found:
            return np.empty(0, int), np.empty((0, 2))
        scale = 2.0 ** levels  # pyrDown: pixel i of the half image is centred on 2i + 0.5
        uv = corners.reshape(-1, 2).astype(np.float64) * scale + (scale - 1) / 2
        if not self._squares_agree(gray, uv):
            uv = uv[::-1].copy()
        refined, converged = refine_saddle_points(image, uv)
        ids = np.flatnonzero(converged)
        if ids.size < MIN_CORNERS:
            return np.empty(0, int), np.empty((0, 2))
        return ids, refined[ids]

    def _squares_agree(self, gray, uv) -> bool:
        """Whether the squares between the detected corners ``uv`` (in the detector's order)
        are dark where the board's squares are black (:meth:`square_parity_contrast` ≥ 0):
        otherwise the detector's order is the board's turned by 180°."""
        return square_parity_contrast(gray, uv, self.squares) >= 0


#: The seed of OpenCV's random generator before each ``findChessboardCornersSB`` call: the
#: detector draws from it (on OpenCV's stereo sample the same image was found in 4 of 5 calls,
#: and calibrations of one folder differed run to run); OpenCV's generator is per thread.
DETECTOR_SEED = 0x5EED


def _find_chessboard_sb(gray, pattern):
    """``cv2.findChessboardCornersSB`` (exhaustive), reproducible: OpenCV's generator seeded
    with :data:`DETECTOR_SEED` first, in the calling thread."""
    cv2.setRNGSeed(DETECTOR_SEED)
    return cv2.findChessboardCornersSB(gray, pattern, flags=cv2.CALIB_CB_EXHAUSTIVE)


def srgb_uint8(gray: np.ndarray) -> np.ndarray:
    """A linear uint8 image (:func:`to_uint8`) encoded with the sRGB curve, as cameras store
    photos: the contrast OpenCV's chessboard detectors are used to."""
    levels = np.arange(256) / 255.0
    table = np.where(levels <= 0.0031308, 12.92 * levels, 1.055 * levels ** (1 / 2.4) - 0.055)
    return np.rint(255 * table).astype(np.uint8)[gray]


def square_parity_contrast(gray, uv, squares) -> float:
    """How much brighter the squares that should be white are than those that should be black
    (grey levels), for inner corners ``uv`` ``((cols−1)·(rows−1), 2)`` numbered row by row.

    Every square enclosed by four corners is sampled at its centre (the mean of its four
    corners; bilinear, on the image blurred by a quarter of the corner spacing): square
    ``(i, j)`` between corner rows ``i, i+1`` and columns ``j, j+1`` is the board's square
    ``(i+1, j+1)``, black when ``i + j`` is even (the top-left square is black). All enclosed
    squares vote, so a corner near the image's edge or a frame line printed around the board
    cannot turn the answer (one sample outside the grid did, on OpenCV's own stereo sample).
    Negative: the order is the board's turned by 180° (for a board with one odd and one even
    number of squares the two orders have opposite parities)."""
    cols, rows = squares[0] - 1, squares[1] - 1
    grid = np.asarray(uv, dtype=np.float64).reshape(rows, cols, 2)
    centres = (grid[:-1, :-1] + grid[:-1, 1:] + grid[1:, :-1] + grid[1:, 1:]) / 4
    spacing = float(np.median(np.linalg.norm(np.diff(grid, axis=1), axis=2)))
    blurred = cv2.GaussianBlur(np.asarray(gray, np.float32), (0, 0), max(spacing / 4, 0.5))
    maps = centres.reshape(-1, 1, 2).astype(np.float32)
    values = cv2.remap(blurred, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE).reshape(rows - 1, cols - 1)
    i, j = np.mgrid[0:rows - 1, 0:cols - 1]
    black = (i + j) % 2 == 0
    return float(values[~black].mean() - values[black].mean())


#: Saddle-point refinement: Gaussian blur σ and half window, as fractions of the distance to the
#: nearest corner (the local square size in pixels); Newton iterations.
SADDLE_BLUR, SADDLE_HALF_WINDOW, SADDLE_ITERATIONS = 0.15, 0.3, 8
#: Last Newton step (px) below which a corner's refinement has converged.
SADDLE_TOLERANCE_PX = 1e-3


def saddle_scales(uv: np.ndarray):
    """``(spacing (N,), blur σ)`` of :func:`refine_saddle_points` for corners ``uv`` ``(N, 2)``:
    each corner's distance to its nearest neighbour (px) and the blur, :data:`SADDLE_BLUR` ×
    their median."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    gaps = np.linalg.norm(uv[:, None] - uv[None], axis=2)
    np.fill_diagonal(gaps, np.inf)
    spacing = gaps.min(axis=1)
    return spacing, SADDLE_BLUR * float(np.median(spacing))


def refine_saddle_points(image: np.ndarray, uv: np.ndarray, spacing=None, blur_sigma=None):
    """Chessboard corners ``(N, 2)`` refined to the saddle point of the blurred image, and
    whether each converged ``(N,)``.

    An X-junction of two straight edges is point-symmetric about the corner, and so is its image
    blurred with an isotropic Gaussian: the corner is the saddle point, whatever the angle
    between the edges (perspective). Each corner's neighbourhood (half window
    :data:`SADDLE_HALF_WINDOW` × the distance to its nearest corner, Gaussian weights) is fitted
    with a quadratic by weighted least squares and the corner moved to its stationary point, a
    few times (vectorized over corners). On rendered tilted boards in air this gave 0.013 px
    RMS where ``findChessboardCornersSB`` gave 0.08–0.42 px and ``cornerSubPix`` 0.05–0.08 px
    (docs/architecture.md). Through a flat port the board's straight edges image as curves;
    the rendered corners then sit 0.02–0.04 px outwards of the forward model (docs/architecture.md:
    about half of it is the renderer's ray-spawn offset at the port). A corner converged when its
    last step is below
    :data:`SADDLE_TOLERANCE_PX` and it stayed within its window; others keep their input
    position and are flagged (an outlier of the detector, or not a corner). ``spacing`` and
    ``blur_sigma`` default to :func:`saddle_scales` of ``uv``."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if uv.shape[0] < 2 and spacing is None:
        return uv.copy(), np.zeros(uv.shape[0], bool)
    if spacing is None or blur_sigma is None:
        spacing, blur_sigma = saddle_scales(uv)
    spacing = np.asarray(spacing, dtype=np.float64)
    blurred = cv2.GaussianBlur(np.asarray(image, np.float32), (0, 0),
                               float(blur_sigma)).astype(np.float64)
    h, w = blurred.shape
    half = SADDLE_HALF_WINDOW * spacing
    r = int(np.ceil(half.max()))
    dy, dx = (g.ravel() for g in np.mgrid[-r:r + 1, -r:r + 1])
    out = uv.copy()
    last = np.full(uv.shape[0], np.inf)
    for _ in range(SADDLE_ITERATIONS):
        c = np.rint(out).astype(int)
        xs, ys = c[:, :1] + dx, c[:, 1:] + dy
        inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
        values = blurred[np.clip(ys, 0, h - 1), np.clip(xs, 0, w - 1)]
        X, Y = xs - out[:, :1], ys - out[:, 1:]
        rr = X * X + Y * Y
        weight = np.exp(-rr / (2 * (half[:, None] / 2) ** 2)) * inside * (rr <= half[:, None] ** 2)
        A = np.stack([X * X, X * Y, Y * Y, X, Y, np.ones_like(X)], axis=-1)
        normal = np.einsum("nk,nki,nkj->nij", weight, A, A)
        rhs = np.einsum("nk,nki,nk->ni", weight, A, values)
        with np.errstate(invalid="ignore", divide="ignore"):
            ok = np.abs(np.linalg.det(normal)) > 0
            p = np.zeros((uv.shape[0], 6))
            p[ok] = np.linalg.solve(normal[ok], rhs[ok][..., None])[..., 0]
            a, b, cc, d, e = p[:, 0], p[:, 1], p[:, 2], p[:, 3], p[:, 4]
            det = 4 * a * cc - b * b
            ok &= det < 0  # a saddle, not an extremum
            step = np.column_stack([(-2 * cc * d + b * e), (b * d - 2 * a * e)]) / det[:, None]
            ok &= np.all(np.isfinite(step), axis=1) & (np.linalg.norm(step, axis=1) < half)
        out[ok] += step[ok]
        last = np.where(ok, np.linalg.norm(np.where(np.isfinite(step), step, 0), axis=1), np.inf)
    converged = (last < SADDLE_TOLERANCE_PX) & (np.linalg.norm(out - uv, axis=1) < half)
    return np.where(converged[:, None], out, uv), converged


def to_uint8(image: np.ndarray) -> np.ndarray:
    """A linear image scaled so that its 99.9th percentile is 255 (uint8), for the detectors."""
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return image
    a = image.astype(np.float64)
    white = float(np.percentile(a, 99.9)) if a.size else 1.0
    white = white if white > 0 else (float(a.max()) or 1.0)
    return np.clip(np.rint(a * (255.0 / white)), 0, 255).astype(np.uint8)


__all__ = ["BOARD_KINDS", "Board", "BoardError", "LAYOUT_TOLERANCE", "MARKER_TOLERANCE",
           "MIN_CORNERS", "PATTERN_TEXELS_PER_SQUARE",
           "refine_saddle_points", "saddle_scales", "to_uint8"]
