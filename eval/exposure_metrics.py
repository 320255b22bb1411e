"""Detections through a change of light: how many true markers each frame's blobs find, and how
long after a light event that rate takes to come back (auto exposure's recovery).

Arrays in, numbers out: blobs ``(n, 2)`` px per camera and frame, true marker positions
``(F, C, M, 2)`` px and their visibility ``(F, C, M)``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["detection_rate", "detection_precision", "recovery_time_s"]


def detection_rate(blobs: list[list[np.ndarray]], true_xy: np.ndarray, visible: np.ndarray, radius_px: float = 2.0) -> np.ndarray:
    """Per frame ``(F,)``: the fraction of visible markers (over all cameras) with a blob within
    ``radius_px`` of their true image position (NaN for a frame with no visible marker).

    blobs : C lists of F arrays ``(n, 2)`` px; true_xy : ``(F, C, M, 2)`` px; visible : ``(F, C, M)`` bool
    """
    F, C = visible.shape[:2]
    found = np.zeros(F)
    total = visible.reshape(F, -1).sum(axis=1).astype(float)
    for c in range(C):
        for k in range(F):
            vis = np.flatnonzero(visible[k, c])
            xy = np.asarray(blobs[c][k], float).reshape(-1, 2)
            if not len(vis) or not len(xy):
                continue
            d = np.linalg.norm(true_xy[k, c, vis][:, None] - xy[None], axis=2).min(axis=1)
            found[k] += np.count_nonzero(d <= radius_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0, found / total, np.nan)


def detection_precision(blobs: list[list[np.ndarray]], true_xy: np.ndarray, visible: np.ndarray,
                        radius_px: float = 2.0) -> np.ndarray:
    """Per frame ``(F,)``: the fraction of blobs (over all cameras) within ``radius_px`` of a visible
    marker's true image position (NaN for a frame without blobs): what is not is noise or clutter."""
    F, C = visible.shape[:2]
    good = np.zeros(F)
    total = np.zeros(F)
    for c in range(C):
        for k in range(F):
            xy = np.asarray(blobs[c][k], float).reshape(-1, 2)
            total[k] += len(xy)
            vis = np.flatnonzero(visible[k, c])
            if not len(vis) or not len(xy):
                continue
            d = np.linalg.norm(xy[:, None] - true_xy[k, c, vis][None], axis=2).min(axis=1)
            good[k] += np.count_nonzero(d <= radius_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0, good / total, np.nan)


def recovery_time_s(times: np.ndarray, rate: np.ndarray, event_s: float, before_s: float = 0.5, fraction: float = 0.9,
                    hold_frames: int = 5) -> float:
    """Seconds from ``event_s`` until the detection ``rate (F,)`` is back to ``fraction`` of its mean
    over the ``before_s`` before the event and stays there for ``hold_frames`` frames (0 when it
    never fell below; inf when it does not come back within the take; NaN when there is no frame
    before the event to compare with)."""
    times, rate = np.asarray(times, float), np.asarray(rate, float)
    pre = (times < event_s) & (times >= event_s - before_s) & np.isfinite(rate)
    if not pre.any():
        return float("nan")
    level = fraction * float(np.mean(rate[pre]))
    after = np.flatnonzero(times >= event_s)
    ok = np.nan_to_num(rate[after], nan=0.0) >= level
    for i in range(len(after)):
        if ok[i: i + hold_frames].all() and i + hold_frames <= len(after):
            return 0.0 if i == 0 else float(times[after[i]] - event_s)
    return float("inf")
