"""Score an estimated camera calibration against the true one (arrays in, numbers out).

Per camera:

* ``focal_error_pct``: ``100 * max(|fx - fx*| / fx*, |fy - fy*| / fy*)``;
* ``principal_point_error_px``: distance between ``(cx, cy)`` and the true one;
* ``distortion_error_px``: worst displacement over the image between the estimated
  and the true distortion models alone. A grid of pixels is taken back to ideal
  normalised coordinates with the *true* camera, then distorted by both models and
  mapped to pixels with the *true* K; the largest difference is reported. This isolates
  the distortion coefficients from focal/principal point errors (scored separately);
* ``projection_error_max_px``: the same grid of rays mapped through the whole estimated
  and true intrinsics (K and distortion together): what a user actually sees;
* ``rotation_error_deg``: angle of ``R_est R_true^T`` after aligning the world frames;
* ``translation_error_mm``: distance between the estimated and true camera *centres*
  after alignment;
* ``reprojection_rms_px``: passed in from the calibration result (not derivable from
  the two calibrations).

World alignment (``align``):

* ``"none"``: the estimate is already in the true world frame (e.g. both defined by the
  same floor board); compared as is.
* ``"rigid"``: the rotation and translation mapping estimated camera centres onto true
  ones (Umeyama / Kabsch, no scale) is applied first; for fewer than three cameras, or
  collinear centres, the rotation is the mean of ``R_true^T R_est`` over cameras instead.
* ``"similarity"``: as ``"rigid"`` with a scale (the scale found is reported; use it
  when the estimate's scale is arbitrary).

The alignment used and its parameters are reported in the result.
"""

from __future__ import annotations

from typing import Literal, Mapping

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from mocap.calibration import Calibration, Camera

Align = Literal["none", "rigid", "similarity"]


def _angle_deg(R: np.ndarray) -> float:
    """Rotation angle of ``R`` in degrees (via quaternions: accurate near 0, unlike arccos of the trace)."""
    return float(np.degrees(Rotation.from_matrix(R).magnitude()))


def _normalized_grid(cam: Camera, n: int = 41) -> np.ndarray:
    """Ideal normalised coordinates ``(n*n', 2)`` of a pixel grid covering ``cam``'s image."""
    w, h = cam.size
    xs = np.linspace(0.0, w - 1.0, n)
    ys = np.linspace(0.0, h - 1.0, max(2, int(round(n * h / w))))
    gx, gy = np.meshgrid(xs, ys)
    px = np.column_stack([gx.ravel(), gy.ravel()])
    und = cv2.undistortPoints(px.reshape(-1, 1, 2), cam.K, cam.dist, None, None, None,
                              (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14))
    return und.reshape(-1, 2)


def _distort(xy: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    pts = np.column_stack([xy, np.ones(len(xy))])
    uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist)
    return uv.reshape(-1, 2)


def distortion_error_px(estimated: Camera, truth: Camera, grid: int = 41) -> float:
    """Worst pixel displacement between the two distortion models over the true image (see module doc)."""
    xy = _normalized_grid(truth, grid)
    a = _distort(xy, truth.K, estimated.dist)
    b = _distort(xy, truth.K, truth.dist)
    return float(np.max(np.linalg.norm(a - b, axis=1)))


def projection_error_max_px(estimated: Camera, truth: Camera, grid: int = 41) -> float:
    """Worst pixel displacement between the full estimated and true intrinsic mappings."""
    xy = _normalized_grid(truth, grid)
    return float(np.max(np.linalg.norm(_distort(xy, estimated.K, estimated.dist) - _distort(xy, truth.K, truth.dist), axis=1)))


def align_worlds(estimated: Calibration, truth: Calibration, align: Align = "rigid") -> tuple[np.ndarray, np.ndarray, float]:
    """Transform ``x_true = s R x_est + t`` best aligning the estimated world to the true one.

    Returns
    -------
    R : (3, 3), t : (3,) metres, s : float
    """
    if align == "none":
        return np.eye(3), np.zeros(3), 1.0
    if align not in ("rigid", "similarity"):
        raise ValueError(f"align must be 'none', 'rigid' or 'similarity', got {align!r}")
    ce = np.stack([c.center for c in estimated])
    ct = np.stack([truth[c.name].center for c in estimated])
    me, mt = ce.mean(axis=0), ct.mean(axis=0)
    de, dt = ce - me, ct - mt
    sv = np.linalg.svd(de, compute_uv=False) if len(de) >= 2 else np.zeros(3)
    well_posed = len(ce) >= 3 and sv[1] > 1e-6 * max(sv[0], 1e-12)
    if well_posed:
        # Umeyama (1991): hand-written because scipy's Rotation.align_vectors has no scale.
        U, S, Vt = np.linalg.svd(dt.T @ de / len(ce))
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
        R = U @ D @ Vt
        s = float(np.trace(np.diag(S) @ D) / np.mean(np.sum(de ** 2, axis=1))) if align == "similarity" else 1.0
    else:
        # x_true = R x_est: camera rotations satisfy R_est = R_true R, so R = R_true^T R_est.
        R = Rotation.from_matrix(np.stack([truth[c.name].R.T @ c.R for c in estimated])).mean().as_matrix()
        s = 1.0
        if align == "similarity" and len(ce) >= 2:
            s = float(np.linalg.norm(dt) / max(np.linalg.norm(de), 1e-12))
    t = mt - s * R @ me
    return R, t, s


def compare_cameras(estimated: Camera, truth: Camera, R_align: np.ndarray | None = None,
                    t_align: np.ndarray | None = None, s_align: float = 1.0, grid: int = 41) -> dict[str, float]:
    """Errors of one camera (see module doc); the alignment maps estimated world to true world."""
    R_align = np.eye(3) if R_align is None else np.asarray(R_align)
    t_align = np.zeros(3) if t_align is None else np.asarray(t_align)
    fx_e, fy_e = estimated.K[0, 0], estimated.K[1, 1]
    fx_t, fy_t = truth.K[0, 0], truth.K[1, 1]
    # Camera in the true world: x_cam = R_e x_est + t_e, x_est = R_a^T (x_true - t_a) / s.
    R_e_aligned = estimated.R @ R_align.T
    c_e_aligned = s_align * R_align @ estimated.center + t_align
    angle = _angle_deg(R_e_aligned @ truth.R.T)
    return {
        "focal_error_pct": float(100.0 * max(abs(fx_e - fx_t) / fx_t, abs(fy_e - fy_t) / fy_t)),
        "fx_error_px": float(fx_e - fx_t),
        "fy_error_px": float(fy_e - fy_t),
        "principal_point_error_px": float(np.hypot(estimated.K[0, 2] - truth.K[0, 2], estimated.K[1, 2] - truth.K[1, 2])),
        "distortion_error_px": distortion_error_px(estimated, truth, grid),
        "projection_error_max_px": projection_error_max_px(estimated, truth, grid),
        "rotation_error_deg": angle,
        "translation_error_mm": float(1000.0 * np.linalg.norm(c_e_aligned - truth.center)),
    }


def compare_calibrations(estimated: Calibration, truth: Calibration, align: Align = "rigid",
                         reprojection_rms_px: Mapping[str, float] | None = None, grid: int = 41) -> dict:
    """Score every camera of ``estimated`` against the camera of the same name in ``truth``.

    Parameters
    ----------
    estimated, truth : Calibration
    align : {"none", "rigid", "similarity"}
        How to bring the estimated world frame onto the true one (module doc).
    reprojection_rms_px : mapping camera -> px, optional
        The calibration's own reprojection RMS, reported alongside.
    grid : int
        Grid points along the image width for the distortion errors.

    Returns
    -------
    dict
        ``"per_camera"``: name -> errors; ``"summary"``: for each error the worst camera
        under the plain name (e.g. ``focal_error_pct``) and the mean as ``<name>_mean``;
        ``"alignment"``: ``{"mode", "rotation_deg", "translation_mm", "scale"}``.
    """
    missing = [c.name for c in estimated if c.name not in truth.names]
    if missing:
        raise KeyError(f"cameras {missing} of the estimate are not in the ground truth ({truth.names})")
    R, t, s = align_worlds(estimated, truth, align)
    per = {c.name: compare_cameras(c, truth[c.name], R, t, s, grid) for c in estimated}
    if reprojection_rms_px is not None:
        for name, v in reprojection_rms_px.items():
            if name in per:
                per[name]["reprojection_rms_px"] = float(v)
    keys = list(next(iter(per.values())).keys())
    summary: dict[str, float] = {}
    for k in keys:
        vals = np.array([per[n][k] for n in per if k in per[n]], dtype=np.float64)
        if k in ("fx_error_px", "fy_error_px"):
            summary[k] = float(vals[np.argmax(np.abs(vals))])
        else:
            summary[k] = float(np.max(vals))
        summary[k + "_mean"] = float(np.mean(np.abs(vals)))
    angle = _angle_deg(R)
    return {
        "per_camera": per,
        "summary": summary,
        "alignment": {"mode": align, "rotation_deg": angle, "translation_mm": float(np.linalg.norm(t) * 1000.0), "scale": s},
    }
