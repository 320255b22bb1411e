"""Multi-view triangulation of labelled 2D points, vectorised over points.

Arrays follow :mod:`mocap.calibration`: ``p2ds`` is ``(C, N, 2)`` distorted pixels with
NaN where a camera did not see the point, ``p3ds`` is ``(N, 3)`` metres (world frame).

* :func:`triangulate_dlt` -- weighted linear DLT on undistorted normalised coordinates,
  the ``(N, 2C, 4)`` systems solved at once (batched 3x3 normal equations).
* :func:`refine_points` -- a few Gauss-Newton steps on the (weighted) reprojection error in
  undistorted pixels, analytic Jacobian, vectorised.
* :func:`reprojection_residuals` -- ``(C, N)`` pixel distances.
* :func:`triangulate` -- DLT + refinement + outlier rejection: while a point's worst
  residual exceeds a threshold, drop the worst camera and retry, as long as at least
  ``min_views`` views remain; otherwise the point is rejected (NaN).
  :func:`triangulate_normalized` does the same on already undistorted coordinates.
* :func:`epipolar_distances` -- symmetric point-to-epipolar-line distances per camera
  pair, for correspondence checks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.calibration import Calibration

__all__ = [
    "TriangulationResult",
    "normalized_coordinates",
    "triangulate_dlt",
    "refine_points",
    "reprojection_residuals",
    "triangulate",
    "triangulate_normalized",
    "project_normalized",
    "camera_normalized",
    "pixels_to_normalized",
    "normalized_residuals",
    "epipolar_distances",
]


@dataclass(frozen=True)
class TriangulationResult:
    """Output of :func:`triangulate`.

    Attributes
    ----------
    points : (N, 3) float
        Metres, world frame; NaN where fewer than ``min_views`` consistent views remained.
    residual_px : (N,) float
        Mean reprojection residual over the views used (pixels); NaN where rejected.
    n_views : (N,) int
        Number of views used.
    used : (C, N) bool
        Which camera observations were used for each point.
    """

    points: np.ndarray
    residual_px: np.ndarray
    n_views: np.ndarray
    used: np.ndarray


def _check_p2ds(p2ds: np.ndarray, calibration: Calibration) -> np.ndarray:
    p = np.asarray(p2ds, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 2:
        raise ValueError(f"p2ds must be (C, N, 2) pixels, got shape {p.shape}")
    if p.shape[0] != len(calibration):
        raise ValueError(
            f"p2ds has {p.shape[0]} cameras but the calibration has {len(calibration)} ({calibration.names}); "
            "pass one row of points per calibrated camera, in calibration order"
        )
    return p


def _check_weights(weights: np.ndarray | None, p2ds: np.ndarray) -> np.ndarray:
    C, N = p2ds.shape[:2]
    finite = np.isfinite(p2ds).all(axis=2)
    if weights is None:
        w = np.ones((C, N))
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (C, N):
            raise ValueError(f"weights must be (C, N) = {(C, N)}, got {w.shape}")
        if np.any(w[finite] < 0) or not np.isfinite(w[finite]).all():
            raise ValueError("weights must be finite and >= 0 where points are given")
    return np.where(finite, w, 0.0)


def normalized_coordinates(p2ds: np.ndarray, calibration: Calibration) -> np.ndarray:
    """Distorted pixels ``(C, N, 2)`` to undistorted normalised image coordinates ``(C, N, 2)``.

    ``(x, y)`` such that the camera-frame ray is ``(x, y, 1)``; NaN stays NaN.
    """
    p = _check_p2ds(p2ds, calibration)
    return np.stack([pixels_to_normalized(cam, p[c]) for c, cam in enumerate(calibration)])


def _dlt_normalized(xy: np.ndarray, Ps: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted DLT. ``xy`` (C, N, 2) normalised, ``Ps`` (C, 3, 4) = [R|t], ``w`` (C, N)."""
    C, N = w.shape
    pts = np.full((N, 3), np.nan)
    ok = (w > 0).sum(axis=0) >= 2
    if ok.any():
        # Rows x*P3 - P1 and y*P3 - P2 of every camera, weighted, of the points with two
        # views only, made directly in (n, C, 2, 4) order: (n, 2C, 4) is then a free reshape.
        xt = np.nan_to_num(xy[:, ok]).transpose(1, 0, 2)                 # (n, C, 2)
        Ak = ((xt[..., None] * Ps[None, :, 2:3, :] - Ps[None, :, :2, :]) * w[:, ok].T[..., None, None]).reshape(-1, 2 * C, 4)
        # Inhomogeneous DLT (point = (X, 1)): least squares on the normal equations,
        # batched 3x3 solves, ~10x faster than a batched eigh/SVD of the 4x4 system
        # and, in metres and normalised coordinates, as accurate (exact data give the
        # point to ~1e-15 m). A tiny ridge keeps near-parallel rays solvable.
        Mk = np.matmul(Ak.transpose(0, 2, 1), Ak)
        lhs = Mk[:, :3, :3] + 1e-12 * np.trace(Mk[:, :3, :3], axis1=1, axis2=2)[:, None, None] * np.eye(3)
        X = np.linalg.solve(lhs, -Mk[:, :3, 3:4])[..., 0]
        pts[ok] = X
    return pts


def _extrinsics(calibration: Calibration) -> np.ndarray:
    return np.stack([np.hstack([c.R, c.t[:, None]]) for c in calibration])


def triangulate_dlt(
    p2ds: np.ndarray, calibration: Calibration, weights: np.ndarray | None = None
) -> np.ndarray:
    """Linear (DLT) triangulation from two or more views, vectorised over points.

    Parameters
    ----------
    p2ds : (C, N, 2) float
        Distorted pixel coordinates, NaN where a camera has no observation.
    calibration : Calibration
        The C cameras, in the order of ``p2ds``.
    weights : (C, N) float, optional
        Per-view confidence (>= 0; 0 ignores the view). Default 1 for every finite point.

    Returns
    -------
    (N, 3) float
        Points in metres; NaN where fewer than two views have positive weight.
    """
    p = _check_p2ds(p2ds, calibration)
    w = _check_weights(weights, p)
    return _dlt_normalized(normalized_coordinates(p, calibration), _extrinsics(calibration), w)


def refine_points(
    p3ds: np.ndarray,
    p2ds: np.ndarray,
    calibration: Calibration,
    weights: np.ndarray | None = None,
    iterations: int = 3,
) -> np.ndarray:
    """Gauss-Newton refinement of points on the weighted reprojection error.

    The error is measured on the undistorted image plane and scaled by each camera's
    focal length, i.e. in undistorted pixels: this has an analytic, fully vectorised
    Jacobian, and for the mild lens distortion of webcams its minimum coincides with
    the distorted-pixel one to well below the noise.

    Parameters
    ----------
    p3ds : (N, 3) float
        Initial points, metres (e.g. from :func:`triangulate_dlt`); NaN rows are kept NaN.
    p2ds : (C, N, 2) float
        Distorted pixels, NaN where missing.
    calibration : Calibration
    weights : (C, N) float, optional
        Per-view weights (multiply each view's squared residual).
    iterations : int
        Number of Gauss-Newton steps (3 is plenty from a DLT start).

    Returns
    -------
    (N, 3) float
        Refined points, metres.
    """
    p = _check_p2ds(p2ds, calibration)
    w = _check_weights(weights, p)
    X = np.array(p3ds, dtype=np.float64, copy=True).reshape(-1, 3)
    if X.shape[0] != p.shape[1]:
        raise ValueError(f"p3ds has {X.shape[0]} points but p2ds has {p.shape[1]}")
    return _refine_normalized(X, normalized_coordinates(p, calibration), calibration, w, iterations)


def _refine_normalized(
    X: np.ndarray, xy: np.ndarray, calibration: Calibration, w: np.ndarray, iterations: int
) -> np.ndarray:
    """Gauss-Newton on ``f * (pi(R X + t) - xy)``; ``xy`` (C, N, 2) normalised, ``w`` (C, N)."""
    X = X.copy()
    ok = np.isfinite(X).all(axis=1) & ((w > 0).sum(axis=0) >= 2)
    if not ok.any():
        return X
    obs = np.nan_to_num(xy[:, ok])
    wk = w[:, ok]
    Xk = X[ok]
    f = calibration.mean_focal_px
    Rs, ts = _rotations_translations(calibration)
    # Every camera at once (stacked products: each camera's slice is the product it had
    # alone, to the bit), the per-camera terms then summed in camera order as before.
    for _ in range(iterations):
        JTJ = np.zeros((len(Xk), 3, 3))
        JTr = np.zeros((len(Xk), 3))
        pc = np.matmul(Xk, Rs.transpose(0, 2, 1)) + ts[:, None, :]   # (C, n, 3) camera frames
        z = pc[..., 2:3]
        uv = pc[..., :2] / z
        # d(uv)/dX = (R[:2] - uv R[2]) / z, in pixels via f.
        J = (Rs[:, None, :2, :] - uv[..., None] * Rs[:, None, 2:3, :]) / z[..., None] * f[:, None, None, None]
        r = (uv - obs) * f[:, None, None]
        JT = J.transpose(0, 1, 3, 2)
        JTJ_c = np.matmul(JT, J * wk[..., None, None])
        JTr_c = np.matmul(JT, (r * wk[..., None])[..., None])[..., 0]
        for c in range(len(Rs)):
            JTJ += JTJ_c[c]
            JTr += JTr_c[c]
        # Tiny Levenberg damping guards degenerate (near-parallel) geometry.
        JTJ += 1e-12 * np.trace(JTJ, axis1=1, axis2=2)[:, None, None] * np.eye(3)
        Xk = Xk - np.linalg.solve(JTJ, JTr[..., None])[..., 0]
    X[ok] = Xk
    return X


def reprojection_residuals(
    p3ds: np.ndarray, p2ds: np.ndarray, calibration: Calibration
) -> np.ndarray:
    """Pixel distance between each observation and the projection of its 3D point.

    Parameters
    ----------
    p3ds : (N, 3) float, metres
    p2ds : (C, N, 2) float, distorted pixels (NaN where missing)
    calibration : Calibration

    Returns
    -------
    (C, N) float
        Residuals in pixels; NaN where the observation or the point is missing.
    """
    p = _check_p2ds(p2ds, calibration)
    proj = calibration.project(np.asarray(p3ds, dtype=np.float64).reshape(-1, 3))
    return np.linalg.norm(proj - p, axis=2)


def triangulate(
    p2ds: np.ndarray,
    calibration: Calibration,
    weights: np.ndarray | None = None,
    max_residual_px: float = 2.0,
    refine: bool = True,
    iterations: int = 3,
    min_views: int = 2,
) -> TriangulationResult:
    """Robust triangulation: DLT, refinement, and worst-camera rejection.

    For every point whose largest reprojection residual exceeds ``max_residual_px``, the
    camera whose removal leaves the smallest worst residual is dropped and the point
    re-triangulated, while more than ``min_views`` views remain. A point still above the
    threshold with only ``min_views`` views is rejected (NaN): with two views one cannot
    tell which one is wrong.

    Parameters
    ----------
    p2ds : (C, N, 2) float
        Distorted pixels, NaN where missing.
    calibration : Calibration
    weights : (C, N) float, optional
        Per-view weights (see :func:`triangulate_dlt`).
    max_residual_px : float
        Outlier threshold on the reprojection residual, pixels. ``inf`` disables rejection.
    refine : bool
        Run :func:`refine_points` after the DLT.
    iterations : int
        Gauss-Newton steps when refining.
    min_views : int
        Minimum number of views for a point (>= 2).

    Returns
    -------
    TriangulationResult
        Residuals in distorted pixels (exact reprojection through the lens model).
    """
    p = _check_p2ds(p2ds, calibration)
    w = _check_weights(weights, p)
    xy = normalized_coordinates(p, calibration)
    return _robust(xy, w, calibration, lambda X, idx: reprojection_residuals(X, p[:, idx], calibration),
                   max_residual_px, refine, iterations, min_views)


def triangulate_normalized(
    xy: np.ndarray,
    calibration: Calibration,
    weights: np.ndarray | None = None,
    max_residual_px: float = 2.0,
    refine: bool = True,
    iterations: int = 3,
    min_views: int = 2,
) -> TriangulationResult:
    """:func:`triangulate` on undistorted normalised coordinates (no lens model calls).

    For callers that triangulate the same observations many times (e.g. frame-by-frame
    label checks): undistort once with :func:`normalized_coordinates`, then call this.
    Residuals are in *undistorted* pixels (normalised error times the focal length),
    which for webcam-like distortion differ from distorted pixels by a few percent.

    Parameters
    ----------
    xy : (C, N, 2) float
        Undistorted normalised coordinates, NaN where missing.
    calibration, weights, max_residual_px, refine, iterations, min_views
        As :func:`triangulate`.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim != 3 or xy.shape[2] != 2 or xy.shape[0] != len(calibration):
        raise ValueError(f"xy must be (C, N, 2) with C = {len(calibration)} cameras, got shape {xy.shape}")
    w = _check_weights(weights, xy)
    return _robust(xy, w, calibration, lambda X, idx: normalized_residuals(X, xy[:, idx], calibration),
                   max_residual_px, refine, iterations, min_views)


def project_normalized(p3ds: np.ndarray, calibration: Calibration) -> np.ndarray:
    """World points ``(N, 3)`` to undistorted normalised coordinates ``(C, N, 2)``.

    NaN for points behind a camera or NaN input.
    """
    X = np.asarray(p3ds, dtype=np.float64).reshape(-1, 3)
    Rs, ts = _rotations_translations(calibration)
    # One stacked product for every camera: each slice is :func:`camera_normalized`'s, to the bit.
    pc = np.matmul(X, Rs.transpose(0, 2, 1)) + ts[:, None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(pc[..., 2:3] > 0, pc[..., :2] / pc[..., 2:3], np.nan)


def camera_normalized(cam, p3ds: np.ndarray) -> np.ndarray:
    """World points ``(N, 3)`` to one camera's undistorted normalised coordinates ``(N, 2)``."""
    pc = np.asarray(p3ds, dtype=np.float64).reshape(-1, 3) @ cam.R.T + cam.t
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(pc[:, 2:3] > 0, pc[:, :2] / pc[:, 2:3], np.nan)


def pixels_to_normalized(cam, p2ds: np.ndarray) -> np.ndarray:
    """One camera's distorted pixels ``(N, 2)`` to undistorted normalised coordinates."""
    und = cam.undistort_pixels(p2ds)
    return (und - cam.K[:2, 2]) @ np.linalg.inv(cam.K[:2, :2]).T


def _rotations_translations(calibration: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """``(C, 3, 3)`` rotations and ``(C, 3)`` translations of the cameras."""
    return np.stack([cam.R for cam in calibration]), np.stack([cam.t for cam in calibration])


def normalized_residuals(p3ds: np.ndarray, xy: np.ndarray, calibration: Calibration) -> np.ndarray:
    """``(C, N)`` residuals in undistorted pixels: ``f * |projection - xy|`` (normalised ``xy``)."""
    d = project_normalized(p3ds, calibration) - xy
    dx, dy = d[..., 0], d[..., 1]
    # np.linalg.norm(d, axis=2), the same bits, without its reduction over a length-2 axis
    return np.sqrt(dx * dx + dy * dy) * calibration.mean_focal_px[:, None]


def _robust(
    xy: np.ndarray, w: np.ndarray, calibration: Calibration, residual_fn,
    max_residual_px: float, refine: bool, iterations: int, min_views: int,
) -> TriangulationResult:
    """DLT (+ refinement) with worst-camera rejection; ``residual_fn(X, idx) -> (C, n)``."""
    if min_views < 2:
        raise ValueError(f"min_views={min_views}: triangulation needs at least 2 views")
    if not max_residual_px > 0:
        raise ValueError(f"max_residual_px={max_residual_px} must be > 0 (use inf to disable rejection)")
    C, N = w.shape
    Ps = _extrinsics(calibration)
    used = w > 0
    used[:, used.sum(axis=0) < min_views] = False
    points = np.full((N, 3), np.nan)
    residuals = np.full((C, N), np.nan)
    todo = np.flatnonzero(used.sum(axis=0) >= min_views)

    def solve(idx: np.ndarray, use: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points (n, 3) and residuals (C, n) of the points ``idx`` from views ``use``."""
        wk = np.where(use, w[:, idx], 0.0)
        X = _dlt_normalized(xy[:, idx], Ps, wk)
        if refine:
            X = _refine_normalized(X, xy[:, idx], calibration, wk, iterations)
        res = residual_fn(X, idx)
        res[~use] = np.nan
        return X, res

    def worst(res: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(res), res, -np.inf).max(axis=0)

    for _ in range(C):  # each round drops at most one camera per point
        if todo.size == 0:
            break
        X, res = solve(todo, used[:, todo])
        points[todo] = X
        residuals[:, todo] = res
        bad = ~(worst(res) <= max_residual_px)  # also catches NaN points
        if not bad.any():
            break
        nv = used[:, todo].sum(axis=0)
        drop = bad & (nv > min_views)
        rej_idx = todo[bad & ~drop]
        used[:, rej_idx] = False
        points[rej_idx] = np.nan
        residuals[:, rej_idx] = np.nan
        todo = todo[drop]
        if todo.size == 0:
            break
        # The worst camera is the one whose removal leaves the smallest worst residual
        # (least squares spreads an outlier's error, so the largest residual is not
        # always in the faulty view).
        score = _drop_scores(used[:, todo], todo, lambda idx, use: worst(solve(idx, use)[1]))
        used[np.argmin(score, axis=0), todo] = False
    n_views = used.sum(axis=0)
    with np.errstate(invalid="ignore"):
        mean_res = np.where(n_views > 0, np.nansum(np.where(used, residuals, 0.0), axis=0) / np.maximum(n_views, 1), np.nan)
    points[n_views < min_views] = np.nan
    return TriangulationResult(points, mean_res, n_views.astype(np.int16), used)


def _drop_scores(use: np.ndarray, todo: np.ndarray, worst_of) -> np.ndarray:
    """``(C, n)`` worst residual of each point ``todo`` (n,) without each of its views
    ``use`` (C, n) (inf where the point has no such view); ``worst_of(idx, use)`` solves.

    The solves of every camera go in one batch (each point's solve is independent of the
    others'), except a camera with a single point: a one-point solve goes through BLAS's
    matrix-vector product, whose last bits differ from the matrix-matrix one of a batch,
    so it stays alone to give the bits it always gave. (Every point here keeps at least
    ``min_views >= 2`` views, so a refinement takes all the points of its batch.)"""
    C = len(use)
    score = np.full((C, todo.size), np.inf)
    cols = [np.flatnonzero(use[c]) for c in range(C)]
    batch = [c for c in range(C) if len(cols[c]) >= 2]
    for c in range(C):
        if len(cols[c]) == 1:
            use_c = use[:, cols[c]].copy()
            use_c[c] = False
            score[c, cols[c]] = worst_of(todo[cols[c]], use_c)
    if batch:
        col = np.concatenate([cols[c] for c in batch])
        cam = np.repeat(batch, [len(cols[c]) for c in batch])
        use_b = use[:, col].copy()
        use_b[cam, np.arange(col.size)] = False
        score[cam, col] = worst_of(todo[col], use_b)
    return score


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def epipolar_distances(xy: np.ndarray, calibration: Calibration) -> np.ndarray:
    """Symmetric epipolar distances between every pair of views, in pixels.

    Parameters
    ----------
    xy : (C, N, 2) float
        Undistorted *normalised* coordinates (see :func:`normalized_coordinates`),
        NaN where missing.
    calibration : Calibration

    Returns
    -------
    (C, C, N) float
        ``d[i, j, n]``: mean of the distance of view j's point to the epipolar line of
        view i's point (measured in view j, pixels via its focal length) and vice versa.
        Symmetric in i, j; NaN on the diagonal and where either point is missing.
    """
    C, N = xy.shape[:2]
    h = np.concatenate([xy, np.ones((C, N, 1))], axis=2)   # (C, N, 3)
    d = np.full((C, C, N), np.nan)
    f = calibration.mean_focal_px
    for i in range(C):
        for j in range(i + 1, C):
            ci, cj = calibration[i], calibration[j]
            R_ij = cj.R @ ci.R.T
            t_ij = cj.t - R_ij @ ci.t
            E = _skew(t_ij) @ R_ij          # x_j^T E x_i = 0
            lj = h[i] @ E.T                  # lines in view j, (N, 3)
            li = h[j] @ E                    # lines in view i
            alg = np.einsum("nk,nk->n", h[j], lj)
            with np.errstate(invalid="ignore", divide="ignore"):
                dj = np.abs(alg) / np.linalg.norm(lj[:, :2], axis=1) * f[j]
                di = np.abs(alg) / np.linalg.norm(li[:, :2], axis=1) * f[i]
            d[i, j] = d[j, i] = 0.5 * (di + dj)
    return d
