"""Find a calibration board in one image, or say why it is not there.

Checkerboards are found with ``cv2.findChessboardCornersSB`` (falling back to
``cv2.findChessboardCorners``, then optionally the exhaustive SB search), then every corner is refined with ``cv2.cornerSubPix``
using a window sized from the board's own corner spacing. On synthetic renders with
exact corners the SB detector alone is off by about 0.1 px on average, ``cornerSubPix``
with a window of 0.4 x the corner spacing by about 0.03 px, while OpenCV sample's fixed
11 px half-window overlaps neighbouring corners on small, tilted boards and can be off by
several pixels (it is the reason ``left02.jpg`` of OpenCV's sample has a 1.2 px view
error). ChArUco boards use ``cv2.aruco.CharucoDetector``.

When a board is not found, :func:`detect_board` tells why, in this order:
cut off at the image border (part of the board is found and its grid continues past an
edge), blurred (variance of the Laplacian below a threshold), a board of another size
(a complete grid with a different corner count), too small (found only after 2x
upsampling), or simply not found.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mocap.calib.boards import BoardSpec, charuco_board

#: Reasons a view can be unusable (``BoardDetection.problem``).
PROBLEMS = ("cut off", "wrong size", "too small", "blurred", "not found", "too few corners")

_SB_EXHAUSTIVE = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3)


@dataclass(frozen=True)
class DetectionSettings:
    """Thresholds of :func:`detect_board`.

    Attributes
    ----------
    min_corners : int
        ChArUco: fewest interpolated corners for a usable view (checkerboards need all).
    blur_threshold : float
        Variance of the Laplacian (grey levels^2) under which a failed image is called
        blurred. Sharp 640x480 photos of a board score several hundred.
    border_margin_px : float
        Corners closer than this to the image edge count as touching it.
    min_square_px : float
        Squares smaller than this (in pixels) are called too small.
    diagnose : bool
        Spend extra detector runs on failed images to say why they failed.
    exhaustive : bool
        Checkerboards: when the fast detectors fail, try OpenCV's exhaustive search
        (finds a few more boards, about a second per failed image).
    """

    min_corners: int = 6
    blur_threshold: float = 20.0
    border_margin_px: float = 12.0
    min_square_px: float = 10.0
    diagnose: bool = True
    exhaustive: bool = False


@dataclass(frozen=True)
class BoardDetection:
    """The board found in one image.

    Attributes
    ----------
    corner_ids : (n,) int
        Indices into :func:`mocap.calib.boards.board_object_points`.
    corners_px : (n, 2) float
        Sub-pixel corner positions, distorted pixels (x right, y down, pixel centres at
        integers).
    image_size : (int, int)
        ``(width, height)``.
    sharpness : float
        Variance of the Laplacian of the grey image.
    problem : str
        ``""`` when usable, else one of :data:`PROBLEMS`.
    detail : str
        What was seen, with numbers (for error messages).
    fix : str
        What to change when taking the pictures again.
    """

    corner_ids: np.ndarray
    corners_px: np.ndarray
    image_size: tuple[int, int]
    sharpness: float
    problem: str = ""
    detail: str = ""
    fix: str = ""

    @property
    def found(self) -> bool:
        return self.problem == ""

    @property
    def n_corners(self) -> int:
        return int(len(self.corner_ids))


def to_gray(image: np.ndarray) -> np.ndarray:
    """Grey uint8 ``(H, W)`` from a grey, BGR or BGRA image (any integer/float dtype)."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    if img.ndim != 2:
        raise ValueError(f"expected an image of shape (H, W) or (H, W, 3), got {np.asarray(image).shape}")
    if img.dtype != np.uint8:
        scale = 255.0 if img.dtype.kind == "f" and float(np.nanmax(img)) <= 1.0 else 1.0
        img = np.clip(np.nan_to_num(img.astype(np.float64) * scale), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)


def laplacian_variance(gray: np.ndarray) -> float:
    """Variance of the Laplacian: the usual focus/blur measure (low = blurred)."""
    return float(cv2.Laplacian(gray, cv2.CV_64F).var())


def min_corner_spacing_px(grid_px: np.ndarray) -> float:
    """Smallest distance between neighbouring corners of a ``(rows, cols, 2)`` grid."""
    d = []
    if grid_px.shape[0] > 1:
        d.append(np.linalg.norm(np.diff(grid_px, axis=0), axis=2).ravel())
    if grid_px.shape[1] > 1:
        d.append(np.linalg.norm(np.diff(grid_px, axis=1), axis=2).ravel())
    return float(np.min(np.concatenate(d))) if d else float("nan")


def refine_corners(gray: np.ndarray, corners_px: np.ndarray, spacing_px: float) -> np.ndarray:
    """``cv2.cornerSubPix`` with a half-window of 0.4 x the corner spacing (2..11 px).

    Parameters
    ----------
    corners_px : (n, 2) float
    spacing_px : float
        Smallest distance between neighbouring corners in this image.
    """
    half = int(np.clip(0.4 * spacing_px, 2, 11))
    pts = np.ascontiguousarray(corners_px, dtype=np.float32).reshape(-1, 1, 2)
    out = cv2.cornerSubPix(gray, pts, (half, half), (-1, -1), _SUBPIX_CRITERIA)
    return out.reshape(-1, 2).astype(np.float64)


def _find_chessboard(gray: np.ndarray, grid: tuple[int, int], exhaustive: bool) -> np.ndarray | None:
    ok, corners = cv2.findChessboardCornersSB(gray, grid, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        # FAST_CHECK: without it the classic detector spends 1-2 s on every 640x480 image
        # that has no board (most of a multi-camera session: the board faces other cameras).
        ok, corners = cv2.findChessboardCorners(
            gray, grid, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
        )
    if not ok and exhaustive:
        ok, corners = cv2.findChessboardCornersSB(gray, grid, flags=_SB_EXHAUSTIVE)
    if not ok or corners is None:
        return None
    return corners.reshape(-1, 2).astype(np.float64)


def _sample(gray: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear grey values at ``(n, 2)`` pixel positions (border replicated)."""
    pts = np.asarray(xy, dtype=np.float32).reshape(1, -1, 2)
    vals = cv2.remap(gray, pts[..., 0], pts[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return vals.reshape(-1).astype(np.float64)


def canonical_checkerboard_order(gray: np.ndarray, corners_px: np.ndarray, spec: BoardSpec) -> np.ndarray:
    """Renumber detected checkerboard corners ``(N, 2)`` so every camera agrees.

    OpenCV returns the grid starting from whichever end it found first. Two rules fix
    the numbering: (1) the board is seen from its printed side, so board ``+x`` (along a
    row) and ``+y`` (down the columns) must keep the image's handedness; (2) on an
    odd/even board the square diagonally outside corner 0 is black (see
    :func:`mocap.calib.boards.render_board_texture`).
    """
    cols, rows = spec.corner_grid
    grid = np.asarray(corners_px, dtype=np.float64).reshape(rows, cols, 2)
    vx = grid[0, -1] - grid[0, 0]
    vy = grid[-1, 0] - grid[0, 0]
    if vx[0] * vy[1] - vx[1] * vy[0] < 0:
        grid = grid[:, ::-1]  # mirrored numbering: reverse each row
    if spec.orientation_unique:
        # Homography board (square units) -> image, to look at the two outer corner squares.
        i, j = np.meshgrid(np.arange(cols), np.arange(rows))
        H, _ = cv2.findHomography(np.stack([i.ravel(), j.ravel()], 1).astype(np.float64), grid.reshape(-1, 2))
        if H is not None:
            offs = np.array([[-0.25, -0.25], [-0.5, -0.5], [-0.75, -0.75], [-0.25, -0.75], [-0.75, -0.25]])
            first = offs
            last = np.array([cols - 1, rows - 1]) - offs
            pts = cv2.perspectiveTransform(np.concatenate([first, last]).reshape(-1, 1, 2), H).reshape(-1, 2)
            vals = _sample(gray, pts)
            if np.mean(vals[: len(offs)]) > np.mean(vals[len(offs):]):
                grid = grid[::-1, ::-1]  # 180 deg: corner 0 must be next to the black square
    return grid.reshape(-1, 2)


def _border_sides(xy: np.ndarray, size: tuple[int, int], margin: float) -> list[str]:
    """Image edges that any of the pixel positions ``(n, 2)`` is beyond (or within ``margin`` of)."""
    w, h = size
    sides = []
    if np.any(xy[:, 0] < margin):
        sides.append("left")
    if np.any(xy[:, 0] > w - 1 - margin):
        sides.append("right")
    if np.any(xy[:, 1] < margin):
        sides.append("top")
    if np.any(xy[:, 1] > h - 1 - margin):
        sides.append("bottom")
    return sides


def _charuco_outline_sides(board, spec: BoardSpec, mk_corners, mk_ids, size: tuple[int, int], margin: float) -> list[str]:
    """Edges the ChArUco board extends beyond, from the homography of the markers seen."""
    obj_all = board.getObjPoints()
    ids_all = np.asarray(board.getIds()).ravel()
    obj, img = [], []
    for c, i in zip(mk_corners, np.asarray(mk_ids).ravel()):
        k = np.flatnonzero(ids_all == i)
        if len(k):
            obj.append(np.asarray(obj_all[k[0]])[:, :2])
            img.append(np.asarray(c).reshape(-1, 2))
    if not obj:
        return []
    H, _ = cv2.findHomography(np.concatenate(obj).astype(np.float64), np.concatenate(img).astype(np.float64), 0)
    if H is None:
        return _border_sides(np.concatenate(img), size, margin)
    w, h = spec.squares[0] * spec.square_length_m, spec.squares[1] * spec.square_length_m
    outline = cv2.perspectiveTransform(np.array([[[0, 0]], [[w, 0]], [[w, h]], [[0, h]]], dtype=np.float64), H).reshape(-1, 2)
    return _border_sides(outline, size, 0.0)


def _empty(size: tuple[int, int], sharpness: float, problem: str, detail: str, fix: str) -> BoardDetection:
    return BoardDetection(np.zeros(0, dtype=np.int64), np.zeros((0, 2)), size, sharpness, problem, detail, fix)


def _sides_cut(grid_px: np.ndarray, size: tuple[int, int], margin: float) -> list[str]:
    """Image edges beyond which a ``(rows, cols, 2)`` corner grid continues.

    The next row/column of corners outside the grid is extrapolated on each side; if it
    would fall outside the image (less ``margin``), the board is cut off there.
    """
    ext = []
    if grid_px.shape[0] > 1:
        ext += [2 * grid_px[0] - grid_px[1], 2 * grid_px[-1] - grid_px[-2]]
    if grid_px.shape[1] > 1:
        ext += [2 * grid_px[:, 0] - grid_px[:, 1], 2 * grid_px[:, -1] - grid_px[:, -2]]
    return _border_sides(np.concatenate(ext) if ext else grid_px.reshape(-1, 2), size, margin)


def _unusable_image(gray: np.ndarray, size: tuple[int, int], sharpness: float,
                    settings: DetectionSettings) -> BoardDetection | None:
    """Why no board can be found in this image at all (uniform or blurred), or None."""
    if float(gray.std()) < 3.0:
        return _empty(size, sharpness, "not found",
                      f"the image is almost uniform (grey-level spread {float(gray.std()):.1f})",
                      "check the lens cap, the lighting and that the camera delivers frames")
    if sharpness < settings.blur_threshold:
        return _empty(size, sharpness, "blurred",
                      f"image blurred (variance of Laplacian {sharpness:.1f} < {settings.blur_threshold:g})",
                      "focus the camera, hold the board still, or use more light / a shorter exposure")
    return None


def _find_partial(gray: np.ndarray) -> np.ndarray | None:
    """Largest visible checkerboard corner grid ``(rows, cols, 2)``, any size >= 3x3."""
    ok, part, meta = cv2.findChessboardCornersSBWithMeta(gray, (3, 3), cv2.CALIB_CB_LARGER | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok or part is None or meta is None:
        return None
    return part.reshape(meta.shape[0], meta.shape[1], 2).astype(np.float64)


def _diagnose_checkerboard(gray: np.ndarray, spec: BoardSpec, settings: DetectionSettings, sharpness: float) -> BoardDetection:
    size = (gray.shape[1], gray.shape[0])
    cols, rows = spec.corner_grid
    grid = _find_partial(gray)
    if grid is not None:
        pr, pc = grid.shape[:2]
        seen = f"{pc}x{pr} of the {cols}x{rows} inner corners"
        sides = _sides_cut(grid, size, settings.border_margin_px)
        if sides and pr * pc < cols * rows:
            return _empty(size, sharpness, "cut off",
                          f"board cut off at the image border: only {seen} are visible, the rest is beyond the "
                          f"{'/'.join(sides)} edge",
                          "keep the whole board, with a white margin, inside every camera's view")
    unusable = _unusable_image(gray, size, sharpness, settings)
    if unusable is not None:
        return unusable
    if grid is not None:
        pr, pc = grid.shape[:2]
        if {pc, pr} != {cols, rows}:
            return _empty(size, sharpness, "wrong size",
                          f"a complete {pc}x{pr}-inner-corner checkerboard is visible, not {cols}x{rows}",
                          "check the board size: count the inner corners (where four squares meet) along each "
                          f"side, e.g. --board-size {pc}x{pr}")
        return _empty(size, sharpness, "not found",
                      f"a {pc}x{pr} corner grid is visible but the board was not found; part of it may be hidden or in glare",
                      "make sure nothing covers the board and there is no reflection on it")
    if max(size) <= 2400:
        up = _find_partial(cv2.resize(gray, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC))
        if up is not None:
            sq = min_corner_spacing_px(up / 2.0)
            return _empty(size, sharpness, "too small",
                          f"board too small in the image (squares about {sq:.0f} px wide; the detector needs >= "
                          f"{settings.min_square_px:.0f} px)",
                          "move the board closer to the camera or print larger squares")
    return _empty(size, sharpness, "not found",
                  f"no {cols}x{rows}-inner-corner checkerboard found",
                  "check the board size (inner corners), that the whole board is in view, and that it is evenly lit without glare")


def _detect_checkerboard(gray: np.ndarray, spec: BoardSpec, settings: DetectionSettings, sharpness: float) -> BoardDetection:
    size = (gray.shape[1], gray.shape[0])
    cols, rows = spec.corner_grid
    corners = _find_chessboard(gray, (cols, rows), settings.exhaustive)
    if corners is None:
        if settings.diagnose:
            return _diagnose_checkerboard(gray, spec, settings, sharpness)
        return _empty(size, sharpness, "not found", f"no {cols}x{rows}-inner-corner checkerboard found", "check the board size and lighting")
    corners = canonical_checkerboard_order(gray, corners, spec)
    spacing = min_corner_spacing_px(corners.reshape(rows, cols, 2))
    if spacing < 0.5 * settings.min_square_px:
        return _empty(size, sharpness, "too small",
                      f"board too small in the image (corner spacing {spacing:.1f} px)",
                      "move the board closer to the camera or print larger squares")
    corners = refine_corners(gray, corners, spacing)
    return BoardDetection(np.arange(spec.n_corners), corners, size, sharpness)


def _detect_charuco(gray: np.ndarray, spec: BoardSpec, settings: DetectionSettings, sharpness: float,
                    detector: "cv2.aruco.CharucoDetector | None" = None) -> BoardDetection:
    size = (gray.shape[1], gray.shape[0])
    board = charuco_board(spec)
    det = detector if detector is not None else cv2.aruco.CharucoDetector(board)
    ch_corners, ch_ids, mk_corners, mk_ids = det.detectBoard(gray)
    n_markers = 0 if mk_ids is None else len(mk_ids)
    n = 0 if ch_ids is None else len(ch_ids)
    if n >= settings.min_corners:
        ids = ch_ids.reshape(-1).astype(np.int64)
        if not board.checkCharucoCornersCollinear(ch_ids):
            xy = ch_corners.reshape(-1, 2).astype(np.float64)
            order = np.argsort(ids)
            return BoardDetection(ids[order], xy[order], size, sharpness)
        return _empty(size, sharpness, "too few corners",
                      f"the {n} board corners seen lie on one line", "show more of the board to the camera")
    total = spec.n_corners
    if n_markers > 0:
        sides = _charuco_outline_sides(board, spec, mk_corners, mk_ids, size, settings.border_margin_px)
        if sides:
            return _empty(size, sharpness, "cut off",
                          f"board cut off at the image border: {n_markers} markers and {n} of {total} corners visible, touching the {'/'.join(sides)} edge",
                          "keep the whole board inside every camera's view")
        return _empty(size, sharpness, "too few corners",
                      f"only {n} of {total} ChArUco corners found ({n_markers} markers; need >= {settings.min_corners})",
                      "show more of the board, avoid glare on the markers, and check --board-size counts squares")
    if settings.diagnose and max(size) <= 2400:
        up = cv2.resize(gray, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)
        _, up_ids, up_mk, up_mk_ids = det.detectBoard(up)
        if up_mk_ids is not None and len(up_mk_ids) > 0:
            return _empty(size, sharpness, "too small",
                          f"board too small in the image (its markers are only found after 2x upsampling)",
                          "move the board closer to the camera or print a larger board")
    unusable = _unusable_image(gray, size, sharpness, settings)
    if unusable is not None:
        return unusable
    return _empty(size, sharpness, "not found",
                  f"no ArUco marker of dictionary {spec.dictionary} found",
                  "check --board-dictionary matches the printed board and that the board is evenly lit")


def detect_board(image: np.ndarray, spec: BoardSpec, settings: DetectionSettings | None = None) -> BoardDetection:
    """Find the board in one image.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        Grey or BGR image.
    spec : BoardSpec
    settings : DetectionSettings, optional

    Returns
    -------
    BoardDetection
        ``found`` is True when the view can be used; otherwise ``problem``/``detail``/``fix``
        say why not.
    """
    settings = settings if settings is not None else DetectionSettings()
    gray = to_gray(image)
    sharpness = laplacian_variance(gray)
    if spec.kind == "checkerboard":
        return _detect_checkerboard(gray, spec, settings, sharpness)
    return _detect_charuco(gray, spec, settings, sharpness)
