"""Unlabelled 3D points from unlabelled blobs: multi-view correspondence by epipolar voting.

Stage header
------------
inputs
    One frame: per camera, the :class:`~mocap.types.Detections` (distorted pixels), and the
    :class:`~mocap.calibration.Calibration`.
outputs
    :class:`UnlabelledPoints`: ``(N, 3)`` points in metres, and for each the index of the
    detection it used in every camera (-1 where none), its view count and its residual.

How
---
1. Every detection is undistorted to normalised coordinates once.
2. For every camera pair ``(a, b)`` the symmetric point-to-epipolar-line distance of every
   detection pair is computed from the essential matrix ``E = [t_ab]x R_ab`` (in pixels of
   each camera); pairs within ``epipolar_px`` are candidates.
3. Each candidate is triangulated from its two views (batched DLT), must lie in front of
   both cameras, and collects *support*: in every other camera, the nearest detection to
   its projection within ``support_px`` (brute force: a few dozen detections per camera).
4. Candidates are taken greedily, most views agreeing within ``rank_residual_px`` first
   (less their residual in those units), then smallest epipolar distance. A candidate is
   accepted when its two base detections are still free; its free support views join it,
   and the point is triangulated again from all its views with worst-view rejection
   (:func:`mocap.triangulation.triangulate_normalized`). Each detection serves at most one
   point, so a marker seen by many cameras gives one point, not one per pair, and the
   ghosts of wrong pairings (which rarely gather support) come last and find their
   detections taken.

A point seen by two cameras only is kept but flagged ``ambiguous`` when either of its
detections had more than one epipolar candidate in the other camera: the labeller trusts
such points only close to a prediction.

This is hand-written because no maintained library does multi-view correspondence of
unlabelled point sets (OpenCV and aniposelib triangulate points that are already matched).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from mocap.calibration import Calibration
from mocap.errors import require_finite
from mocap.triangulation import pixels_to_normalized, triangulate_normalized
from mocap.types import Detections

__all__ = ["CorrespondenceParams", "UnlabelledPoints", "reconstruct_unlabelled", "normalised_detections"]


@dataclass(frozen=True)
class CorrespondenceParams:
    """Settings of :func:`reconstruct_unlabelled`.

    Attributes
    ----------
    epipolar_px : float
        Largest point-to-epipolar-line distance of a candidate pair, pixels.
    support_px : float
        Largest distance of a supporting detection from the candidate's projection, pixels.
    max_residual_px : float
        Worst-view rejection threshold of the final triangulation, pixels.
    min_depth_m : float
        A point must lie at least this far in front of each camera that sees it.
    rank_residual_px : float
        Candidates are taken in the order of their views that agree within this many pixels,
        less their mean residual in these units.
    """

    epipolar_px: float = 2.5
    support_px: float = 3.0
    max_residual_px: float = 2.5
    min_depth_m: float = 0.2
    rank_residual_px: float = 1.0

    def __post_init__(self) -> None:
        require_finite(self, ("epipolar_px", "support_px", "max_residual_px", "min_depth_m", "rank_residual_px"))


@dataclass
class UnlabelledPoints:
    """Unlabelled 3D points of one frame.

    Attributes
    ----------
    xyz : (N, 3) float
        Metres, world frame.
    detection_index : (N, C) int
        Per camera, the index of the detection each point used, -1 where none.
    n_views : (N,) int
    residual_px : (N,) float
        Mean reprojection residual over the views used (undistorted pixels).
    ambiguous : (N,) bool
        Two-view points whose pairing was not unique.
    """

    xyz: np.ndarray
    detection_index: np.ndarray
    n_views: np.ndarray
    residual_px: np.ndarray
    ambiguous: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    def __len__(self) -> int:
        return len(self.xyz)

    @classmethod
    def empty(cls, n_cameras: int) -> "UnlabelledPoints":
        return cls(np.zeros((0, 3)), np.zeros((0, n_cameras), np.intp), np.zeros(0, np.intp), np.zeros(0), np.zeros(0, bool))


def normalised_detections(detections: Sequence[Detections], calibration: Calibration) -> list[np.ndarray]:
    """Per camera, the detections in undistorted normalised coordinates ``(n_c, 2)``."""
    return [pixels_to_normalized(cam, d.xy) if len(d) else np.zeros((0, 2)) for d, cam in zip(detections, calibration)]


def _pair_geometry(calibration: Calibration) -> dict[tuple[int, int], np.ndarray]:
    """Essential matrices ``E_ab`` with ``x_b^T E_ab x_a = 0`` for every camera pair ``a < b``."""
    out = {}
    for a, ca in enumerate(calibration):
        for b in range(a + 1, len(calibration)):
            cb = calibration[b]
            R = cb.R @ ca.R.T
            t = cb.t - R @ ca.t
            tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
            out[(a, b)] = tx @ R
    return out


def _two_view_points(xa: np.ndarray, xb: np.ndarray, Pa: np.ndarray, Pb: np.ndarray) -> np.ndarray:
    """Batched linear triangulation of ``K`` normalised pairs ``(K, 2)`` -> ``(K, 3)``, the
    cameras ``[R|t]`` either ``(3, 4)`` for all or ``(K, 3, 4)`` one per pair."""
    rows = np.stack([
        xa[:, 0:1] * Pa[..., 2, :] - Pa[..., 0, :], xa[:, 1:2] * Pa[..., 2, :] - Pa[..., 1, :],
        xb[:, 0:1] * Pb[..., 2, :] - Pb[..., 0, :], xb[:, 1:2] * Pb[..., 2, :] - Pb[..., 1, :],
    ], axis=1)                                                    # (K, 4, 4)
    M = np.matmul(rows.transpose(0, 2, 1), rows)
    lhs = M[:, :3, :3] + 1e-12 * np.eye(3)
    return np.linalg.solve(lhs, -M[:, :3, 3:4])[..., 0]


def reconstruct_unlabelled(
    detections: Sequence[Detections],
    calibration: Calibration,
    params: CorrespondenceParams | None = None,
    normalised: list[np.ndarray] | None = None,
) -> UnlabelledPoints:
    """Unlabelled 3D points of one frame from every camera's unlabelled detections.

    Parameters
    ----------
    detections : C Detections, in calibration order
    calibration : Calibration
    params : CorrespondenceParams, optional
    normalised : per camera ``(n_c, 2)`` undistorted normalised detections, optional
        (computed when not given).

    Returns
    -------
    UnlabelledPoints
    """
    p = params or CorrespondenceParams()
    C = len(calibration)
    xs = normalised if normalised is not None else normalised_detections(detections, calibration)
    focal = calibration.mean_focal_px
    cand = _pair_candidates(xs, calibration, focal, p)
    if cand is None:
        return UnlabelledPoints.empty(C)
    ca, cb, ia, ib, dist, amb = cand
    X = _candidate_points(xs, calibration, ca, cb, ia, ib)
    views, depth_ok = _supporting_views(X, xs, calibration, focal, ca, cb, ia, ib, p)
    # Rank each candidate by the views that agree within rank_residual_px (worst-view
    # rejection), less its residual in units of rank_residual_px. Where markers lie a few
    # pixels apart, support gathered from a neighbour's detections makes a ghost between two
    # markers with more views (each a pixel or so off) than either true point (a tenth of a
    # pixel); counting views alone takes the ghost first and both markers are lost. The
    # accepted point keeps all its views: its own triangulation rejects at max_residual_px.
    tight = triangulate_normalized(_observations(xs, views), calibration, max_residual_px=p.rank_residual_px,
                                   refine=False)
    agreeing = np.where(np.isfinite(tight.residual_px), tight.n_views, 1)
    score = agreeing - np.nan_to_num(tight.residual_px, nan=0.0) / p.rank_residual_px
    order = np.lexsort((dist, -score))
    order = order[depth_ok[order]]
    accepted, accepted_amb = _accept_in_order(order, xs, views, ca, cb, ia, ib, amb)
    if not accepted:
        return UnlabelledPoints.empty(C)
    det_index = np.array(accepted, dtype=np.intp)                # (N, C)
    tri = triangulate_normalized(_observations(xs, det_index), calibration, max_residual_px=p.max_residual_px)
    keep = np.isfinite(tri.points).all(axis=1)
    det_index = np.where(tri.used.T, det_index, -1)
    return UnlabelledPoints(
        xyz=tri.points[keep],
        detection_index=det_index[keep],
        n_views=tri.n_views[keep].astype(np.intp),
        residual_px=tri.residual_px[keep],
        ambiguous=np.array(accepted_amb, bool)[keep],
    )


def _pair_candidates(xs: list[np.ndarray], calibration: Calibration, focal: np.ndarray, p: CorrespondenceParams):
    """Every pair of detections of two cameras within ``epipolar_px`` of each other's
    epipolar lines: ``(ca, cb, ia, ib, dist, amb)`` (cameras, detection indices, the larger
    epipolar distance in pixels, whether either detection has other candidates in that
    pair of cameras), or None when there is none."""
    cand_a, cand_b, cand_ia, cand_ib, cand_d, cand_amb = [], [], [], [], [], []
    hs = [np.column_stack([x, np.ones(len(x))]) for x in xs]   # homogeneous, (n_c, 3)
    for (a, b), E in _pair_geometry(calibration).items():
        if len(xs[a]) == 0 or len(xs[b]) == 0:
            continue
        ha, hb = hs[a], hs[b]
        lb = ha @ E.T                                           # epipolar lines in b, (na, 3)
        la = hb @ E                                             # epipolar lines in a, (nb, 3)
        alg = hb @ lb.T                                         # (nb, na): x_b^T E x_a
        db = np.abs(alg) / np.hypot(lb[:, 0], lb[:, 1])[None, :] * focal[b]
        da = np.abs(alg) / np.hypot(la[:, 0], la[:, 1])[:, None] * focal[a]
        d = np.maximum(da, db)                                   # (nb, na) pixels
        ib, ia = np.nonzero(d < p.epipolar_px)
        if ia.size == 0:
            continue
        n_in_b = np.bincount(ia, minlength=len(xs[a]))           # candidates of each a-detection
        n_in_a = np.bincount(ib, minlength=len(xs[b]))
        cand_a.append(np.full(ia.size, a))
        cand_b.append(np.full(ia.size, b))
        cand_ia.append(ia)
        cand_ib.append(ib)
        cand_d.append(d[ib, ia])
        cand_amb.append((n_in_b[ia] > 1) | (n_in_a[ib] > 1))
    if not cand_a:
        return None
    return (np.concatenate(cand_a), np.concatenate(cand_b), np.concatenate(cand_ia), np.concatenate(cand_ib),
            np.concatenate(cand_d), np.concatenate(cand_amb))


def _candidate_points(xs: list[np.ndarray], calibration: Calibration, ca: np.ndarray, cb: np.ndarray,
                      ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """``(K, 3)`` two-view points of the ``K`` candidates, every camera pair in one batch
    (each candidate's system is solved on its own, to the same bits as pair by pair)."""
    Ps = np.stack([np.hstack([c.R, c.t[:, None]]) for c in calibration])
    every, start = np.concatenate(xs), _offsets(xs)
    return _two_view_points(every[start[ca] + ia], every[start[cb] + ib], Ps[ca], Ps[cb])


def _offsets(xs: list[np.ndarray]) -> np.ndarray:
    """Where each camera's detections start in their concatenation."""
    return np.concatenate([[0], np.cumsum([len(x) for x in xs])[:-1]]).astype(np.intp)


def _supporting_views(X: np.ndarray, xs: list[np.ndarray], calibration: Calibration, focal: np.ndarray,
                      ca: np.ndarray, cb: np.ndarray, ia: np.ndarray, ib: np.ndarray,
                      p: CorrespondenceParams) -> tuple[np.ndarray, np.ndarray]:
    """``views (K, C)``: each candidate's detection in every camera (its pair's two, and the
    nearest within ``support_px`` of its projection in the others; -1: none), and
    ``depth_ok (K,)``: the point lies in front of its pair's cameras."""
    K, C = len(X), len(calibration)
    views = np.full((K, C), -1, dtype=np.intp)
    views[np.arange(K), ca] = ia
    views[np.arange(K), cb] = ib
    depth_ok = np.ones(K, bool)
    for c, cam in enumerate(calibration):
        z = X @ cam.R[2] + cam.t[2]
        base = (ca == c) | (cb == c)
        depth_ok &= ~base | (z > p.min_depth_m)
        if len(xs[c]) == 0:
            continue
        other = ~base & (z > p.min_depth_m)
        if not other.any():
            continue
        pc = X[other] @ cam.R.T + cam.t
        uv = pc[:, :2] / pc[:, 2:3]
        ii, hit = _nearest_within(uv, xs[c], p.support_px / focal[c])
        rows = np.flatnonzero(other)[hit]
        views[rows, c] = ii[hit]
    return views, depth_ok


def _nearest_within(q: np.ndarray, x: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Index ``(k,)`` of the nearest of the points ``x (n, 2)`` to each ``q (k, 2)``, and whether
    it lies closer than ``r``: what ``cKDTree(x).query(q, distance_upper_bound=r)`` answers
    (the same squared distances, ``dx * dx + dy * dy``, and the same strict test against
    ``r * r``), by brute force: a frame's few hundred projections against a camera's few dozen
    detections cost a tenth of building and querying the tree."""
    dx = q[:, 0:1] - x[:, 0]
    dy = q[:, 1:2] - x[:, 1]
    d2 = dx * dx + dy * dy                                        # (k, n)
    nearest = d2.argmin(axis=1)
    return nearest, d2[np.arange(len(q)), nearest] < r * r


def _observations(xs: list[np.ndarray], index: np.ndarray) -> np.ndarray:
    """``(C, N, 2)`` normalised detections at ``index (N, C)`` (NaN where -1)."""
    C, N = len(xs), len(index)
    obs = np.full((C, N, 2), np.nan)
    for c in range(C):
        ok = index[:, c] >= 0
        obs[c, ok] = xs[c][index[ok, c]]
    return obs


def _accept_in_order(order: np.ndarray, xs: list[np.ndarray], views: np.ndarray, ca: np.ndarray, cb: np.ndarray,
                     ia: np.ndarray, ib: np.ndarray, amb: np.ndarray) -> tuple[list[np.ndarray], list[bool]]:
    """Candidates taken greedily in ``order``, each detection used once: their views (a
    view already used is dropped) and whether each is an ambiguous two-view point."""
    C = len(xs)
    used = [[False] * len(x) for x in xs]
    accepted: list[np.ndarray] = []
    accepted_amb: list[bool] = []
    # Python lists: the loop reads single elements, which numpy scalars make slow.
    ca_l, cb_l, ia_l, ib_l, amb_l, views_l = ca.tolist(), cb.tolist(), ia.tolist(), ib.tolist(), amb.tolist(), views.tolist()
    for k in order.tolist():
        a, b = ca_l[k], cb_l[k]
        if used[a][ia_l[k]] or used[b][ib_l[k]]:
            continue
        v = list(views_l[k])
        for c in range(C):
            if v[c] >= 0 and used[c][v[c]]:
                v[c] = -1
        for c in range(C):
            if v[c] >= 0:
                used[c][v[c]] = True
        accepted.append(np.array(v, dtype=views.dtype))
        accepted_amb.append(bool(amb_l[k]) and sum(1 for x in v if x >= 0) == 2)
    return accepted, accepted_amb
