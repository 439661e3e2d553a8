"""Calibration boards: their geometry in the board frame, the pattern OpenCV draws, and the
detection of their corners with OpenCV.

Board frame (mm): origin at the pattern's top-left corner as OpenCV draws it, x along the image
columns (right), y along the rows (down), z = x × y, pointing *away* from whoever looks at the
printed side. A board pose ``(R, t)`` maps board to reference coordinates,
``X_ref = R @ X_board + t``.

Two kinds (``kind``):

* ``"chessboard"``: ``cols × rows`` squares, the top-left one black; the inner corners are
  numbered row by row, ``id = i·(cols − 1) + j`` at ``((j + 1)·s, (i + 1)·s, 0)``. Detected with
  OpenCV's classic detector or ``cv2.findChessboardCornersSB`` (:func:`grid_candidates`), the
  corners refined to their point of symmetry and every grid checked before it is accepted
  (:mod:`measure.calibration.corners`). The 180° ambiguity of a board with one odd and one
  even count is resolved by the colours of all the squares the corners enclose
  (:func:`square_parity_contrast`: the top-left square is black; a board printed with its
  top-left square white is the same board turned by 180°, and is measured in that frame); a
  board of odd × odd or even × even squares (ROS's 8 × 6 inner corners) looks the same turned
  by 180° (:attr:`Board.symmetric`, :meth:`Board.symmetries`): one camera's calibration does
  not care, a rig's settles the turn by its cameras' consistency.
* ``"charuco"``: OpenCV's ``cv2.aruco.CharucoBoard`` (``dictionary``, default ``DICT_5X5_1000``,
  any of OpenCV's predefined ``DICT_…`` names; markers ``marker_ratio`` of a square); corner
  ids and positions are OpenCV's (``getChessboardCorners``). Detected with
  ``cv2.aruco.CharucoDetector``; partial views work.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

from .corners import check_grid, corner_spacing, refine_corners

BOARD_KINDS = ("chessboard", "charuco", "circles", "acircles")
#: The circle grids: OpenCV's symmetric (``circles``) and asymmetric (``acircles``) grids.
CIRCLE_KINDS = ("circles", "acircles")
CHARUCO_DICTIONARY = "DICT_5X5_1000"
#: Texels per square of the printed pattern as renderers use it (ChArUco marker bits stay whole
#: texels).
PATTERN_TEXELS_PER_SQUARE = 140
#: Corners fewer than this in a view do not count as a detection of the board.
MIN_CORNERS = 6
#: Chessboards are found on the image halved until it is at most this wide (OpenCV's search
#: takes ~3 s on a 2448 px image with CALIB_CB_ACCURACY, 0.14 s at 1224 px without it); the
#: corners are then refined on the full image (:func:`measure.calibration.corners.
#: refine_corners`). Where nothing is found there, the full image is searched as well (small,
#: steep boards).
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
    square side and ``dictionary`` OpenCV's predefined ArUco dictionary (ChArUco only).
    A circle grid (:data:`CIRCLE_KINDS`): ``squares`` = (dots per row, rows), OpenCV's
    ``patternSize``; ``square_mm`` the grid's pitch (OpenCV's object points: ``(j·s, i·s)``,
    asymmetric ``((2j + i mod 2)·s, i·s)``, the first dot at the origin); ``circle_mm`` the
    dots' diameter (0: not given; their eccentricity is then not corrected)."""

    kind: str = "chessboard"
    squares: tuple = (11, 8)
    square_mm: float = 40.0
    marker_ratio: float = 0.5
    dictionary: str = CHARUCO_DICTIONARY
    circle_mm: float = 0.0

    def __post_init__(self):
        if self.kind not in BOARD_KINDS:
            raise BoardError(f"board kind {self.kind!r}: choose from {', '.join(BOARD_KINDS)}")
        try:
            cols, rows = (int(v) for v in self.squares)
        except (TypeError, ValueError):
            raise BoardError(f"board squares must be two integers (cols, rows), got "
                             f"{self.squares!r}") from None
        least = 2 if self.kind in CIRCLE_KINDS else 3
        if cols < least or rows < least or cols > 100 or rows > 100:
            what = "dots per row and rows" if self.kind in CIRCLE_KINDS else "board squares"
            raise BoardError(f"{what} must be {least}..100 each, got {cols}x{rows}")
        if not (np.isfinite(self.circle_mm) and self.circle_mm >= 0):
            raise BoardError(f"dot diameter must be positive, got {self.circle_mm!r} mm")
        if self.kind in CIRCLE_KINDS and self.circle_mm >= self.square_mm * (
                2 if self.kind == "acircles" else 1):
            raise BoardError(f"dots of {self.circle_mm:g} mm do not fit a pitch of "
                             f"{self.square_mm:g} mm")
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
        object.__setattr__(self, "circle_mm", float(self.circle_mm))

    # --- geometry -----------------------------------------------------------------------------
    @property
    def size_mm(self) -> tuple[float, float]:
        """(width, height) of the pattern, mm."""
        return self.squares[0] * self.square_mm, self.squares[1] * self.square_mm

    @property
    def n_corners(self) -> int:
        """The board's points: inner corners, or a circle grid's dots."""
        if self.kind in CIRCLE_KINDS:
            return self.squares[0] * self.squares[1]
        return (self.squares[0] - 1) * (self.squares[1] - 1)

    def corners(self) -> np.ndarray:
        """Inner corners (a circle grid: its dots' centres) ``(n_corners, 3)`` in the board
        frame (mm), in id order."""
        if self.kind == "charuco":
            return np.asarray(self._charuco().getChessboardCorners(), dtype=np.float64)
        if self.kind in CIRCLE_KINDS:
            i, j = (g.ravel() for g in np.mgrid[0:self.squares[1], 0:self.squares[0]])
            x = 2 * j + i % 2 if self.kind == "acircles" else j
            return np.column_stack([x, i, np.zeros(i.size)]).astype(np.float64) * self.square_mm
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
        """The printed sheet (module docs below); a chessboard or ChArUco board only."""
        if self.kind in CIRCLE_KINDS:
            raise BoardError("a circle grid is not rendered here (chessboard or charuco)")
        return self._squares_pattern(px_per_square)

    def _squares_pattern(self, px_per_square: int) -> np.ndarray:
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
        spacing = float(np.median(corner_spacing(uv)))
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
            del out["marker_ratio"]
        if self.kind not in CIRCLE_KINDS:
            del out["circle_mm"]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> Board:
        try:
            return cls(kind=data["kind"], squares=tuple(data["squares"]),
                       square_mm=float(data["square_mm"]),
                       marker_ratio=float(data.get("marker_ratio", 0.5)),
                       dictionary=str(data.get("dictionary", CHARUCO_DICTIONARY)),
                       circle_mm=float(data.get("circle_mm", 0.0)))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, BoardError):
                raise
            raise BoardError(f"not a board definition ({exc})") from None

    # --- detection ----------------------------------------------------------------------------
    @property
    def symmetric(self) -> bool:
        """Whether the board looks the same turned (a chessboard of odd × odd or even × even
        squares, a symmetric circle grid): one photo cannot tell its corner 0 from its last;
        see :meth:`symmetries`."""
        return len(self.symmetries()) > 1

    def symmetries(self) -> list:
        """The renumberings of the points that a photo cannot tell apart, ``[(ids (n,), R
        (3, 3), t (3,))]``: point ``i`` may be the board's ``ids[i]``, which is the board turned
        by ``X' = R X + t`` (board frame, mm). The identity first, then each turn by 90°, 180°
        or 270° about the points' centre that maps the board onto itself (a chessboard's
        squares' colours too; a ChArUco board's markers never)."""
        points = self.corners()
        out = [(np.arange(len(points)), np.eye(3), np.zeros(3))]
        if self.kind == "charuco":
            return out
        from scipy.spatial import cKDTree

        centre = points.mean(axis=0)
        tree = cKDTree(points[:, :2])
        for degrees in (180, 90, 270):
            c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
            R = np.array([[np.rint(c), -np.rint(s), 0], [np.rint(s), np.rint(c), 0], [0, 0, 1.0]])
            t = centre - R @ centre
            distance, ids = tree.query((points @ R.T + t)[:, :2])
            if np.all(distance < 1e-6 * self.square_mm) and len(set(ids)) == len(ids) and (
                    self.kind != "chessboard" or self._colours_kept(R)):
                out.append((ids, R, t))
        return out

    def _colours_kept(self, R) -> bool:
        """Whether turning a chessboard by ``R`` (about its centre) keeps black squares black:
        a turn by 180° does when cols + rows is even, by 90° (cols = rows) when cols is odd."""
        cols, rows = self.squares
        if abs(R[0, 0] + 1) < 1e-9:  # 180°
            return (cols + rows) % 2 == 0
        return cols % 2 == 1

    def detect(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Corners of the board in a single-channel image (any dtype; linear values — a photo
        decoded, a render as it is): ``(ids (M,), pixels (M, 2))`` in OpenCV pixel coordinates;
        empty when the board is not found (or fewer than :data:`MIN_CORNERS` corners).

        Chessboards: the detectors (:func:`grid_candidates`: the classic detector, then
        ``findChessboardCornersSB``) search the image as a camera stores it
        (:func:`detector_view`); each grid they return is numbered as the board
        (:meth:`_oriented`), refined on the linear image
        (:func:`measure.calibration.corners.refine_corners`) and checked
        (:func:`measure.calibration.corners.check_grid`): the first grid that is the board is
        kept, without the corners that fail the checks."""
        if self.kind == "charuco":
            corners, ids, _, _ = cv2.aruco.CharucoDetector(self._charuco()).detectBoard(
                to_uint8(image))
            if ids is None or len(ids) < MIN_CORNERS:
                return np.empty(0, int), np.empty((0, 2))
            return ids.ravel().astype(int), corners.reshape(-1, 2).astype(np.float64)
        if self.kind in CIRCLE_KINDS:
            return self._detect_dots(image)
        cols, rows = self.squares[0] - 1, self.squares[1] - 1
        view = detector_view(image)
        for uv in grid_candidates(view, (cols, rows)):
            uv = self._oriented(view, uv)
            refined, converged = refine_corners(image, uv)
            check = check_grid(image, refined, converged, rows, cols)
            if check.valid and np.count_nonzero(check.keep) >= MIN_CORNERS:
                ids = np.flatnonzero(check.keep)
                return ids, refined[ids]
        return np.empty(0, int), np.empty((0, 2))

    def _detect_dots(self, image) -> tuple[np.ndarray, np.ndarray]:
        """A circle grid's dots (:mod:`measure.calibration.circles`): OpenCV's grid, numbered
        as the board (a grid seen mirrored — its rows running the other way round the first
        dot than the board's — renumbered row by row backwards; a symmetric grid from the dot
        nearest the image's top-left), each centre measured on the linear image."""
        from .circles import find_circle_grid, refine_dot_centres

        found = find_circle_grid(detector_view(image), self.squares, self.kind == "acircles")
        if found is None:
            return np.empty(0, int), np.empty((0, 2))
        uv, light = found
        cols, rows = self.squares
        if _handedness(uv, self.corners()) < 0 and self.kind == "circles":
            uv = uv.reshape(rows, cols, 2)[::-1].reshape(-1, 2)
        if self.symmetric:
            uv = self._canonical(uv)
        refined, ok = refine_dot_centres(image, uv, corner_spacing(uv), light)
        ids = np.flatnonzero(ok)
        if ids.size < MIN_CORNERS:
            return np.empty(0, int), np.empty((0, 2))
        return ids, refined[ids]

    def _canonical(self, uv) -> np.ndarray:
        """Of the numberings :meth:`symmetries` allows, the one whose point 0 lies nearest the
        image's top-left (smallest u + v, then v)."""
        candidates = [uv[np.argsort(ids)] for ids, _, _ in self.symmetries()]
        return min(candidates, key=lambda c: (float(c[0].sum()), float(c[0][1])))

    def _oriented(self, gray, uv) -> np.ndarray:
        """A detector's grid ``uv`` numbered as the board: turned by 180° where the squares
        between its corners are light where the board's are black
        (:func:`square_parity_contrast`); a symmetric board (:attr:`symmetric`), which no photo
        can orient, numbered from the corner nearest the image's top-left (the pair's and the
        rig's calibrations settle the turn between cameras by their consistency)."""
        if self.symmetric:
            return self._canonical(uv)
        if square_parity_contrast(gray, uv, self.squares) < 0:
            return uv[::-1].copy()
        return uv


def _handedness(uv, points) -> float:
    """The sign with which the image ``uv`` of board ``points`` (the same order) turns: +1 when
    the board is seen from its printed side (x then y of the board turn as u then v of the
    image), −1 mirrored; from the signed areas of the two point sets."""
    # the signed area of the points taken in id order round their hull, image against board
    order = _hull_order(points)
    return float(np.sign(_signed_area(uv[order]) * _signed_area(points[order, :2])))


def _hull_order(points) -> np.ndarray:
    """Ids of the board points on their convex hull, in the hull's order."""
    xy = np.ascontiguousarray(np.asarray(points, np.float32)[:, :2])
    return cv2.convexHull(xy, returnPoints=False).ravel()


def _signed_area(polygon) -> float:
    x, y = np.asarray(polygon, np.float64)[:, 0], np.asarray(polygon, np.float64)[:, 1]
    return float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) / 2)


#: The seed of OpenCV's random generator before each ``findChessboardCornersSB`` call: the
#: detector draws from it (on OpenCV's stereo sample the same image was found in 4 of 5 calls,
#: and calibrations of one folder differed run to run); OpenCV's generator is per thread.
DETECTOR_SEED = 0x5EED


def _find_chessboard_sb(gray, pattern):
    """``cv2.findChessboardCornersSB`` (exhaustive), reproducible: OpenCV's generator seeded
    with :data:`DETECTOR_SEED` first, in the calling thread."""
    cv2.setRNGSeed(DETECTOR_SEED)
    return cv2.findChessboardCornersSB(gray, pattern, flags=cv2.CALIB_CB_EXHAUSTIVE)


def _find_chessboard_classic(gray, pattern):
    """``cv2.findChessboardCorners`` with adaptive thresholds and normalisation."""
    return cv2.findChessboardCorners(
        gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)


def grid_candidates(view: np.ndarray, pattern):
    """The grids ``(cols·rows, 2)`` OpenCV's chessboard detectors find in ``view`` (uint8, as
    stored), cheapest first: on the image halved until at most :data:`DETECTION_WIDTH_PX`
    wide the classic detector, then ``findChessboardCornersSB``; on a halved image also SB on
    the full one (small, steep boards). Pixels of the full image (a pixel ``i`` of a halved
    image is centred on ``2i + 0.5``). A generator: the caller stops at the first grid it
    accepts."""
    small, levels = view, 0
    while small.shape[1] > DETECTION_WIDTH_PX:
        small, levels = cv2.pyrDown(small), levels + 1
    tries = [(_find_chessboard_classic, small, levels), (_find_chessboard_sb, small, levels)]
    if levels:
        tries.append((_find_chessboard_sb, view, 0))
    for find, image, level in tries:
        found, corners = find(image, pattern)
        if found:
            scale = 2.0 ** level
            yield corners.reshape(-1, 2).astype(np.float64) * scale + (scale - 1) / 2


def detector_view(image: np.ndarray) -> np.ndarray:
    """The image as a camera stores it, for OpenCV's detectors (uint8): ``image`` itself when
    it is uint8, else its linear values over their white (the 99.9th percentile) encoded with
    the sRGB curve before they are rounded — an 8-bit sRGB photo read as linear comes back as
    its own stored levels; rounding linear values to 8 bits first would crush the darks (sRGB
    levels 0–55 into 0–9)."""
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return image
    # the linear values on 65536 levels of their white, then the sRGB curve by a table
    levels = np.clip(image.astype(np.float32) * np.float32(65535.0 / _white(image)), 0, 65535)
    return _SRGB_TABLE[np.rint(levels).astype(np.uint16)]


def _srgb_table() -> np.ndarray:
    """uint8 of the sRGB curve of 65536 linear levels (0 … 1)."""
    x = np.arange(65536) / 65535.0
    encoded = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(255 * encoded).astype(np.uint8)


_SRGB_TABLE = _srgb_table()


def _white(image: np.ndarray) -> float:
    """A linear image's white: the 99.9th percentile of every fourth pixel of every fourth row
    (its maximum where that is 0; 1 when both are)."""
    a = np.asarray(image)
    a = a[::4, ::4] if a.ndim == 2 and min(a.shape) >= 64 else a
    a = a.astype(np.float64)
    white = float(np.percentile(a, 99.9)) if a.size else 1.0
    return white if white > 0 else (float(a.max()) if a.size else 0.0) or 1.0


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
    sigma = max(spacing / 4, 0.5)
    h, w = np.asarray(gray).shape[:2]
    lo = np.floor(centres.reshape(-1, 2).min(axis=0) - 4 * sigma - 2).astype(int).clip(0)
    hi = np.ceil(centres.reshape(-1, 2).max(axis=0) + 4 * sigma + 2).astype(int).clip(
        None, [w - 1, h - 1])
    blurred = cv2.GaussianBlur(np.asarray(gray[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1], np.float32),
                               (0, 0), sigma)  # only round the squares sampled
    centres = centres - lo
    maps = centres.reshape(-1, 1, 2).astype(np.float32)
    values = cv2.remap(blurred, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE).reshape(rows - 1, cols - 1)
    i, j = np.mgrid[0:rows - 1, 0:cols - 1]
    black = (i + j) % 2 == 0
    return float(values[~black].mean() - values[black].mean())


def to_uint8(image: np.ndarray) -> np.ndarray:
    """A linear image scaled so that its 99.9th percentile is 255 (uint8), for the detectors."""
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return image
    return np.clip(np.rint(image.astype(np.float64) * (255.0 / _white(image))), 0,
                   255).astype(np.uint8)


__all__ = ["BOARD_KINDS", "Board", "CIRCLE_KINDS", "BoardError", "DETECTION_WIDTH_PX", "LAYOUT_TOLERANCE",
           "MARKER_TOLERANCE", "MIN_CORNERS", "PATTERN_TEXELS_PER_SQUARE", "detector_view",
           "grid_candidates", "square_parity_contrast", "to_uint8"]
