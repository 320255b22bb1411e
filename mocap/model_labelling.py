"""Model-based labelling of unlabelled 3D points, from any frame, through gaps.

Stage header
------------
inputs
    Per frame, the unlabelled 3D points of :func:`mocap.correspondence.reconstruct_unlabelled`,
    the frame times, and a *marker model* of the subject: either the subject's skeleton with its
    markers (:class:`SkeletonMarkerModel`, a :class:`~mocap.skeleton.SkeletonSolver`), or rigid
    marker clusters learned from a labelled trial (:class:`ClusterMarkerModel`) for captures
    without a skeleton.
outputs
    :class:`PointLabels`: for every frame and label, the index of the point carrying it (-1 where
    none), and the model's estimate of every marker.

This is what commercial systems call model-based auto-labelling. No first-frame pose is assumed:

1. **Start where the fit is confident.** A global search (the model's ``initialise``)
   is tried on a few frames spread over the take; the frame whose fit explains the most points
   becomes the start, and labelling runs forward and backward from it.
2. **Track.** Each frame, the model predicts every marker (the previous pose, or each marker's
   constant-velocity extrapolation where it was seen in the last two frames); points are
   assigned to labels by the Hungarian method within a wide gate; the model is refitted to the
   assigned points and the assignment repeated within a tight gate around the refitted model.
   One point carries at most one label, a label at most one point.
3. **Gaps.** A marker that was not seen is still predicted by the model (its segment's other
   markers, or the skeleton): it is labelled again as soon as a point appears within the tight
   gate, after a gap of any length. A neighbour 2 cm away keeps its own label, because its own
   prediction is nearer.
4. **Veto.** A point assigned to a label but farther than the tight gate from the refitted model
   loses the label (a point the model cannot explain is left unlabelled rather than trusted).
5. **Loss.** When a frame's fit explains too few points the global search runs again there, and
   the better of the two is kept.
"""

from __future__ import annotations

import functools
import time

from dataclasses import dataclass
from typing import Protocol, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from mocap.correspondence import UnlabelledPoints
from mocap.errors import require, require_finite

__all__ = [
    "ModelLabellingParams",
    "PointLabels",
    "MarkerModel",
    "assign_to_predictions",
    "constant_velocity",
    "kabsch",
    "label_points",
    "match_rigid_cluster",
    "point_positions",
]


@dataclass(frozen=True)
class ModelLabellingParams:
    """Settings of :func:`label_points`.

    Attributes
    ----------
    wide_gate_m : float
        Assignment gate around the predictions before the refit.
    tight_gate_m : float
        Gate around the refitted model: a label keeps a point only this close to the model.
    init_frames : int
        Number of frames, spread over the take, on which the global search is tried first to
        choose the start.
    init_budget : int
        If none of those gives a fit that explains every point, the search goes on, coarse to
        fine (:func:`start_candidates`), over at most this many frames in all.
    min_explained : float
        A tracked frame whose refit labels fewer than this fraction of the labels that the
        previous frame had (or of the points present) triggers the global search again.
    """

    wide_gate_m: float = 0.08
    tight_gate_m: float = 0.02
    init_frames: int = 5
    init_budget: int = 24
    min_explained: float = 0.8

    def __post_init__(self) -> None:
        require_finite(self, ("wide_gate_m", "tight_gate_m", "min_explained"))
        require(self.tight_gate_m <= self.wide_gate_m, self, "tight_gate_m", f"must not exceed wide_gate_m ({self.wide_gate_m})")
        require(int(self.init_frames) >= 1, self, "init_frames", "must be >= 1")
        require(int(self.init_budget) >= int(self.init_frames), self, "init_budget", f"must be >= init_frames ({self.init_frames})")


@dataclass
class PointLabels:
    """Result of :func:`label_points`.

    Attributes
    ----------
    labels : list[str], length M
    point_index : (F, M) int
        Index into each frame's :class:`UnlabelledPoints` of the point carrying each label,
        -1 where none.
    predicted : (F, M, 3) float
        The model's estimate of every marker (metres), NaN where the model was not fitted.
    start_frame : int
        Frame where labelling started (the most confident global fit).
    reinitialisations : int
        Frames where the global search ran again after a loss.
    start_search_ms : float
        Time spent choosing the start (step 1), once per take; a long take does not pay it
        again per frame.
    """

    labels: list[str]
    point_index: np.ndarray
    predicted: np.ndarray
    start_frame: int
    reinitialisations: int
    start_search_ms: float = 0.0


# --------------------------------------------------------------------------- assignment
def assign_to_predictions(pred: np.ndarray, points: np.ndarray, gate_m: float | np.ndarray,
                          allowed: np.ndarray | None = None) -> np.ndarray:
    """Hungarian assignment of predicted markers ``(M, 3)`` to points ``(N, 3)`` within gates.

    ``gate_m`` is one radius or one per label ``(M,)``. ``allowed`` ``(N,)`` bool restricts the
    points that may be taken. Leaving a label unassigned costs its ``gate^2``, so a label takes a
    point only when that beats leaving it free. Returns ``(M,)`` point index or -1.
    """
    M = len(pred)
    out = np.full(M, -1, dtype=np.intp)
    ok = np.isfinite(pred).all(axis=1)
    cols = np.arange(len(points)) if allowed is None else np.flatnonzero(allowed)
    if len(cols) == 0 or not ok.any():
        return out
    g2 = np.broadcast_to(np.asarray(gate_m, dtype=np.float64), (M,))[ok] ** 2
    d2 = ((pred[ok, None, :] - points[None, cols, :]) ** 2).sum(axis=2)
    big = 1e6 * max(float(g2.max()), 1e-12)
    d2 = np.where(d2 < g2[:, None], d2, big)
    m = int(ok.sum())
    # Only labels with some point inside their gate need the solver.
    live = (d2 < big).any(axis=1)
    if not live.any():
        return out
    d2 = d2[live]
    live_cols = (d2 < big).any(axis=0)
    d2 = d2[:, live_cols]
    k = d2.shape[0]
    dummy = np.full((k, k), big)
    np.fill_diagonal(dummy, g2[live])
    rows, cc = linear_sum_assignment(np.hstack([d2, dummy]))
    real = cc < d2.shape[1]
    sub = np.full(m, -1, dtype=np.intp)
    live_idx = np.flatnonzero(live)
    sub[live_idx[rows[real]]] = cols[live_cols][cc[real]]
    out[ok] = sub
    return out


def _det3(A: np.ndarray) -> float:
    """Determinant of a 3 x 3 matrix by cofactors."""
    return float(A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
                 + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]))


def kabsch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation ``R`` and translation ``t`` with ``dst ~ src @ R.T + t`` (least squares, proper)."""
    # sum / n is what ndarray.mean computes, without its dispatch; the labelling calls this
    # some 10^5 times a take.
    cs, cd = src.sum(axis=0) / len(src), dst.sum(axis=0) / len(dst)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    V = np.ascontiguousarray(Vt.T)
    # V @ diag(1, 1, d) as a column scaling (exact: d is +-1), without building the diagonal.
    # Only the sign of det(V U^T) = det(V) det(U) is needed, and both are +-1 (orthogonal), so
    # the 3 x 3 cofactor expansion gives the sign LAPACK's LU would, at a fraction of the cost.
    V[:, 2] *= np.sign(_det3(V) * _det3(U))
    R = V @ U.T
    return R, cd - R @ cs


@functools.lru_cache(maxsize=512)
def _cluster_bases(local_bytes: bytes, shape: tuple[int, ...], max_bases: int) -> tuple[np.ndarray, list[tuple[int, int, int]]]:
    """A cluster's inter-marker distances ``(k, k)`` and its base triangles: the triples spanning
    the largest areas (most discriminative); several, so that a cluster with one base marker
    hidden is still found. Cached by the cluster's shape: a take matches the same few clusters
    thousands of times (the areas alone were 15 % of the labelling of a static take)."""
    local = np.frombuffer(local_bytes, dtype=np.float64).reshape(shape)
    k = len(local)
    Dm = np.linalg.norm(local[:, None] - local[None], axis=2)
    Dm.flags.writeable = False
    triples = [(a, b, c) for a in range(k) for b in range(a + 1, k) for c in range(b + 1, k)]
    areas = [np.linalg.norm(np.cross(local[b] - local[a], local[c] - local[a])) for a, b, c in triples]
    return Dm, [triples[i] for i in np.argsort(areas)[::-1][:max_bases]]


def match_rigid_cluster(local: np.ndarray, points: np.ndarray, tol_m: float, max_matches: int = 8,
                        allowed: np.ndarray | None = None, max_bases: int = 4) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, float]]:
    """Places where a rigid marker cluster appears among unlabelled points.

    Parameters
    ----------
    local : (k, 3) float
        The cluster's markers in its own frame (k >= 3), metres.
    points : (N, 3) float
        Unlabelled points, metres.
    tol_m : float
        Tolerance on inter-marker distances and on the fitted cluster's residual.

    Returns
    -------
    list of (R, t, index, rms_m)
        Cluster pose (``world = local @ R.T + t``), the point index of each cluster marker (-1
        where not found), and the RMS residual; best first (most markers, then lowest RMS).
    """
    k = len(local)
    if k < 3 or len(points) < 3:
        return []
    pts = points if allowed is None else np.where(allowed[:, None], points, np.nan)
    local = np.asarray(local, dtype=np.float64)
    Dm, bases = _cluster_bases(local.tobytes(), local.shape, max_bases)
    Dp = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    targets = np.nan_to_num(pts, nan=1e9)
    found = []
    tried: set[bytes] = set()  # assignments already refitted: the same assignment refits the same
    for a, b, c in bases:
        with np.errstate(invalid="ignore"):
            ii, jj = np.nonzero(np.abs(Dp - Dm[a, b]) < tol_m)
            # third points for every pair at once, in the order the pairs and points come
            third = (np.abs(Dp[jj] - Dm[b, c]) < tol_m) & (np.abs(Dp[ii] - Dm[a, c]) < tol_m)
        for p, kk in zip(*np.nonzero(third)):
            i, j = ii[p], jj[p]
            if kk == i or kk == j:
                continue
            R, t = kabsch(local[[a, b, c]], pts[[i, j, kk]])
            world = local @ R.T + t
            idx = assign_to_predictions(world, targets, tol_m)
            use = idx >= 0
            if use.sum() < 3 or idx.tobytes() in tried:
                continue
            tried.add(idx.tobytes())
            R, t = kabsch(local[use], pts[idx[use]])
            res = np.linalg.norm(local[use] @ R.T + t - pts[idx[use]], axis=1)
            if res.max() > tol_m:
                continue
            found.append((R, t, idx, float(np.sqrt(np.mean(res**2)))))
    found.sort(key=lambda f: (-int((f[2] >= 0).sum()), f[3]))
    unique: list = []
    for f in found:
        if all(not np.array_equal(f[2], u[2]) for u in unique):
            unique.append(f)
        if len(unique) >= max_matches:
            break
    return unique


# --------------------------------------------------------------------------- models
class MarkerModel(Protocol):
    """What :func:`label_points` needs of a subject model."""

    labels: list[str]

    def initialise(self, points: np.ndarray, trusted: np.ndarray) -> tuple[object, np.ndarray, float]:
        """Global search on one frame: ``(state, point index per label, score)``. Untrusted points
        (ambiguous two-view points) may only be taken within the tight gate of the final fit."""

    def track(self, points: np.ndarray, trusted: np.ndarray, state: object, previous: Sequence[np.ndarray],
              gates: tuple[float, float]) -> tuple[object, np.ndarray, float]:
        """One frame from a previous state: ``(state, point index per label, score)``. Untrusted
        points (ambiguous two-view points) may only be taken within the tight gate."""

    def markers(self, state: object) -> np.ndarray:
        """The model's marker positions ``(M, 3)`` for a state."""


def constant_velocity(model_pred: np.ndarray, previous: Sequence[np.ndarray]) -> np.ndarray:
    """Each marker's constant-velocity extrapolation where its last two positions are known,
    else the model's prediction. ``previous``: the last labelled positions ``(M, 3)``, newest last."""
    pred = model_pred.copy()
    if len(previous) >= 2:
        a, b = previous[-2], previous[-1]
        ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
        pred[ok] = 2.0 * b[ok] - a[ok]
    elif len(previous) == 1:
        b = previous[-1]
        ok = np.isfinite(b).all(axis=1) & ~np.isfinite(pred).all(axis=1)
        pred[ok] = b[ok]
    return pred


# --------------------------------------------------------------------------- sequence
def start_candidates(n_frames: int, first: int, budget: int) -> np.ndarray:
    """Frames to try the global search on, coarse to fine: ``first`` frames spread over the
    take, then the midpoints between the frames tried so far, and so on, ``budget`` frames at
    most (each once)."""
    if n_frames <= 0:
        return np.zeros(0, dtype=int)
    order: list[int] = []
    seen: set[int] = set()
    n = max(1, min(first, n_frames))
    while len(order) < min(budget, n_frames):
        for f in np.linspace(0, n_frames - 1, n).round().astype(int):
            if int(f) not in seen and len(order) < budget:
                seen.add(int(f))
                order.append(int(f))
        if n >= n_frames:
            break
        n = 2 * n - 1
    return np.array(order, dtype=int)


def label_points(frames: Sequence[UnlabelledPoints], model: MarkerModel, params: ModelLabellingParams | None = None) -> PointLabels:
    """Label every frame's unlabelled points with a marker model (see the module docstring)."""
    p = params or ModelLabellingParams()
    F, M = len(frames), len(model.labels)
    index = np.full((F, M), -1, dtype=np.intp)
    predicted = np.full((F, M, 3), np.nan)
    if F == 0:
        return PointLabels(list(model.labels), index, predicted, 0, 0)
    # 1. The start: the most confident global fit among a few frames spread over the take.
    trusted = [(fr.n_views >= 3) | ~fr.ambiguous for fr in frames]

    def init(f: int):
        if len(frames[f]) < 3:
            return None, np.full(M, -1, dtype=np.intp), 0.0
        return model.initialise(frames[f].xyz, trusted[f])

    t_start = time.perf_counter()
    counts = np.array([int(t.sum()) for t in trusted])
    best = (-1, None, None, -np.inf)
    for f in start_candidates(F, p.init_frames, p.init_budget):
        state, idx, score = init(int(f))
        if state is not None and score > best[3]:
            best = (int(f), state, idx, score)
        if state is not None and (idx >= 0).sum() >= min(M, counts[f]):
            # A fit that explains every point: no need to look further. Not "nearly every":
            # a fit one point short is often one with two similar clusters swapped (thigh and
            # shank markers, c3d_codamotion_walk: 10 of 16 such frames were wrong), while the
            # fits that explain every point were right on every frame there.
            break
    if best[1] is None:
        for f in np.argsort(-counts):  # every frame, most points first, until one fits
            state, idx, score = init(int(f))
            if state is not None:
                best = (int(f), state, idx, score)
                break
    start, state0, idx0, _ = best
    start_ms = (time.perf_counter() - t_start) * 1e3
    if state0 is None:
        return PointLabels(list(model.labels), index, predicted, 0, 0, start_ms)
    index[start] = idx0
    predicted[start] = model.markers(state0)
    reinit = 0
    # 2. Forward from the start; then backward from the frame after it, so that the start frame
    # itself is labelled again by tracking (a global fit can be wrong on a limb that tracking
    # has recovered one frame later).
    def run(f: int, direction: int, state, history: list[np.ndarray], last_count: int) -> tuple[int, object]:
        nonlocal reinit
        after = None
        while 0 <= f < F:
            pts = frames[f].xyz
            state_t, idx_t, score_t = model.track(pts, trusted[f], state, history[-2:], (p.wide_gate_m, p.tight_gate_m))
            n_t = int((idx_t >= 0).sum())
            if n_t < p.min_explained * min(last_count, len(pts)):
                state_i, idx_i, score_i = init(f)
                reinit += 1
                if state_i is not None and score_i > score_t:
                    state_t, idx_t, n_t = state_i, idx_i, int((idx_i >= 0).sum())
                    history = []
            index[f] = idx_t
            predicted[f] = model.markers(state_t)
            state = state_t
            history = (history + [point_positions(pts, idx_t)])[-2:]
            last_count = max(n_t, 1)
            if after is None:
                after = state_t
            f += direction
        return last_count, after

    n0 = int((idx0 >= 0).sum())
    _, next_state = run(start + 1, 1, state0, [point_positions(frames[start].xyz, idx0)], n0)
    if next_state is not None:
        back_history = [point_positions(frames[g].xyz, index[g]) for g in (start + 2, start + 1) if g < F]
        run(start, -1, next_state, back_history, max(int((index[start + 1] >= 0).sum()), 1))
    else:
        run(start - 1, -1, state0, [point_positions(frames[start].xyz, idx0)], n0)
    return PointLabels(list(model.labels), index, predicted, start, reinit, start_ms)


def point_positions(points: np.ndarray, idx: np.ndarray) -> np.ndarray:
    out = np.full((len(idx), 3), np.nan)
    ok = idx >= 0
    out[ok] = points[idx[ok]]
    return out
