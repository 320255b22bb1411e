"""Labelled 2D tracks of several cameras to labelled 3D trajectories.

Correspondence across views is given by the labels the 2D trackers keep; it is checked
with epipolar geometry (a view whose point lies far from the epipolar lines of the other
views' points of the same label is dropped), then every label of every frame is
triangulated in one vectorised call (:func:`mocap.triangulation.triangulate`: DLT,
refinement, worst-camera rejection on the reprojection residual). Optionally the
trajectories are smoothed (zero-lag Butterworth or Kalman/RTS, :mod:`mocap.smoothing`) and
short gaps are filled with a cubic spline and flagged in ``Trajectories.filled``; longer
gaps stay NaN.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from mocap.calibration import Calibration
from mocap.smoothing import butterworth_filtfilt, fill_gaps, rts_smooth
from mocap.triangulation import epipolar_distances, normalized_coordinates, triangulate
from mocap.types import Trajectories, Tracks2D

__all__ = ["ReconstructionParams", "reconstruct", "epipolar_keep_mask", "calibration_for_cameras"]


@dataclass(frozen=True)
class ReconstructionParams:
    """Settings of :func:`reconstruct`.

    Attributes
    ----------
    epipolar_threshold_px : float
        A view is dropped when its point is farther than this (pixels, symmetric
        epipolar distance) from the epipolar lines of all but at most one of the other
        views that agree best. ``inf`` disables the check.
    max_residual_px : float
        Reprojection residual above which the worst camera is dropped (pixels).
    refine : bool
        Gauss-Newton refinement of the DLT points.
    refine_iterations : int
    min_views : int
        Views needed for a point (>= 2).
    coasting_weight : float
        Weight of a tracker's prediction while it coasts (status 2) relative to a measured
        detection (weight 1). 0 (default) uses measured detections only.
    smoothing : {"none", "butterworth", "rts"}
    cutoff_hz : float
        Butterworth cut-off (single pass), Hz.
    butter_order : int
    rts_accel_std : float
        RTS smoother: white-acceleration std, m/s^2.
    rts_meas_std_m : float
        RTS smoother: measurement noise std, metres.
    max_gap_frames : int
        Longest interior gap filled by cubic spline (frames); 0 disables filling.
    gap_fill : {"auto", "cubic", "lsq"}
        Cubic used to fill (see :func:`mocap.smoothing.fill_gaps`). ``"auto"``: an
        interpolating spline after smoothing, a least-squares cubic on raw points (an
        interpolating spline through noisy points amplifies their noise in the gap).
    gap_context_frames : int
        Valid frames on each side of a gap used to fit the spline.
    """

    epipolar_threshold_px: float = 4.0
    max_residual_px: float = 2.0
    refine: bool = True
    refine_iterations: int = 3
    min_views: int = 2
    coasting_weight: float = 0.0
    smoothing: Literal["none", "butterworth", "rts"] = "none"
    cutoff_hz: float = 6.0
    butter_order: int = 4
    rts_accel_std: float = 30.0
    rts_meas_std_m: float = 0.001
    max_gap_frames: int = 10
    gap_fill: Literal["auto", "cubic", "lsq"] = "auto"
    gap_context_frames: int = 10

    def __post_init__(self) -> None:
        def need(cond: bool, field: str, value, fix: str) -> None:
            if not cond:
                raise ValueError(f"ReconstructionParams.{field}={value!r}: {fix}")

        need(self.epipolar_threshold_px > 0, "epipolar_threshold_px", self.epipolar_threshold_px, "must be > 0 pixels (inf disables)")
        need(self.max_residual_px > 0, "max_residual_px", self.max_residual_px, "must be > 0 pixels (inf disables)")
        need(self.refine_iterations >= 0, "refine_iterations", self.refine_iterations, "must be >= 0")
        need(self.min_views >= 2, "min_views", self.min_views, "triangulation needs >= 2 views")
        need(0 <= self.coasting_weight <= 1, "coasting_weight", self.coasting_weight, "must be in [0, 1]")
        need(self.smoothing in ("none", "butterworth", "rts"), "smoothing", self.smoothing, "use 'none', 'butterworth' or 'rts'")
        need(self.cutoff_hz > 0, "cutoff_hz", self.cutoff_hz, "must be > 0 Hz")
        need(self.butter_order >= 1, "butter_order", self.butter_order, "must be >= 1")
        need(self.rts_accel_std > 0, "rts_accel_std", self.rts_accel_std, "must be > 0 m/s^2")
        need(self.rts_meas_std_m > 0, "rts_meas_std_m", self.rts_meas_std_m, "must be > 0 m")
        need(self.max_gap_frames >= 0, "max_gap_frames", self.max_gap_frames, "must be >= 0 frames")
        need(self.gap_fill in ("auto", "cubic", "lsq"), "gap_fill", self.gap_fill, "use 'auto', 'cubic' or 'lsq'")
        need(self.gap_context_frames >= 1, "gap_context_frames", self.gap_context_frames, "must be >= 1 frame")


def calibration_for_cameras(camera_names: list[str], calibration: Calibration) -> Calibration:
    """The calibration's cameras in the order of ``camera_names``.

    Raises
    ------
    ValueError
        If a name has no calibrated camera (the message lists both sets of names).
    """
    names = list(camera_names)
    if names == calibration.names:
        return calibration
    missing = [n for n in names if n not in calibration.names]
    if missing:
        raise ValueError(
            f"tracks name cameras {names} but the calibration has {calibration.names}; "
            f"no calibration for {missing}: use the calibration file of this rig or rename the videos' cameras"
        )
    return Calibration(tuple(calibration[n] for n in names))


def epipolar_keep_mask(xy_norm: np.ndarray, calibration: Calibration, threshold_px: float) -> np.ndarray:
    """Which observations of each point agree with the other views' epipolar lines.

    Parameters
    ----------
    xy_norm : (C, N, 2) float
        Undistorted normalised coordinates, NaN where missing.
    calibration : Calibration
    threshold_px : float
        Symmetric epipolar distance (pixels) under which two views agree.

    Returns
    -------
    (C, N) bool
        An observation is kept when it agrees with at least one other view and with
        at least ``s_max - 1`` views, ``s_max`` being the best agreement count among the
        point's views (so a single wrong view among three or more consistent ones is
        dropped; ambiguous cases are left to the reprojection test). A point seen in two
        views that disagree loses both.
    """
    finite = np.isfinite(xy_norm).all(axis=2)
    if not np.isfinite(threshold_px):
        return finite
    d = epipolar_distances(xy_norm, calibration)          # (C, C, N)
    with np.errstate(invalid="ignore"):
        agree = d < threshold_px
    support = agree.sum(axis=1)                            # (C, N)
    s_max = support.max(axis=0, keepdims=True)
    return finite & (support >= 1) & (support >= s_max - 1)


def reconstruct(
    tracks: Tracks2D,
    calibration: Calibration,
    params: ReconstructionParams | None = None,
    times: np.ndarray | None = None,
) -> Trajectories:
    """Triangulate labelled 2D tracks into 3D trajectories.

    Parameters
    ----------
    tracks : Tracks2D
        ``xy`` (F, C, M, 2) distorted pixels per frame, camera and label, NaN where not
        measured; ``camera_names`` must all be in ``calibration``.
    calibration : Calibration
    params : ReconstructionParams, optional
    times : (F,) float
        Frame timestamps in seconds (needed for smoothing and gap filling).

    Returns
    -------
    Trajectories
        ``xyz`` (F, M, 3) metres; ``n_views`` and ``residual_px`` per frame and label;
        ``filled`` marks spline-filled samples.
    """
    params = ReconstructionParams() if params is None else params
    xy = np.asarray(tracks.xy, dtype=np.float64)
    if xy.ndim != 4 or xy.shape[3] != 2:
        raise ValueError(f"tracks.xy must be (F, C, M, 2) pixels, got shape {xy.shape}")
    F, C, M, _ = xy.shape
    if len(tracks.camera_names) != C or len(tracks.labels) != M:
        raise ValueError(
            f"tracks.xy is {xy.shape} but there are {len(tracks.camera_names)} camera names and {len(tracks.labels)} labels"
        )
    if times is None:
        raise ValueError("reconstruct needs the frame times (seconds), e.g. np.arange(F) / rate_hz")
    t = np.asarray(times, dtype=np.float64).ravel()
    if t.shape[0] != F:
        raise ValueError(f"times has {t.shape[0]} entries but tracks have {F} frames")
    cal = calibration_for_cameras(list(tracks.camera_names), calibration)

    p2ds = xy.transpose(1, 0, 2, 3).reshape(C, F * M, 2).copy()
    weights = np.isfinite(p2ds).all(axis=2).astype(np.float64)
    if params.coasting_weight > 0 and tracks.predicted_xy is not None and tracks.status is not None:
        pred = np.asarray(tracks.predicted_xy, dtype=np.float64).transpose(1, 0, 2, 3).reshape(C, F * M, 2)
        coast = (np.asarray(tracks.status).transpose(1, 0, 2).reshape(C, F * M) == Tracks2D.COASTING)
        coast &= (weights == 0) & np.isfinite(pred).all(axis=2)
        p2ds[coast] = pred[coast]
        weights[coast] = params.coasting_weight

    xy_norm = normalized_coordinates(p2ds, cal)
    keep = epipolar_keep_mask(xy_norm, cal, params.epipolar_threshold_px)
    weights = np.where(keep, weights, 0.0)
    p2ds = np.where(keep[..., None], p2ds, np.nan)
    res = triangulate(
        p2ds, cal, weights,
        max_residual_px=params.max_residual_px,
        refine=params.refine and params.refine_iterations > 0,
        iterations=params.refine_iterations,
        min_views=params.min_views,
    )
    xyz = res.points.reshape(F, M, 3)
    residual = res.residual_px.reshape(F, M)
    n_views = res.n_views.reshape(F, M).astype(np.int16)

    if params.smoothing != "none" and F > 1:
        dt = float(np.median(np.diff(t)))
        if params.smoothing == "butterworth":
            xyz = butterworth_filtfilt(xyz, 1.0 / dt, params.cutoff_hz, params.butter_order)
        else:
            xyz = rts_smooth(xyz, dt, params.rts_accel_std, params.rts_meas_std_m)
    method = params.gap_fill
    if method == "auto":
        method = "cubic" if params.smoothing != "none" else "lsq"
    xyz, filled = fill_gaps(xyz, t, params.max_gap_frames, method, params.gap_context_frames)
    return Trajectories(list(tracks.labels), xyz, t, filled=filled, residual_px=residual, n_views=n_views)
