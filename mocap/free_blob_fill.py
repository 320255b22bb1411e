"""Markers the model check left out, measured again from blobs no kept label uses.

Inputs: labelled trajectories after the model check ``(F, M, 3)`` m, the 2D measurements
behind them ``(F, C, M, 2)`` px, every camera's blobs, the calibration and the checked
skeleton's marker positions ``(F, M, 3)`` m.
Output: the trajectories with points added where a marker is missing, and the measurements
that made them.

After the check a marker can be missing although its blobs were detected: its label had a
ghost or another marker's blob, and the check dropped the point. Its own blobs are then often
used by no label at all (on the CMU walk seen by 4 cameras, 222 of the 277 missing marker-frames
seen by two cameras or more had free blobs in at least two). Where the checked model predicts the
marker, a free blob close to the prediction in each camera (and no other free blob near it) is
taken, and the point they triangulate to is kept if it lies within the model check's own limit
of the prediction (:func:`mocap.model_check.error_limit_mm`), so the fill admits nothing the
check would drop. Written here because it joins the pipeline's own pieces (the checked model,
the blobs' use by labels, the robust triangulation); no library does this step.
"""

from __future__ import annotations

import numpy as np

from mocap.calibration import Calibration
from mocap.triangulation import triangulate
from mocap.types import Detections, Trajectories

__all__ = ["fill_from_free_blobs", "free_blobs"]


def free_blobs(blobs: np.ndarray, used_xy: np.ndarray) -> np.ndarray:
    """``(n,)`` bool: blobs ``(n, 2)`` that are none of the measurements ``used_xy`` ``(k, 2)``."""
    used_xy = used_xy[np.isfinite(used_xy).all(axis=1)]
    if len(blobs) == 0 or len(used_xy) == 0:
        return np.ones(len(blobs), bool)
    return ~(np.abs(blobs[:, None, :] - used_xy[None]).max(axis=2) < 1e-9).any(axis=1)


def fill_from_free_blobs(traj: Trajectories, measured_xy: np.ndarray, detections: list[list[Detections]],
                         calibration: Calibration, predicted: np.ndarray, limit_mm: tuple[float, float],
                         gate_px: float = 3.0, max_residual_px: float = 2.0
                         ) -> tuple[Trajectories, np.ndarray, int]:
    """Add the missing markers that free blobs near the model's prediction measure.

    Parameters
    ----------
    traj : Trajectories
        After the model check; ``filled`` marks points that are not measured.
    measured_xy : (F, C, M, 2) float
        The labelled measurements, px (NaN where none).
    detections : list over cameras of list over frames of Detections
    calibration : Calibration
    predicted : (F, M, 3) float
        The checked skeleton's markers, m (NaN where the model has no such marker).
    limit_mm : (two_views, more_views)
        The farthest a point may lie from its prediction, by the number of views it has.
    gate_px : float
        A free blob is taken in a camera when it is within this of the projected prediction and
        no other free blob is within twice this.
    max_residual_px : float
        The triangulation's outlier threshold.

    Returns
    -------
    traj : Trajectories
        With the points added.
    measured_xy : (F, C, M, 2) float
        With the blobs of the added points.
    added : int
    """
    F, M = traj.xyz.shape[:2]
    C = len(calibration)
    filled = np.zeros((F, M), bool) if traj.filled is None else np.asarray(traj.filled, bool)
    kept = np.isfinite(traj.xyz[..., 0]) & ~filled
    missing = ~kept & np.isfinite(predicted[..., 0])
    xyz, filled = traj.xyz.copy(), filled.copy()
    n_views = np.zeros((F, M), int) if traj.n_views is None else np.asarray(traj.n_views).copy()
    residual = np.full((F, M), np.nan) if traj.residual_px is None else np.asarray(traj.residual_px, float).copy()
    measured_xy = measured_xy.copy()
    added = 0
    for f in np.flatnonzero(missing.any(axis=1)):
        blobs = [detections[c][f].xy for c in range(C)]
        free = [free_blobs(blobs[c], measured_xy[f, c][kept[f]]) for c in range(C)]
        markers = np.flatnonzero(missing[f])
        uv = calibration.project(predicted[f, markers])                       # (C, n, 2)
        for i, m in enumerate(markers):
            p2ds = np.full((C, 1, 2), np.nan)
            pick = np.full(C, -1)
            for c in range(C):
                idx = np.flatnonzero(free[c])
                if len(idx) == 0 or not np.isfinite(uv[c, i]).all():
                    continue
                dist = np.linalg.norm(blobs[c][idx] - uv[c, i], axis=1)
                order = np.argsort(dist)
                if dist[order[0]] < gate_px and (len(order) == 1 or dist[order[1]] > 2 * gate_px):
                    pick[c] = idx[order[0]]
                    p2ds[c, 0] = blobs[c][pick[c]]
            if (pick >= 0).sum() < 2:
                continue
            tri = triangulate(p2ds, calibration, max_residual_px=max_residual_px)
            X = tri.points[0]
            if not np.isfinite(X).all():
                continue
            limit = limit_mm[0] if tri.n_views[0] == 2 else limit_mm[1]
            if np.linalg.norm(X - predicted[f, m]) * 1e3 > limit:
                continue
            xyz[f, m], n_views[f, m], residual[f, m], filled[f, m] = X, tri.n_views[0], tri.residual_px[0], False
            for c in np.flatnonzero((pick >= 0) & tri.used[:, 0]):
                free[c][pick[c]] = False
                measured_xy[f, c, m] = blobs[c][pick[c]]
            added += 1
    return Trajectories(list(traj.labels), xyz, traj.times, filled, residual, n_views), measured_xy, added
