"""Wand calibration: three markers at known distances, waved through the capture volume.

Optical mocap systems calibrate extrinsics by waving a wand: every frame gives three
points seen by several cameras, spread through the whole volume, and the known marker
distances fix the scale. Here the wand can

* refine a board-based rig (its points and distance residuals join the bundle
  adjustment), or
* build the rig on its own when the cameras' intrinsics are known (each camera
  calibrated with its own board views, or given): relative poses of camera pairs come
  from the essential matrix of their common wand points (``cv2.findEssentialMat`` +
  ``cv2.recoverPose``), each pair's scale from the wand distances, and a maximum
  spanning tree chains them from the reference camera.

Markers are labelled: ``markers_px[c, f, m]`` is marker ``m`` of :class:`WandSpec`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mocap.calib.errors import DisconnectedCamerasError, WandError
from mocap.calib.extrinsics import connected_groups, maximum_spanning_tree
from mocap.calib.geometry import compose_poses, intrinsics_from_vector, triangulate_dlt

#: Marker index pairs of ``WandSpec.distances_m``.
WAND_PAIRS = ((0, 1), (1, 2), (0, 2))


@dataclass(frozen=True)
class WandSpec:
    """A rigid wand with three markers.

    Attributes
    ----------
    distances_m : (float, float, float)
        Distances between markers 0-1, 1-2 and 0-2, metres (measure the real wand).
    """

    distances_m: tuple[float, float, float]

    def __post_init__(self) -> None:
        d = tuple(float(x) for x in self.distances_m)
        if len(d) != 3 or min(d) <= 0 or not np.all(np.isfinite(d)):
            raise ValueError(f"WandSpec.distances_m needs three positive distances (0-1, 1-2, 0-2) in metres, got {self.distances_m}")
        a, b, c = sorted(d)
        if c > a + b + 1e-9:
            raise ValueError(f"WandSpec.distances_m {d} violate the triangle inequality: no three points have these distances")
        object.__setattr__(self, "distances_m", d)

    @classmethod
    def collinear(cls, d01_m: float, d12_m: float) -> "WandSpec":
        """Markers on a line: 0 -- 1 -- 2."""
        return cls((d01_m, d12_m, d01_m + d12_m))

    @property
    def distances(self) -> np.ndarray:
        return np.asarray(self.distances_m)


def wand_distances(points: np.ndarray) -> np.ndarray:
    """Distances of marker pairs 0-1, 1-2, 0-2: ``(F, 3, 3)`` metres -> ``(F, 3)``."""
    p = np.asarray(points, dtype=np.float64)
    idx = np.asarray(WAND_PAIRS)
    return np.linalg.norm(p[:, idx[:, 0]] - p[:, idx[:, 1]], axis=2)


def normalized_observations(markers_px: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """Undistorted normalised coordinates ``(C, F, 3, 2)`` of pixel observations (NaN kept)."""
    out = np.full(markers_px.shape, np.nan)
    for c in range(markers_px.shape[0]):  # one vectorised undistortPoints call per camera
        K, dist = intrinsics_from_vector(intrinsics[c])
        p = markers_px[c].reshape(-1, 2)
        ok = np.isfinite(p).all(axis=1)
        if ok.any():
            und = cv2.undistortPoints(p[ok].reshape(-1, 1, 2), K, dist, None, None, None,
                                      (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12))
            flat = out[c].reshape(-1, 2)
            flat[ok] = und.reshape(-1, 2)
            out[c] = flat.reshape(out[c].shape)
    return out


def triangulate_wand(intrinsics: np.ndarray, R_cw: np.ndarray, t_cw: np.ndarray, markers_px: np.ndarray) -> np.ndarray:
    """Wand markers in 3D, ``(F, 3, 3)`` metres (NaN where fewer than two cameras saw one)."""
    xy = normalized_observations(np.asarray(markers_px, dtype=np.float64), intrinsics)
    C, F = xy.shape[:2]
    P = np.concatenate([R_cw, t_cw[:, :, None]], axis=2)
    return triangulate_dlt(P, xy.reshape(C, F * 3, 2)).reshape(F, 3, 3)


def wand_initial_rig(intrinsics: np.ndarray, markers_px: np.ndarray, spec: WandSpec, camera_names: list[str],
                     reference: int = 0, min_frames: int = 10) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]]]:
    """Camera poses from the wand alone (see module docstring).

    Parameters
    ----------
    intrinsics : (C, 9) float
        Known ``fx fy cx cy k1 k2 p1 p2 k3`` of each camera.
    markers_px : (C, F, 3, 2) float
        Labelled wand markers, NaN where unseen.
    spec : WandSpec
    camera_names : list[str]
    reference : int
        Camera whose frame is the world.
    min_frames : int
        Fewest common frames (all three markers) for a camera pair to be linked.

    Returns
    -------
    R_cw, t_cw : (C, 3, 3), (C, 3)
        World-to-camera poses in the reference camera's frame, metres.
    tree : list of (parent, child)
    """
    markers_px = np.asarray(markers_px, dtype=np.float64)
    C = markers_px.shape[0]
    xy = normalized_observations(markers_px, intrinsics)
    complete = np.isfinite(xy).all(axis=(2, 3))  # (C, F)
    shared = (complete[:, None, :] & complete[None, :, :]).sum(axis=2)
    np.fill_diagonal(shared, 0)
    linked = np.where(shared >= min_frames, shared, 0)
    groups = connected_groups(linked)
    if len(groups) > 1:
        raise DisconnectedCamerasError([[camera_names[i] for i in g] for g in groups], camera_names[reference])
    tree = maximum_spanning_tree(linked, reference)
    f_mean = float(np.mean(intrinsics[:, :2]))
    R_cw = np.full((C, 3, 3), np.nan)
    t_cw = np.full((C, 3), np.nan)
    R_cw[reference], t_cw[reference] = np.eye(3), np.zeros(3)
    for parent, child in tree:
        both = complete[parent] & complete[child]
        p1 = xy[parent, both].reshape(-1, 2)
        p2 = xy[child, both].reshape(-1, 2)
        E, mask = cv2.findEssentialMat(p1, p2, np.eye(3), method=cv2.RANSAC, prob=0.9999, threshold=2.0 / f_mean)
        if E is None or E.shape != (3, 3):
            raise WandError(f"cameras {camera_names[parent]!r} and {camera_names[child]!r}: the wand points they share "
                            f"({both.sum()} frames) do not determine their relative pose; wave the wand through more "
                            f"of the volume both cameras see (not only along one line or in one plane)")
        _, R, t, _ = cv2.recoverPose(E, p1, p2, np.eye(3), mask=mask)
        t = t.ravel()
        # Scale: the baseline is unit length; the wand distances say how long it really is.
        P = np.stack([np.hstack([np.eye(3), np.zeros((3, 1))]), np.hstack([R, t[:, None]])])
        pts = triangulate_dlt(P, np.stack([p1, p2])).reshape(-1, 3, 3)
        ratio = spec.distances[None, :] / wand_distances(pts)
        scale = float(np.nanmedian(ratio))
        if not np.isfinite(scale) or scale <= 0:
            raise WandError(f"cameras {camera_names[parent]!r} and {camera_names[child]!r}: could not scale the wand points")
        R_cw[child], t_cw[child] = compose_poses(R, t * scale, R_cw[parent], t_cw[parent])
    return R_cw, t_cw, tree


def label_collinear_wand(blobs_px: np.ndarray, spec: WandSpec, max_line_residual_px: float = 3.0) -> np.ndarray:
    """Label unordered blobs of a collinear wand as markers 0, 1, 2.

    The middle blob is the one between the other two; marker 0 is the end nearer to it
    when ``d01 < d12`` (the farther one otherwise). Perspective changes the ratio of
    the two segments a little, so the wand's two segments must differ clearly in length
    (by 25 % or more).

    Parameters
    ----------
    blobs_px : (C, F, 3, 2) float
        The three wand blobs per camera and frame, in any order; NaN rows where a camera
        did not see three blobs.
    spec : WandSpec
        Must be collinear (``d02 = d01 + d12``).
    max_line_residual_px : float
        Frames whose middle blob is farther than this from the line through the ends are
        left out (NaN): probably not the wand.

    Returns
    -------
    (C, F, 3, 2) float
        Labelled markers; NaN where the frame could not be labelled.
    """
    d01, d12, d02 = spec.distances_m
    if abs(d01 + d12 - d02) > 1e-6 * d02:
        raise ValueError(f"label_collinear_wand needs a collinear wand (d02 = d01 + d12), got distances {spec.distances_m}")
    ratio = d01 / d12
    if 0.8 < ratio < 1.25:
        raise ValueError(f"wand segments {d01} m and {d12} m are too alike to tell the ends apart; "
                         f"use a wand whose two segments differ by at least 25 %")
    b = np.asarray(blobs_px, dtype=np.float64)
    ok = np.isfinite(b).all(axis=(2, 3))
    dist = np.linalg.norm(b[:, :, :, None, :] - b[:, :, None, :, :], axis=4)  # (C, F, 3, 3)
    mid = np.argmin(np.nan_to_num(dist.sum(axis=3), nan=np.inf), axis=2)  # (C, F)
    ends = np.array([[1, 2], [0, 2], [0, 1]])[mid]  # (C, F, 2)
    take = lambda idx: np.take_along_axis(b, idx[..., None, None].repeat(2, axis=3), axis=2)[:, :, 0]  # noqa: E731
    pm, pa, pb = take(mid), take(ends[..., 0]), take(ends[..., 1])
    da, db = np.linalg.norm(pa - pm, axis=2), np.linalg.norm(pb - pm, axis=2)
    a_is_zero = (da < db) == (ratio < 1.0)
    p0 = np.where(a_is_zero[..., None], pa, pb)
    p2 = np.where(a_is_zero[..., None], pb, pa)
    line = p2 - p0
    cross = line[..., 0] * (pm - p0)[..., 1] - line[..., 1] * (pm - p0)[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        residual = np.abs(cross) / np.linalg.norm(line, axis=2)
    good = ok & (residual <= max_line_residual_px)
    out = np.stack([p0, pm, p2], axis=2)
    out[~good] = np.nan
    return out
