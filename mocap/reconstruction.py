"""Labelled 2D tracks of several cameras to labelled 3D trajectories.

Correspondence across views is given by the labels the 2D trackers keep. It is first
corrected with the 3D points seen by the other cameras (:func:`relabel_views`: undoes
swaps, drops inconsistent views, re-acquires lost labels from the raw detections), then
checked with epipolar geometry (a view whose point lies far from the epipolar lines of
the other views' points of the same label is dropped), then every label of every frame is
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
from scipy.optimize import linear_sum_assignment

from mocap.calibration import Calibration
from mocap.errors import require, require_one_of
from mocap.smoothing import butterworth_filtfilt, fill_gaps, rts_smooth
from mocap.triangulation import (
    camera_normalized,
    epipolar_distances,
    normalized_coordinates,
    pixels_to_normalized,
    triangulate,
    triangulate_normalized,
)
from mocap.types import Detections, Trajectories, Tracks2D

__all__ = ["ReconstructionParams", "reconstruct", "relabel_views", "epipolar_keep_mask", "calibration_for_cameras"]


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
    refine, refine_iterations : bool, int
        Gauss-Newton refinement of the DLT points, and its iterations.
    min_views : int
        Views needed for a point (>= 2).
    coasting_weight : float
        Weight of a tracker's prediction while it coasts (status 2) relative to a measured
        detection (weight 1). 0 (default) uses measured detections only.
    smoothing : {"none", "butterworth", "rts"}
    cutoff_hz, butter_order : float, int
        Butterworth cut-off (single pass), Hz, and order.
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
    relabel_gate_px : float or None
        3D-guided correction of the 2D labels before triangulation (see
        :func:`relabel_views`): a camera's observation is re-assigned to the label whose
        point, triangulated from the other cameras, projects within this many pixels.
        None: ``1.5 * max_residual_px`` (both scale with the detection noise); 0
        disables it (labels are then taken as the trackers give them).
    relabel_sweeps : int
        Correction sweeps per frame.
    crowd_px : float
        A view of a marker is *crowded* when another marker's image lies within this many
        pixels of it (another label's observation, or another reconstructed marker's
        reprojection: a neighbour whose blob merged with this one is not observed itself).
        Its centroid then carries part of the neighbour's light: on bvh_walk's 1-2 pixel
        markers, views with a neighbour within 3 px are 0.41 px RMS from the true
        projection, isolated ones 0.12 px. 0 disables.
    crowded_weight : float
        Weight of a crowded view in the second triangulation (1 = no down-weighting). About
        the ratio of the two error variances, so that a point seen cleanly by two cameras
        barely moves for a crowded third, while a point seen only crowded is still measured.
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
    relabel_gate_px: float | None = None
    relabel_sweeps: int = 2
    crowd_px: float = 3.0
    crowded_weight: float = 0.1

    def __post_init__(self) -> None:
        require(self.epipolar_threshold_px > 0, self, "epipolar_threshold_px", "must be > 0 pixels (inf disables)")
        require(self.max_residual_px > 0, self, "max_residual_px", "must be > 0 pixels (inf disables)")
        require(self.refine_iterations >= 0, self, "refine_iterations", "must be >= 0")
        require(self.min_views >= 2, self, "min_views", "triangulation needs >= 2 views")
        require(0 <= self.coasting_weight <= 1, self, "coasting_weight", "must be in [0, 1]")
        require_one_of(self, "smoothing", ("none", "butterworth", "rts"))
        require(self.cutoff_hz > 0, self, "cutoff_hz", "must be > 0 Hz")
        require(self.butter_order >= 1, self, "butter_order", "must be >= 1")
        require(self.rts_accel_std > 0, self, "rts_accel_std", "must be > 0 m/s^2")
        require(self.rts_meas_std_m > 0, self, "rts_meas_std_m", "must be > 0 m")
        require(self.max_gap_frames >= 0, self, "max_gap_frames", "must be >= 0 frames")
        require_one_of(self, "gap_fill", ("auto", "cubic", "lsq"))
        require(self.gap_context_frames >= 1, self, "gap_context_frames", "must be >= 1 frame")
        require(self.relabel_gate_px is None or self.relabel_gate_px >= 0, self, "relabel_gate_px", "must be None or >= 0 pixels (0 disables)")
        require(self.relabel_sweeps >= 1, self, "relabel_sweeps", "must be >= 1")
        require(self.crowd_px >= 0, self, "crowd_px", "must be >= 0 pixels (0 disables)")
        require(0 < self.crowded_weight <= 1, self, "crowded_weight", "must be in (0, 1]")


def crowded_views(p2ds: np.ndarray, xyz: np.ndarray, calibration: Calibration, crowd_px: float) -> np.ndarray:
    """Which observations have another marker's image within ``crowd_px`` pixels.

    Parameters
    ----------
    p2ds : (C, F, M, 2) float
        Labelled observations, distorted pixels, NaN where missing.
    xyz : (F, M, 3) float
        The markers' reconstructed points (metres), NaN where missing.
    calibration : Calibration
        The cameras of ``p2ds``, in its order.
    crowd_px : float

    Returns
    -------
    (C, F, M) bool
        True where another label's observation, or another marker's reprojection, lies
        within ``crowd_px`` of the observation.
    """
    C, F, M, _ = p2ds.shape
    crowded = np.zeros((C, F, M), bool)
    if crowd_px <= 0 or M < 2:
        return crowded
    finite = np.isfinite(xyz).all(axis=2).ravel()
    proj = np.full((C, F * M, 2), np.nan)
    if finite.any():
        proj[:, finite] = calibration.project(xyz.reshape(-1, 3)[finite])
    proj = proj.reshape(C, F, M, 2)
    not_self = ~np.eye(M, dtype=bool)
    for c in range(C):
        obs = p2ds[c]
        ox, oy = obs[..., 0], obs[..., 1]
        px, py = proj[c][..., 0], proj[c][..., 1]
        with np.errstate(invalid="ignore"):
            # Distances (F, M, M) as np.linalg.norm(..., axis=3) computes them (the same bits)
            # without its reduction over a length-2 axis.
            dx, dy = ox[:, :, None] - ox[:, None], oy[:, :, None] - oy[:, None]
            d_obs = np.sqrt(dx * dx + dy * dy)
            dx, dy = ox[:, :, None] - px[:, None], oy[:, :, None] - py[:, None]
            d_proj = np.sqrt(dx * dx + dy * dy)
            near = ((d_obs < crowd_px) | (d_proj < crowd_px)) & not_self
        crowded[c] = near.any(axis=2) & np.isfinite(obs[..., 0])
    return crowded


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


def _reassign(pred: np.ndarray, cur: np.ndarray, cand: np.ndarray, gate_px: float) -> np.ndarray:
    """One camera, one frame: which candidate each label takes.

    Parameters
    ----------
    pred : (M, 2) float
        Labels' predicted positions (pixels, NaN where no prediction).
    cur : (M,) int
        Each label's current candidate index (-1 none).
    cand : (n, 2) float
        Candidate observations (pixels, same frame as ``pred``).
    gate_px : float

    Returns
    -------
    (M,) int
        Candidate index per label, -1 for none. Predicted labels are assigned by the
        Hungarian method within the gate (leaving one unassigned costs ``gate_px^2``);
        the others keep their current candidate unless a predicted label claimed it.
    """
    out = np.full(len(cur), -1)
    has = np.isfinite(pred).all(axis=1)
    claimed = np.zeros(len(cand), dtype=bool)
    if has.any() and len(cand):
        d2 = ((pred[has, None, :] - cand[None, :, :]) ** 2).sum(axis=2)
        g2 = gate_px**2
        big = 1e6 * g2
        d2 = np.where(d2 < g2, d2, big)
        k = int(has.sum())
        dummy = np.full((k, k), big)
        np.fill_diagonal(dummy, g2)
        rows, cols = linear_sum_assignment(np.hstack([d2, dummy]))
        real = cols < len(cand)
        idx = np.flatnonzero(has)
        out[idx[rows[real]]] = cols[real]
        claimed[cols[real]] = True
    keep = ~has & (cur >= 0)
    keep[keep] = ~claimed[cur[keep]]
    out[keep] = cur[keep]
    return out


def _candidates(
    raw: np.ndarray, detections: list[list[Detections]] | None, cal: Calibration
) -> tuple[list[list[np.ndarray]], list[list[np.ndarray]], np.ndarray]:
    """Per camera and frame, the candidate observations (distorted and normalised) and,
    per tracker label, its candidate index.

    Candidates are the tracker's observations plus, if given, all detections (exact
    duplicates merged). Returns ``cand_px[c][f]`` (n, 2) distorted pixels,
    ``cand_n[c][f]`` (n, 2) normalised coordinates and ``tracker_idx`` (F, C, M).
    """
    F, C, M, _ = raw.shape
    cand_px: list[list[np.ndarray]] = [[None] * F for _ in range(C)]
    cand_n: list[list[np.ndarray]] = [[None] * F for _ in range(C)]
    tracker_idx = np.full((F, C, M), -1)
    for c in range(C):
        per_frame = []
        for f in range(F):
            have = np.isfinite(raw[f, c]).all(axis=1)
            pts = raw[f, c, have]
            if detections is not None and len(detections[c][f]):
                pts = np.vstack([pts, detections[c][f].xy])
            if len(pts):
                uniq, inv = np.unique(pts, axis=0, return_inverse=True)
                tracker_idx[f, c, np.flatnonzero(have)] = inv.ravel()[: have.sum()]
            else:
                uniq = np.zeros((0, 2))
            per_frame.append(uniq)
        # One undistortion call per camera for all frames' candidates.
        sizes = [len(u) for u in per_frame]
        flat = np.vstack(per_frame) if sum(sizes) else np.zeros((0, 2))
        norm = pixels_to_normalized(cal[c], flat) if len(flat) else flat
        for f, part_px, part_n in zip(range(F), per_frame, np.split(norm, np.cumsum(sizes)[:-1])):
            cand_px[c][f] = part_px
            cand_n[c][f] = part_n
    return cand_px, cand_n, tracker_idx


class _LabelMotion:
    """Each label's last triangulated point and its velocity (metres per frame), to predict
    the label for up to ``max_coast_frames`` frames once no camera pair sees it."""

    def __init__(self, M: int, max_coast_frames: int) -> None:
        self.max_coast_frames = max_coast_frames
        self.last = np.full((M, 3), np.nan)         # last triangulated point of each label
        self.vel = np.zeros((M, 3))                 # its velocity, metres per frame
        self.last_f = np.full(M, -(10**9))

    def coast(self, f: int) -> np.ndarray:
        """``(M, 3)`` constant-velocity predictions at frame ``f`` (NaN where too old or never seen)."""
        age = f - self.last_f
        moving = (age <= self.max_coast_frames) & np.isfinite(self.last).all(axis=1)
        return np.where(moving[:, None], self.last + self.vel * age[:, None], np.nan)

    def update(self, f: int, now: np.ndarray) -> None:
        """Take frame ``f``'s triangulated points ``now (M, 3)`` (NaN where unseen)."""
        last, vel, last_f = self.last, self.vel, self.last_f
        seen = np.isfinite(now).all(axis=1)
        recent = seen & (f - last_f <= self.max_coast_frames) & np.isfinite(last).all(axis=1)
        vel[recent] = (now[recent] - last[recent]) / (f - last_f[recent])[:, None]
        vel[seen & ~recent] = 0.0
        last[seen] = now[seen]
        last_f[seen] = f


def _observed(cand_n: list, f: int, idx: np.ndarray) -> np.ndarray:
    """``(C, M, 2)`` normalised observations of frame ``f`` at candidate indices ``idx (C, M)``."""
    C, M = idx.shape
    xy = np.full((C, M, 2), np.nan)
    for c in range(C):
        ok = idx[c] >= 0
        xy[c, ok] = cand_n[c][f][idx[c, ok]]
    return xy


def _relabel_frame(cur: np.ndarray, cand_n: list, f: int, cal: Calibration, focal: np.ndarray, coast: np.ndarray,
                   sweeps: int, gate_px: float, max_residual_px: float) -> tuple[np.ndarray, np.ndarray | None]:
    """Frame ``f``'s correction sweeps (see :func:`relabel_views`): candidate indices ``cur
    (C, M)`` re-assigned to the labels the other cameras (or ``coast``) project onto them.
    Returns them and the sweep's points ``(C + 1, M, 3)``, or None when the last sweep
    changed labels (its all-camera block is then stale)."""
    C, M = cur.shape
    cams = np.arange(C)
    for _ in range(sweeps):
        xy = _observed(cand_n, f, cur)
        # Blocks 0..C-1 leave one camera out; block C uses them all.
        blocks = np.repeat(xy[None], C + 1, axis=0)             # (C + 1, C, M, 2)
        blocks[cams, cams] = np.nan
        tri = triangulate_normalized(blocks.transpose(1, 0, 2, 3).reshape(C, (C + 1) * M, 2), cal,
                                     max_residual_px=max_residual_px, refine=False)
        pts = tri.points.reshape(C + 1, M, 3)
        # A label's own motion only proposes an observation where it has none; it
        # never vetoes one (a coasting prediction drifts, the other views do not).
        from_motion = ~np.isfinite(pts[:C]).all(axis=2) & (cur < 0)        # (C, M)
        loo = np.where(from_motion[..., None], coast[None], pts[:C])
        new = cur.copy()
        for c in range(C):
            pred = camera_normalized(cal[c], loo[c]) * focal[c]
            here = np.where((cur[c] >= 0)[:, None], cand_n[c][f][np.maximum(cur[c], 0)] * focal[c], np.nan) if len(cand_n[c][f]) else np.full((M, 2), np.nan)
            with np.errstate(invalid="ignore"):
                ok = np.linalg.norm(here - pred, axis=1) <= gate_px
            if not (np.isfinite(pred).all(axis=1) & ~ok).any():
                continue  # every predicted label already at its observation
            new[c] = _reassign(pred, cur[c], cand_n[c][f] * focal[c], gate_px)
        if np.array_equal(new, cur):
            return cur, pts
        cur = new
    return cur, None


def _mapped(tracker_idx: np.ndarray, mapping: np.ndarray) -> np.ndarray:
    """``(C, M)`` candidate index of each label (-1: none) from one frame's ``tracker_idx
    (C, M)`` and the cameras' tracker label -> label ``mapping (C, M)``."""
    C, M = mapping.shape
    cur = np.full((C, M), -1)
    for c in range(C):
        a = np.flatnonzero((tracker_idx[c] >= 0) & (mapping[c] >= 0))
        cur[c, mapping[c, a]] = tracker_idx[c, a]
    return cur


def _remember(mapping: np.ndarray, tracker_idx: np.ndarray, cur: np.ndarray) -> None:
    """Remember in ``mapping`` which label each tracker label's observation now belongs to
    (-1: to none)."""
    for c in range(len(mapping)):
        a = np.flatnonzero(tracker_idx[c] >= 0)
        if a.size:
            same = tracker_idx[c, a][:, None] == cur[c][None, :]         # (a, M)
            mapping[c, a] = np.where(same.any(axis=1), np.argmax(same, axis=1), -1)


def relabel_views(
    tracks: Tracks2D,
    calibration: Calibration,
    gate_px: float = 3.0,
    max_residual_px: float = 2.0,
    detections: list[list[Detections]] | None = None,
    sweeps: int = 2,
    max_coast_frames: int = 10,
) -> Tracks2D:
    """Correct the 2D labels of each camera with the 3D points seen by the others.

    A 2D tracker can swap two labels or let a hidden marker's label take a neighbour's
    blob. Frame by frame, each label is triangulated from all cameras but ``c``
    (robustly: one wrong view among them is rejected) and projected into ``c``; the
    observations of ``c`` are re-assigned to the labels whose projections they match
    (Hungarian assignment within ``gate_px``). A label no other camera can triangulate
    is predicted from its own recent 3D motion (constant velocity, up to
    ``max_coast_frames`` frames), which also re-acquires labels the trackers lost
    everywhere when the raw ``detections`` are given.

    Corrections are remembered as a mapping from each camera's tracker labels to
    labels (or to "unknown" when the observation was found inconsistent) and carried to
    the next frames, so that errors made by different cameras at different times do
    not add up to a wrong majority.

    Frames are processed in order (the mapping and motion are sequential); within a
    frame all cameras are checked at once (one batched triangulation per sweep), in
    undistorted coordinates computed once for the whole sequence.

    Parameters
    ----------
    tracks : Tracks2D
        ``xy`` (F, C, M, 2) distorted pixels.
    calibration : Calibration
    gate_px : float
        Largest distance between an observation and a label's projection, pixels.
    max_residual_px : float
        Outlier threshold of the triangulations, pixels.
    detections : C lists of F Detections, optional
        All detections of every camera and frame (tracks' camera order); default: the
        observations present in ``tracks``.
    sweeps : int
        Correction sweeps per frame (a sweep uses the previous sweep's labels).
    max_coast_frames : int
        How long a label's own 3D motion may predict it once no camera pair sees it.

    Returns
    -------
    Tracks2D
        Same labels and cameras; ``xy`` corrected; ``status`` is 1 where an observation
        is assigned, else the tracker's coasting status or 0.
    """
    cal = calibration_for_cameras(list(tracks.camera_names), calibration)
    raw = np.asarray(tracks.xy, dtype=np.float64)
    F, C, M, _ = raw.shape
    if detections is not None and (len(detections) != C or any(len(d) != F for d in detections)):
        raise ValueError(f"detections must be {C} lists (one per camera) of {F} frames")
    cand_px, cand_n, tracker_idx = _candidates(raw, detections, cal)
    focal = cal.mean_focal_px
    out = np.full_like(raw, np.nan)
    mapping = np.tile(np.arange(M), (C, 1))        # camera c's tracker label a -> label (-1: unknown)
    motion = _LabelMotion(M, max_coast_frames)
    for f in range(F):
        cur = _mapped(tracker_idx[f], mapping)      # candidate index of each label
        cur, pts = _relabel_frame(cur, cand_n, f, cal, focal, motion.coast(f), sweeps, gate_px, max_residual_px)
        for c in range(C):
            ok = cur[c] >= 0
            out[f, c, ok] = cand_px[c][f][cur[c, ok]]
        _remember(mapping, tracker_idx[f], cur)
        # Each label's own 3D motion, for the frames when no camera pair sees it.
        if pts is None:
            now = triangulate_normalized(_observed(cand_n, f, cur), cal, max_residual_px=max_residual_px,
                                         refine=False).points
        else:
            now = pts[C]
        motion.update(f, now)
    status = np.asarray(tracks.status).copy() if tracks.status is not None else np.zeros((F, C, M), np.int8)
    measured = np.isfinite(out).all(axis=3)
    status = np.where(measured, Tracks2D.TRACKED, np.where(status == Tracks2D.TRACKED, 0, status)).astype(np.int8)
    return Tracks2D(list(tracks.labels), out, tracks.predicted_xy, status, list(tracks.camera_names))


def _checked_times(tracks: Tracks2D, times: np.ndarray | None) -> np.ndarray:
    """The frame times ``(F,)`` as float, after checking the tracks' shapes against them."""
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
    return t


def _weighted_views(tracks: Tracks2D, cal: Calibration, params: ReconstructionParams) -> tuple[np.ndarray, np.ndarray]:
    """``(C, F * M, 2)`` pixels and their weights: the measurements (weight 1), the trackers'
    coasting predictions where there is none (``coasting_weight``), views off the epipolar
    lines dropped (weight 0, NaN)."""
    xy = np.asarray(tracks.xy, dtype=np.float64)
    F, C, M, _ = xy.shape
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
    return p2ds, weights


def _triangulate_tracks(tracks: Tracks2D, cal: Calibration,
                        params: ReconstructionParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points ``(F, M, 3)``, residuals ``(F, M)`` px and view counts ``(F, M)`` of the tracks."""
    F, C, M, _ = np.shape(tracks.xy)
    p2ds, weights = _weighted_views(tracks, cal, params)

    def triangulate_views(w: np.ndarray):
        return triangulate(
            p2ds, cal, w,
            max_residual_px=params.max_residual_px,
            refine=params.refine and params.refine_iterations > 0,
            iterations=params.refine_iterations,
            min_views=params.min_views,
        )

    res = triangulate_views(weights)
    if params.crowd_px > 0 and params.crowded_weight < 1:
        # Views whose blob shares light with a neighbour's, found from the first points,
        # count less in a second triangulation.
        crowded = crowded_views(p2ds.reshape(C, F, M, 2), res.points.reshape(F, M, 3), cal, params.crowd_px)
        if crowded.any():
            res = triangulate_views(np.where(crowded.reshape(C, F * M), params.crowded_weight * weights, weights))
    return res.points.reshape(F, M, 3), res.residual_px.reshape(F, M), res.n_views.reshape(F, M).astype(np.int16)


def _smooth_and_fill(xyz: np.ndarray, t: np.ndarray, params: ReconstructionParams) -> tuple[np.ndarray, np.ndarray]:
    """The points smoothed as ``params.smoothing`` says, short gaps filled; and the filled mask."""
    F = xyz.shape[0]
    if params.smoothing != "none" and F > 1:
        dt = float(np.median(np.diff(t)))
        if params.smoothing == "butterworth":
            xyz = butterworth_filtfilt(xyz, 1.0 / dt, params.cutoff_hz, params.butter_order)
        else:
            xyz = rts_smooth(xyz, dt, params.rts_accel_std, params.rts_meas_std_m)
    method = params.gap_fill
    if method == "auto":
        method = "cubic" if params.smoothing != "none" else "lsq"
    return fill_gaps(xyz, t, params.max_gap_frames, method, params.gap_context_frames)


def reconstruct(
    tracks: Tracks2D,
    calibration: Calibration,
    params: ReconstructionParams | None = None,
    times: np.ndarray | None = None,
    detections: list[list[Detections]] | None = None,
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
    detections : C lists of F Detections, optional
        All detections (tracks' camera order): lets the 3D-guided label correction
        (:func:`relabel_views`) recover observations the trackers missed.

    Returns
    -------
    Trajectories
        ``xyz`` (F, M, 3) metres; ``n_views`` and ``residual_px`` per frame and label;
        ``filled`` marks spline-filled samples.
    """
    params = ReconstructionParams() if params is None else params
    t = _checked_times(tracks, times)
    C = len(tracks.camera_names)
    cal = calibration_for_cameras(list(tracks.camera_names), calibration)
    gate = 1.5 * params.max_residual_px if params.relabel_gate_px is None else params.relabel_gate_px
    if gate > 0 and np.isfinite(gate) and C >= 3:
        tracks = relabel_views(tracks, cal, gate, params.max_residual_px, detections, params.relabel_sweeps)
    xyz, residual, n_views = _triangulate_tracks(tracks, cal, params)
    xyz, filled = _smooth_and_fill(xyz, t, params)
    return Trajectories(list(tracks.labels), xyz, t, filled=filled, residual_px=residual, n_views=n_views)
