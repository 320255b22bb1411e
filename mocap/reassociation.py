"""3D-guided 2D correspondence: reproject the reconstruction, re-associate detections.

After a first reconstruction every labelled 3D point is reprojected into every
camera and matched (Hungarian, gated) to that frame's detections. This

* recovers views where a camera's 2D tracker lost or never acquired a label although
  the marker is plainly visible (the 3D point from the other cameras says where);
* removes 2D associations that disagree with the 3D point (a swap in one camera);
* drops views whose blob is clearly not a whole marker: much smaller than the same
  marker's blobs in the other cameras at their distances (partly hidden behind a limb:
  its centroid is pulled off the centre) or much larger (two markers merged), as long
  as two good views remain.

The blob-size test needs no calibration of the detector: blob areas are compared with
the marker's expected projected area ``pi (f r / z)^2`` *relative to the median of
that ratio over all views of the frame*, so threshold and optics blur cancel out.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from mocap.calibration import Calibration
from mocap.types import Detections, Tracks2D, Trajectories


@dataclass(frozen=True)
class ReassociationParams:
    """Settings of :func:`reassociate`.

    gate_px : match radius around a reprojected triangulated point (pixels)
    gate_filled_px : match radius around a gap-filled (interpolated) point
    marker_radius_m : physical marker radius (for expected blob areas)
    min_area_ratio, max_area_ratio : accepted blob area relative to the frame's typical
        area-to-expected ratio; views outside are dropped when enough others remain
    min_good_views : views that must remain after dropping odd-sized blobs
    """

    gate_px: float = 3.0
    gate_filled_px: float = 6.0
    marker_radius_m: float = 0.007
    min_area_ratio: float = 0.7
    max_area_ratio: float = 1.6
    min_good_views: int = 2


def _match_within_gate(proj_px: np.ndarray, det_px: np.ndarray, gate_px: np.ndarray,
                       labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One camera and frame: labels ``(n,)`` at ``proj_px`` ``(n, 2)`` matched one to one to the
    detections ``det_px`` ``(k, 2)`` within each label's ``gate_px`` ``(n,)`` (Hungarian on the
    distances); returns the matched labels and detection indices."""
    # np.linalg.norm(proj_px[:, None, :] - det_px[None, :, :], axis=2), the same bits
    dx, dy = proj_px[:, None, 0] - det_px[None, :, 0], proj_px[:, None, 1] - det_px[None, :, 1]
    d = np.sqrt(dx * dx + dy * dy)
    allowed = d <= gate_px[:, None]
    if not allowed.any():
        return labels[:0], np.zeros(0, np.intp)
    rows, cols = linear_sum_assignment(np.where(allowed, d, 1e6))
    good = allowed[rows, cols]
    return labels[rows[good]], cols[good]


def reassociate(tracks: Tracks2D, detections: list[list[Detections]], traj: Trajectories,
                calibration: Calibration, params: ReassociationParams | None = None,
                points: np.ndarray | None = None, gate_px: np.ndarray | None = None) -> tuple[Tracks2D, dict[str, int]]:
    """New tracks whose ``xy`` are the detections that agree with the 3D reconstruction.

    Parameters
    ----------
    tracks : Tracks2D with ``xy`` (F, C, M, 2)
    detections : C lists of F Detections (calibration order)
    traj : Trajectories ``(F, M, 3)`` from a first reconstruction of ``tracks``
    calibration : Calibration
    points : (F, M, 3) metres, optional
        Where each label's marker is expected instead of ``traj.xyz`` (e.g. the markers
        of a fitted skeleton, which predicts markers the cameras lost); NaN = unknown.
    gate_px : (F, M) pixels, optional
        Match radius per frame and label (default from ``params`` and ``traj.filled``).

    Returns
    -------
    (Tracks2D, stats) where stats counts views ``recovered``, ``changed``, ``removed``
    and ``dropped_size``.
    """
    p = params or ReassociationParams()
    F, C, M, _ = tracks.xy.shape
    # Labels without a 3D point keep their trackers' measurements; labels with one are
    # re-associated below (or lose a measurement that disagrees with it).
    new_xy = np.array(tracks.xy, dtype=np.float64, copy=True)
    area_ratio = np.full((F, C, M), np.nan)
    X = traj.xyz if points is None else np.asarray(points, dtype=np.float64)
    filled = np.asarray(traj.filled, bool)
    have = np.isfinite(X).all(axis=2)
    cams = [calibration[n] for n in tracks.camera_names]
    for c, cam in enumerate(cams):
        f_px = cam.mean_focal_px
        proj = cam.project(X.reshape(-1, 3)).reshape(F, M, 2)
        z = cam.to_camera(np.nan_to_num(X.reshape(-1, 3))).reshape(F, M, 3)[..., 2]
        expected = np.pi * (f_px * p.marker_radius_m / np.where(z > 0, z, np.nan)) ** 2
        gate = np.where(filled, p.gate_filled_px, p.gate_px) if gate_px is None else np.asarray(gate_px)
        ok_all = have & np.isfinite(proj).all(axis=2)
        for f in range(F):
            det = detections[c][f]
            ok = ok_all[f]
            if not ok.any():
                continue
            if len(det) == 0:
                new_xy[f, c, ok] = np.nan
                continue
            labels = np.nonzero(ok)[0]
            new_xy[f, c, labels] = np.nan
            m_idx, j_idx = _match_within_gate(proj[f, labels], det.xy, gate[f, labels], labels)
            new_xy[f, c, m_idx] = det.xy[j_idx]
            area_ratio[f, c, m_idx] = det.area[j_idx] / expected[f, m_idx]
    # Blob size relative to the frame's typical ratio (threshold and blur cancel out).
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a frame with no blob at all: NaN, said by the metrics
        typical = np.nanmedian(area_ratio.reshape(F, -1), axis=1)
        rel = area_ratio / typical[:, None, None]
    odd = np.isfinite(rel) & ((rel < p.min_area_ratio) | (rel > p.max_area_ratio))
    n_valid = np.isfinite(new_xy).all(axis=3)
    good_views = (n_valid & ~odd).sum(axis=1, keepdims=True)
    drop = odd & (good_views >= p.min_good_views)
    new_xy[drop] = np.nan
    old_valid = np.isfinite(tracks.xy).all(axis=3)
    now_valid = np.isfinite(new_xy).all(axis=3)
    moved = old_valid & now_valid & (np.linalg.norm(np.nan_to_num(new_xy - tracks.xy), axis=3) > 1e-9)
    stats = {
        "recovered": int((now_valid & ~old_valid).sum()),
        "changed": int(moved.sum()),
        "removed": int((old_valid & ~now_valid & ~drop).sum()),
        "dropped_size": int(drop.sum()),
    }
    # Keep the trackers' own estimates and status for reporting; only the measurements change.
    out = Tracks2D(list(tracks.labels), new_xy, tracks.predicted_xy, tracks.status, list(tracks.camera_names))
    return out, stats
