"""Vectorised camera geometry for calibration (many poses and cameras at once).

``cv2.projectPoints`` and ``cv2.triangulatePoints`` take one pose or one camera pair
per call; bundle adjustment evaluates tens of thousands of points with a different
camera and board pose each, hundreds of times, so the same OpenCV formulas are written
here once over whole arrays. Conventions are OpenCV's: ``x_cam = R @ x + t``, distortion
``k1 k2 p1 p2 k3``, pixel centres at integers.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

#: Order of the per-camera intrinsic parameter vector used in calibration.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def rotvec_to_matrix(rotvecs: np.ndarray) -> np.ndarray:
    """Rodrigues vectors ``(n, 3)`` radians to rotation matrices ``(n, 3, 3)``."""
    return Rotation.from_rotvec(np.asarray(rotvecs, dtype=np.float64).reshape(-1, 3)).as_matrix()


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(n, 3, 3)`` to Rodrigues vectors ``(n, 3)``."""
    return Rotation.from_matrix(np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)).as_rotvec()


def intrinsics_vector(K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """``(3, 3)`` K and ``(5,)`` distortion to the ``(9,)`` vector of :data:`INTRINSIC_NAMES`."""
    K = np.asarray(K, dtype=np.float64)
    return np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], np.asarray(dist, dtype=np.float64).ravel()[:5]])


def intrinsics_from_vector(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`intrinsics_vector`: ``(K (3, 3), dist (5,))``."""
    v = np.asarray(v, dtype=np.float64)
    K = np.array([[v[0], 0.0, v[2]], [0.0, v[1], v[3]], [0.0, 0.0, 1.0]])
    return K, v[4:9].copy()


def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply OpenCV's 5-term distortion to normalised coordinates.

    Parameters
    ----------
    xy : (n, 2) float
        Ideal normalised image coordinates ``(X/Z, Y/Z)``.
    dist : (5,) or (n, 5) float
        ``k1 k2 p1 p2 k3``, one set or one per point.
    """
    xy = np.asarray(xy, dtype=np.float64)
    d = np.broadcast_to(np.asarray(dist, dtype=np.float64), xy.shape[:-1] + (5,))
    x, y = xy[..., 0], xy[..., 1]
    k1, k2, p1, p2, k3 = (d[..., i] for i in range(5))
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def project_camera_points(x_cam: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """Project camera-frame points to distorted pixels (``cv2.projectPoints`` without the pose).

    Parameters
    ----------
    x_cam : (n, 3) float
        Points in each camera's frame, metres.
    intrinsics : (9,) or (n, 9) float
        ``fx fy cx cy k1 k2 p1 p2 k3`` (one camera, or one row per point).

    Returns
    -------
    (n, 2) float
        Pixels. Points at or behind the camera plane give non-finite values.
    """
    x_cam = np.asarray(x_cam, dtype=np.float64)
    p = np.broadcast_to(np.asarray(intrinsics, dtype=np.float64), x_cam.shape[:-1] + (9,))
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = x_cam[..., :2] / x_cam[..., 2:3]
    xyd = distort_normalized(xy, p[..., 4:9])
    return np.stack([p[..., 0] * xyd[..., 0] + p[..., 2], p[..., 1] * xyd[..., 1] + p[..., 3]], axis=-1)


def transform_points(R: np.ndarray, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``R @ x + t`` row by row: ``R (n, 3, 3)``, ``t (n, 3)``, ``x (n, 3)`` -> ``(n, 3)``."""
    return np.einsum("nij,nj->ni", R, x) + t


def invert_pose(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of ``x -> R x + t`` for stacked ``R (..., 3, 3)``, ``t (..., 3)``."""
    Rt = np.swapaxes(R, -1, -2)
    return Rt, -np.einsum("...ij,...j->...i", Rt, t)


def compose_poses(R_ab: np.ndarray, t_ab: np.ndarray, R_bc: np.ndarray, t_bc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``T_ab @ T_bc`` for stacked poses (frame c to frame a)."""
    return R_ab @ R_bc, np.einsum("...ij,...j->...i", R_ab, t_bc) + t_ab


def mean_pose(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Robust average of poses ``R (n, 3, 3)``, ``t (n, 3)``: chordal rotation mean, median translation."""
    R_mean = Rotation.from_matrix(R).mean().as_matrix()
    return R_mean, np.median(np.asarray(t).reshape(-1, 3), axis=0)


def triangulate_dlt(P: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation of many points from any number of views.

    Hand-written because ``cv2.triangulatePoints`` handles one camera pair at a time;
    this solves every point's homogeneous system in one batched SVD.

    Parameters
    ----------
    P : (C, 3, 4) float
        Projection matrices acting on the coordinates ``xy`` is given in (e.g.
        ``[R | t]`` for normalised undistorted coordinates).
    xy : (C, n, 2) float
        Observations, NaN where a camera did not see the point.

    Returns
    -------
    (n, 3) float
        Points; NaN where fewer than two views saw the point.
    """
    P = np.asarray(P, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64)
    C, n = xy.shape[:2]
    seen = np.isfinite(xy).all(axis=2)  # (C, n)
    x = np.where(seen, xy[..., 0], 0.0)
    y = np.where(seen, xy[..., 1], 0.0)
    rows_x = x[..., None] * P[:, None, 2, :] - P[:, None, 0, :]  # (C, n, 4)
    rows_y = y[..., None] * P[:, None, 2, :] - P[:, None, 1, :]
    A = np.concatenate([rows_x, rows_y], axis=0) * np.concatenate([seen, seen], axis=0)[..., None]
    A = np.transpose(A, (1, 0, 2))  # (n, 2C, 4)
    # Scale rows for conditioning.
    norm = np.linalg.norm(A, axis=2, keepdims=True)
    A = np.divide(A, norm, out=np.zeros_like(A), where=norm > 0)
    _, _, vt = np.linalg.svd(A)
    X = vt[:, -1, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        pts = X[:, :3] / X[:, 3:4]
    pts[seen.sum(axis=0) < 2] = np.nan
    return pts
