"""Skeleton (joint angles and joint centres) scored against ground truth."""

from __future__ import annotations

import numpy as np


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles to (-pi, pi]."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def joint_angle_rmse_deg(est_rad: np.ndarray, true_rad: np.ndarray, mask: np.ndarray | None = None) -> float:
    """RMSE over frames and joints of wrapped angle differences, degrees.

    est_rad, true_rad : (F, H); mask : (H,) or (F, H) bool of the joints to score.
    """
    d = wrap_angle(np.asarray(est_rad) - np.asarray(true_rad))
    if mask is not None:
        d = np.where(np.broadcast_to(mask, d.shape), d, np.nan)
    d = d[np.isfinite(d)]
    return float(np.degrees(np.sqrt(np.mean(d**2)))) if d.size else float("nan")


def per_joint_angle_rmse_deg(est_rad: np.ndarray, true_rad: np.ndarray) -> np.ndarray:
    d = wrap_angle(np.asarray(est_rad) - np.asarray(true_rad))
    with np.errstate(invalid="ignore"):
        return np.degrees(np.sqrt(np.nanmean(d**2, axis=0)))


def joint_position_rmse_mm(est_xyz: np.ndarray, true_xyz: np.ndarray) -> float:
    """RMSE of joint-centre positions ``(F, J, 3)`` metres, in millimetres."""
    e = np.linalg.norm(np.asarray(est_xyz) - np.asarray(true_xyz), axis=-1)
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e**2)) * 1e3) if e.size else float("nan")
