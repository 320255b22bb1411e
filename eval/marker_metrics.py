"""Marker capture scored against ground truth: arrays in, numbers out.

Definitions (the same for every tracker and scenario):

* ``rmse_mm``: root mean square of the 3D distance between each label's estimate and
  its own true marker centre, over every frame and label where the estimate is finite
  (triangulated or gap-filled).
* ``reconstructed_fraction``: of the marker-frames the ground truth marks visible in
  two or more cameras, the fraction with a finite estimate.
* ``label_swaps``: number of times a label's 3D estimate *starts* sitting on another
  marker: it is more than ``swap_radius_m`` from its own marker and within it of
  another one.
* ``losses_2d``: number of 2D loss events over all cameras and labels: a loss starts
  at a frame where the marker is visible in that camera and its label's tracked
  position is absent (lost) or more than ``loss_radius_px`` from the true projection,
  after a frame where it was correct.
* ``gaps`` and ``gaps_recovered``: a gap is a run of frames where a marker is visible in
  fewer than two cameras, strictly inside the span where it is visible in two or more; it
  is recovered when, within ``window`` frames after it ends, the marker's own label is
  estimated within ``tol_m`` of it (labelled again, not taken over by a neighbour).
"""

from __future__ import annotations

import numpy as np


def _onsets(bad: np.ndarray, axis: int = 0) -> int:
    """Number of False->True transitions along ``axis`` (a True first frame counts)."""
    b = np.moveaxis(bad.astype(bool), axis, 0)
    prev = np.concatenate([np.zeros((1,) + b.shape[1:], bool), b[:-1]])
    return int(np.sum(b & ~prev))


def marker_errors_m(est_xyz: np.ndarray, true_xyz: np.ndarray) -> np.ndarray:
    """Per frame and label 3D error ``(F, M)`` metres, NaN where the estimate is missing."""
    return np.linalg.norm(np.asarray(est_xyz) - np.asarray(true_xyz), axis=-1)


def rmse_mm(est_xyz: np.ndarray, true_xyz: np.ndarray) -> float:
    e = marker_errors_m(est_xyz, true_xyz)
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e**2)) * 1e3) if e.size else float("nan")


def reconstructed_fraction(est_xyz: np.ndarray, visible: np.ndarray, min_views: int = 2) -> float:
    """``visible`` is ``(F, C, M)`` ground-truth visibility."""
    eligible = np.asarray(visible).sum(axis=1) >= min_views
    if not eligible.any():
        return float("nan")
    have = np.isfinite(np.asarray(est_xyz)).all(axis=-1)
    return float(have[eligible].mean())


def label_swaps(est_xyz: np.ndarray, true_xyz: np.ndarray, swap_radius_m: float = 0.02) -> int:
    est = np.asarray(est_xyz)
    tru = np.asarray(true_xyz)
    d = np.linalg.norm(est[:, :, None, :] - tru[:, None, :, :], axis=-1)  # (F, M_est, M_true)
    M = d.shape[1]
    own = d[:, np.arange(M), np.arange(M)]
    d_other = d.copy()
    d_other[:, np.arange(M), np.arange(M)] = np.inf
    with np.errstate(invalid="ignore"):
        swapped = (own > swap_radius_m) & (np.nanmin(d_other, axis=2) < swap_radius_m)
    return _onsets(swapped)


def losses_2d(tracked_xy: np.ndarray, true_xy: np.ndarray, visible: np.ndarray, loss_radius_px: float = 5.0) -> int:
    """``tracked_xy`` (F, C, M, 2) tracker estimate (NaN when lost), ``true_xy`` and ``visible`` alike."""
    err = np.linalg.norm(np.asarray(tracked_xy) - np.asarray(true_xy), axis=-1)
    vis = np.asarray(visible, bool)
    bad = vis & ~(err <= loss_radius_px)  # NaN (lost) counts as bad
    return _onsets(bad)


def per_marker_error_mm(est_xyz: np.ndarray, true_xyz: np.ndarray) -> np.ndarray:
    """Error ``(F, M)`` in millimetres (NaN where missing), for plots."""
    return marker_errors_m(est_xyz, true_xyz) * 1e3


def gap_recovery(est_xyz: np.ndarray, true_xyz: np.ndarray, visible: np.ndarray, window: int = 10,
                 tol_m: float = 0.005) -> tuple[int, int]:
    """``(gaps recovered, gaps)`` (see the module docstring); ``visible`` is ``(F, C, M)``."""
    eligible = np.asarray(visible).sum(axis=1) >= 2                     # (F, M)
    err = marker_errors_m(est_xyz, true_xyz)
    good = np.isfinite(err) & (err < tol_m)
    F, M = eligible.shape
    gaps = recovered = 0
    for m in range(M):
        seen = np.flatnonzero(eligible[:, m])
        if seen.size < 2:
            continue
        inside = ~eligible[seen[0]:seen[-1] + 1, m]
        starts = np.flatnonzero(inside & ~np.concatenate([[False], inside[:-1]]))
        for s in starts:
            end = s + int(np.argmax(~inside[s:])) + seen[0]               # first eligible frame after the gap
            gaps += 1
            after = np.arange(end, min(end + window, F))
            after = after[eligible[after, m]]
            recovered += bool(good[after, m].any())
    return recovered, gaps


def summarize_markers(est_xyz, true_xyz, visible, tracked_xy=None, true_xy=None, filled=None) -> dict[str, float]:
    out = {
        "markers.rmse_mm": rmse_mm(est_xyz, true_xyz),
        "markers.reconstructed_fraction": reconstructed_fraction(est_xyz, visible),
        "markers.label_swaps": label_swaps(est_xyz, true_xyz),
    }
    e = marker_errors_m(est_xyz, true_xyz)
    fin = e[np.isfinite(e)]
    out["markers.p95_error_mm"] = float(np.percentile(fin, 95) * 1e3) if fin.size else float("nan")
    out["markers.max_error_mm"] = float(fin.max() * 1e3) if fin.size else float("nan")
    out["markers.gaps_recovered"], out["markers.gaps"] = gap_recovery(est_xyz, true_xyz, visible)
    if filled is not None:
        out["markers.filled_fraction"] = float(np.asarray(filled).mean())
    if tracked_xy is not None and true_xy is not None:
        out["markers.losses_2d"] = losses_2d(tracked_xy, true_xy, visible)
    return out
