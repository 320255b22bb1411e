"""Per-camera intrinsics by Zhang's method (``cv2.calibrateCamera``), with checks.

Before calibrating, the views are checked for the classic degeneracy of planar
calibration: if the board has the same orientation in every view (e.g. always
fronto-parallel), focal length and board distance cannot be told apart. After
calibrating, views whose reprojection RMS is far above the others (a mis-detected
corner, motion blur) are dropped and the camera is calibrated again.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from mocap.calib.errors import BoardNotFoundError, CalibrationError, DegenerateViewsError, ViewFailure
from mocap.errors import require, require_one_of


@dataclass(frozen=True)
class IntrinsicsOptions:
    """Model and view-selection options of :func:`calibrate_intrinsics`.

    Attributes
    ----------
    fix_aspect_ratio : bool
        Keep ``fy / fx`` at 1 (``cv2.CALIB_FIX_ASPECT_RATIO``).
    fix_principal_point : bool
        Keep ``(cx, cy)`` at the image centre.
    k3 : {"auto", "free", "fixed"}
        Sixth-order radial term. ``"fixed"`` keeps ``k3 = 0``; ``"auto"`` fits both models
        and keeps ``k3`` only if it lowers the residual enough to pass the Bayesian
        information criterion (``n ln(RSS0/RSS1) > ln n``): with few views of a mild
        lens ``k3`` mostly fits noise and trades off against the focal length.
    zero_tangent : bool
        Keep ``p1 = p2 = 0``.
    min_views : int
        Fewest usable views per camera.
    min_corners : int
        Fewest corners for a ChArUco view to count.
    outlier_factor, outlier_min_px : float
        A view is dropped when its RMS exceeds both ``outlier_factor`` x the median view
        RMS and ``outlier_min_px``.
    min_tilt_spread_deg : float
        Views whose board normals all lie within this angle of each other are degenerate.
    """

    fix_aspect_ratio: bool = False
    fix_principal_point: bool = False
    k3: str = "auto"
    zero_tangent: bool = False
    min_views: int = 5
    min_corners: int = 6
    outlier_factor: float = 3.0
    outlier_min_px: float = 1.0
    min_tilt_spread_deg: float = 5.0

    def __post_init__(self) -> None:
        require_one_of(self, "k3", ("auto", "free", "fixed"))
        require(self.min_views >= 3, self, "min_views", "must be >= 3 (Zhang's method)")

    @property
    def cv_flags(self) -> int:
        flags = 0
        if self.fix_aspect_ratio:
            flags |= cv2.CALIB_FIX_ASPECT_RATIO
        if self.fix_principal_point:
            flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
        if self.k3 == "fixed":
            flags |= cv2.CALIB_FIX_K3
        if self.zero_tangent:
            flags |= cv2.CALIB_ZERO_TANGENT_DIST
        return flags


@dataclass
class IntrinsicsResult:
    """One camera's Zhang calibration.

    Attributes
    ----------
    camera : str
    image_size : (int, int)
    K : (3, 3) float
    dist : (5,) float
    rms_px : float
        Reprojection RMS over the views kept.
    view_rms_px : (V,) float
        Per-view RMS (NaN for views without the board); rejected views keep the value
        they had when rejected.
    used : (V,) bool
    rejected : dict[int, str]
        View index -> reason.
    rvecs, tvecs : (V, 3) float
        Camera-from-board pose of each used view (NaN elsewhere), metres.
    """

    camera: str
    image_size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray
    rms_px: float
    view_rms_px: np.ndarray
    used: np.ndarray
    rejected: dict[int, str] = field(default_factory=dict)
    rvecs: np.ndarray | None = None
    tvecs: np.ndarray | None = None
    k3_free: bool = True


def board_normals_from_homographies(corners_px: np.ndarray, object_points: np.ndarray,
                                    image_size: tuple[int, int]) -> np.ndarray:
    """Rough board normal of each view in the camera frame, ``(V, 3)`` unit vectors.

    Uses a guessed camera (focal = image width, centred principal point) and the
    plane-to-image homography. The guess scales tilt angles but keeps parallel views
    parallel, which is all the degeneracy check needs.

    Parameters
    ----------
    corners_px : (V, N, 2) float, NaN where unseen
    object_points : (N, 3) float, board frame (z = 0)
    """
    w, h = image_size
    f = float(max(w, h))
    Kinv = np.linalg.inv(np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]]))
    normals = np.full((corners_px.shape[0], 3), np.nan)
    for v in range(corners_px.shape[0]):  # one homography per view (V is small)
        ok = np.isfinite(corners_px[v]).all(axis=1)
        if ok.sum() < 4:
            continue
        H, _ = cv2.findHomography(object_points[ok, :2], corners_px[v, ok], 0)
        if H is None:
            continue
        M = Kinv @ H
        r1, r2 = M[:, 0], M[:, 1]
        n = np.cross(r1, r2)
        normals[v] = n / np.linalg.norm(n) * np.sign(n[2] if n[2] != 0 else 1.0)
    return normals


def check_view_spread(camera: str, corners_px: np.ndarray, object_points: np.ndarray,
                      image_size: tuple[int, int], min_spread_deg: float) -> float:
    """Raise :class:`DegenerateViewsError` if all board normals are (nearly) parallel.

    Returns
    -------
    float
        Largest angle between two views' board normals, degrees.
    """
    n = board_normals_from_homographies(corners_px, object_points, image_size)
    n = n[np.isfinite(n).all(axis=1)]
    if len(n) < 2:
        return 0.0
    cosang = np.clip(np.abs(n @ n.T), 0.0, 1.0)
    spread = float(np.degrees(np.arccos(cosang.min())))
    if spread < min_spread_deg:
        tilt = np.degrees(np.arccos(np.clip(np.abs(n[:, 2]), 0.0, 1.0)))
        raise DegenerateViewsError(camera, len(n), spread, float(tilt.min()), float(tilt.max()), min_spread_deg)
    return spread


def spans_plane(seen: np.ndarray, object_points: np.ndarray) -> np.ndarray:
    """``(V,)`` bool: the seen corners of each view are not (nearly) on one line.

    A homography, hence Zhang's initialisation and PnP, needs corners spanning two
    directions of the board; partial ChArUco views along one edge do not.

    Parameters
    ----------
    seen : (V, N) bool
    object_points : (N, 3) float
    """
    xy = object_points[:, :2]
    n = np.maximum(seen.sum(axis=1), 1)
    mean = (seen @ xy) / n[:, None]
    # Second moments of the seen corners per view -> smallest principal spread.
    sxx = (seen @ (xy[:, 0] ** 2)) / n - mean[:, 0] ** 2
    syy = (seen @ (xy[:, 1] ** 2)) / n - mean[:, 1] ** 2
    sxy = (seen @ (xy[:, 0] * xy[:, 1])) / n - mean[:, 0] * mean[:, 1]
    tr, det = sxx + syy, sxx * syy - sxy ** 2
    lam_min = tr / 2 - np.sqrt(np.maximum(tr ** 2 / 4 - det, 0.0))
    d0 = np.linalg.norm(xy[1:] - xy[0], axis=1)
    pitch = float(np.min(d0[d0 > 0])) if np.any(d0 > 0) else 1.0  # corner spacing of the grid
    return np.sqrt(np.maximum(lam_min, 0.0)) > 0.25 * pitch


def _view_rms(obj: list[np.ndarray], img: list[np.ndarray], rvecs, tvecs, K, dist) -> np.ndarray:
    out = np.empty(len(obj))
    for i, (o, p, r, t) in enumerate(zip(obj, img, rvecs, tvecs)):
        proj, _ = cv2.projectPoints(o, r, t, K, dist)
        out[i] = np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - p.reshape(-1, 2)) ** 2, axis=1)))
    return out


def calibrate_intrinsics(corners_px: np.ndarray, object_points: np.ndarray, image_size: tuple[int, int],
                         camera: str = "camera", options: IntrinsicsOptions | None = None,
                         labels: list[str] | None = None, is_checkerboard: bool = True) -> IntrinsicsResult:
    """Zhang calibration of one camera from its board views.

    Parameters
    ----------
    corners_px : (V, N, 2) float
        Board corners per view, distorted pixels, NaN where not seen.
    object_points : (N, 3) float
        Board corners in the board frame, metres.
    image_size : (int, int)
        ``(width, height)``.
    camera : str
        Name used in messages.
    options : IntrinsicsOptions, optional
    labels : list[str], optional
        File name of each view, for messages.
    is_checkerboard : bool
        Checkerboard views need every corner; ChArUco views ``options.min_corners``.

    Raises
    ------
    BoardNotFoundError
        Fewer than ``options.min_views`` usable views.
    DegenerateViewsError
        All views have the board at the same orientation.
    """
    opt = options if options is not None else IntrinsicsOptions()
    corners_px = np.asarray(corners_px, dtype=np.float64)
    V, N = corners_px.shape[:2]
    labels = labels if labels is not None else [f"view {v}" for v in range(V)]
    seen = np.isfinite(corners_px).all(axis=2)
    n_seen = seen.sum(axis=1)
    need = N if is_checkerboard else max(4, opt.min_corners)
    usable = (n_seen >= need) & spans_plane(seen, object_points)
    if usable.sum() < opt.min_views:
        failures = [ViewFailure(labels[v], "too few corners", f"{n_seen[v]} of {N} corners seen") for v in np.flatnonzero(~usable)]
        raise BoardNotFoundError(camera, int(usable.sum()), V, opt.min_views, failures)
    check_view_spread(camera, np.where(usable[:, None, None], corners_px, np.nan), object_points, image_size,
                      opt.min_tilt_spread_deg)

    fit = _fit(corners_px, object_points, image_size, opt.cv_flags, usable, opt, camera)
    if opt.k3 == "auto":
        # Same views for both models, so their residuals compare (BIC, one extra parameter).
        free = fit  # fitted with k3 free, on exactly the views it kept
        fixed = _fit(corners_px, object_points, image_size, opt.cv_flags | cv2.CALIB_FIX_K3, fit["used"], opt, camera, reject=False)
        n_res = 2 * fixed["n_points"]
        rss0, rss1 = fixed["rms"] ** 2 * fixed["n_points"], free["rms"] ** 2 * free["n_points"]
        keep = rss1 > 0 and n_res * np.log(rss0 / rss1) > np.log(n_res)
        fit = dict(free if keep else fixed, rejected=fit["rejected"], view_rms=np.where(fit["used"], (free if keep else fixed)["view_rms"], fit["view_rms"]))
        k3_free = bool(keep)
    else:
        k3_free = opt.k3 == "free"
    return IntrinsicsResult(camera, (int(image_size[0]), int(image_size[1])), fit["K"], fit["dist"], fit["rms"],
                            fit["view_rms"], fit["used"], fit["rejected"], fit["rvecs"], fit["tvecs"], k3_free)


def _fit(corners_px: np.ndarray, object_points: np.ndarray, image_size: tuple[int, int], flags: int,
         usable: np.ndarray, opt: IntrinsicsOptions, camera: str, reject: bool = True) -> dict:
    """``cv2.calibrateCamera`` on the usable views, dropping outlier views and refitting."""
    w, h = image_size
    V = corners_px.shape[0]
    f0 = float(max(w, h))
    K0 = np.array([[f0, 0, (w - 1) / 2], [0, f0, (h - 1) / 2], [0, 0, 1.0]])
    if opt.fix_principal_point:
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS  # keep the centred principal point of K0
    used = usable.copy()
    rejected: dict[int, str] = {}
    view_rms = np.full(V, np.nan)
    while True:
        idx = np.flatnonzero(used)
        obj = [np.ascontiguousarray(object_points[np.isfinite(corners_px[v]).all(axis=1)], dtype=np.float32) for v in idx]
        img = [np.ascontiguousarray(corners_px[v][np.isfinite(corners_px[v]).all(axis=1)], dtype=np.float32).reshape(-1, 1, 2) for v in idx]
        try:
            _, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, (w, h), K0.copy(), None, flags=flags)
        except cv2.error as exc:
            raise CalibrationError(f"camera {camera!r}: cv2.calibrateCamera failed on {len(idx)} views "
                                   f"({str(exc).strip().splitlines()[-1]}); check the views show the board from "
                                   f"different angles and that the board size is right") from exc
        dist = np.asarray(dist, dtype=np.float64).ravel()[:5]
        per_view = _view_rms(obj, img, rvecs, tvecs, K, dist)
        view_rms[idx] = per_view
        limit = max(opt.outlier_factor * float(np.median(per_view)), opt.outlier_min_px)
        bad = per_view > limit
        if not reject or not bad.any() or len(idx) - bad.sum() < opt.min_views:
            break
        for v, e in zip(idx[bad], per_view[bad]):
            rejected[int(v)] = f"reprojection RMS {e:.2f} px > {limit:.2f} px (outlier view: mis-detected corners or motion blur)"
            used[v] = False
    rv = np.full((V, 3), np.nan)
    tv = np.full((V, 3), np.nan)
    rv[idx] = np.asarray(rvecs, dtype=np.float64).reshape(-1, 3)
    tv[idx] = np.asarray(tvecs, dtype=np.float64).reshape(-1, 3)
    n_pts = np.array([len(o) for o in obj])
    total = float(np.sqrt(np.sum(per_view ** 2 * n_pts) / n_pts.sum()))
    return dict(K=np.asarray(K, dtype=np.float64), dist=dist, rms=total, view_rms=view_rms, used=used,
                rejected=rejected, rvecs=rv, tvecs=tv, n_points=int(n_pts.sum()))
