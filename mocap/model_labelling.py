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

1. **Start where the fit is confident.** A global search (:meth:`SkeletonMarkerModel.initialise`)
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

from dataclasses import dataclass
from typing import Protocol, Sequence

import numpy as np
import pinocchio as pin
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation
from scipy.spatial import cKDTree

from mocap.correspondence import UnlabelledPoints
from mocap.skeleton import SkeletonSolver

__all__ = [
    "ModelLabellingParams",
    "PointLabels",
    "SkeletonMarkerModel",
    "ClusterMarkerModel",
    "assign_to_predictions",
    "label_points",
    "match_rigid_cluster",
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
        Number of frames, spread over the take, on which the global search is tried to
        choose the start.
    min_explained : float
        A tracked frame whose refit labels fewer than this fraction of the labels that the
        previous frame had (or of the points present) triggers the global search again.
    """

    wide_gate_m: float = 0.08
    tight_gate_m: float = 0.02
    init_frames: int = 5
    min_explained: float = 0.8

    def __post_init__(self) -> None:
        for name in ("wide_gate_m", "tight_gate_m", "min_explained"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"ModelLabellingParams.{name}={v!r}: must be a finite number > 0")
        if self.tight_gate_m > self.wide_gate_m:
            raise ValueError("ModelLabellingParams: tight_gate_m must not exceed wide_gate_m")
        if int(self.init_frames) < 1:
            raise ValueError(f"ModelLabellingParams.init_frames={self.init_frames!r}: must be >= 1")


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
    """

    labels: list[str]
    point_index: np.ndarray
    predicted: np.ndarray
    start_frame: int
    reinitialisations: int


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


def _kabsch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation ``R`` and translation ``t`` with ``dst ~ src @ R.T + t`` (least squares, proper)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cd - R @ cs


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
    Dm = np.linalg.norm(local[:, None] - local[None], axis=2)
    # Base triangles: the triples spanning the largest areas (most discriminative); several, so
    # that a cluster with one base marker hidden is still found.
    triples = [(a, b, c) for a in range(k) for b in range(a + 1, k) for c in range(b + 1, k)]
    areas = [np.linalg.norm(np.cross(local[b] - local[a], local[c] - local[a])) for a, b, c in triples]
    bases = [triples[i] for i in np.argsort(areas)[::-1][:max_bases]]
    Dp = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    found = []
    for a, b, c in bases:
        with np.errstate(invalid="ignore"):
            ii, jj = np.nonzero(np.abs(Dp - Dm[a, b]) < tol_m)
        for i, j in zip(ii, jj):
            with np.errstate(invalid="ignore"):
                ks = np.flatnonzero((np.abs(Dp[j] - Dm[b, c]) < tol_m) & (np.abs(Dp[i] - Dm[a, c]) < tol_m))
            for kk in ks:
                if kk == i or kk == j:
                    continue
                R, t = _kabsch(local[[a, b, c]], pts[[i, j, kk]])
                world = local @ R.T + t
                idx = assign_to_predictions(world, np.nan_to_num(pts, nan=1e9), tol_m)
                use = idx >= 0
                if use.sum() < 3:
                    continue
                R, t = _kabsch(local[use], pts[idx[use]])
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


class SkeletonMarkerModel:
    """The subject's skeleton with its markers (Pinocchio), as a labelling model.

    The global search places the root by matching the pelvis's (else the thorax's) rigid
    marker cluster among the points, then sets every body's hinges from the root outwards by a
    grid search scored on unlabelled points (each model marker's capped distance to its nearest
    point; a child body's markers must lie at their fixed distance from the child's joint
    centre), then alternates Hungarian assignment and inverse kinematics with shrinking gates.
    """

    def __init__(self, solver: SkeletonSolver, cluster_tol_m: float = 0.012, grid_gate_m: float = 0.08) -> None:
        self.solver = solver
        self.labels = list(solver.marker_labels)
        self.cluster_tol_m = cluster_tol_m
        self.grid_gate_m = grid_gate_m
        self.max_roots = 3
        cs = solver._cold
        self._tables = cs
        n_b = len(cs.parent)
        self._hinges = len(solver.tree.hinge_names)
        q0 = solver.neutral()
        p0 = solver.marker_positions(q0)
        # Rigid clusters: bodies with >= 3 markers, root body first.
        self._clusters: list[tuple[int, np.ndarray]] = []
        for b in range(n_b):
            own = np.flatnonzero(cs.own_markers[b])
            if len(own) >= 3:
                self._clusters.append((b, own))
        self._p0 = p0

    # -------------------------------------------------------------- kinematics
    # A state is ``(q, v)`` concatenated: the configuration (nq) and its change over the last
    # frame as a tangent vector (nv), for a constant-velocity prediction of the next frame.
    def markers(self, state: np.ndarray) -> np.ndarray:
        return self.solver.marker_positions(state[: self.solver.nq])

    def _state(self, q: np.ndarray, q_prev: np.ndarray | None = None) -> np.ndarray:
        v = np.zeros(self.solver.model.nv) if q_prev is None else pin.difference(self.solver.model, q_prev, q)
        return np.concatenate([q, v])

    def _fit(self, q0: np.ndarray, obs: np.ndarray, ok: np.ndarray, iterations: int, prior: np.ndarray | None = None) -> tuple[np.ndarray, float]:
        if ok.sum() < 3:
            return q0, np.inf
        prior = np.zeros(self._hinges) if prior is None else prior
        q, rms, _, _ = self.solver._solve_frame(obs, ok, q0, prior, iterations)
        return q, rms

    def _refine(self, q: np.ndarray, points: np.ndarray, gates: Sequence[float], iterations: int,
                prior: np.ndarray | None = None, pred: np.ndarray | None = None,
                trusted: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        idx = np.full(len(self.labels), -1, dtype=np.intp)
        for k, g in enumerate(gates):
            X = pred if (k == 0 and pred is not None) else self.markers(q)
            idx = assign_to_predictions(X, points, g, allowed=trusted)
            ok = idx >= 0
            obs = np.full((len(self.labels), 3), np.nan)
            obs[ok] = points[idx[ok]]
            q, _ = self._fit(q, obs, ok, iterations, prior)
        X = self.markers(q)
        idx = assign_to_predictions(X, points, gates[-1])
        return q, idx

    # -------------------------------------------------------------- global search
    def _root_candidates(self, points: np.ndarray) -> list[np.ndarray]:
        """Root configurations (neutral hinges) from rigid-cluster matches, best first."""
        out: list[np.ndarray] = []
        for b, own in self._clusters[:3]:
            # Cluster markers at the neutral pose (root joint at the identity): a match (R, t)
            # moves the whole neutral model, so the root joint's pose is (R, t) itself.
            for R, t, idx, _ in match_rigid_cluster(self._p0[own], points, self.cluster_tol_m, max_matches=6):
                q = self.solver.neutral()
                q[:3] = t
                q[3:7] = pin.Quaternion(R).coeffs()  # x y z w
                out.append(q)
        return out

    def _capped(self, pred: np.ndarray, tree: cKDTree) -> np.ndarray:
        """Sum over the last-but-one axis of each predicted marker's capped squared distance to
        its nearest point: ``pred (..., k, 3)`` -> ``(...)``."""
        d, _ = tree.query(pred.reshape(-1, 3))
        return (np.minimum(d / self.grid_gate_m, 1.0) ** 2).reshape(pred.shape[:-1]).sum(axis=-1)

    def _shell(self, centre: np.ndarray, radius: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Capped squared distance of the nearest point to each sphere ``centre (G, k, 3)`` of
        ``radius (k,)``, summed over ``k`` -> ``(G,)``."""
        dist = np.linalg.norm(centre[:, :, None, :] - points[None, None], axis=3)        # (G, k, N)
        shell = np.abs(dist - radius[None, :, None]).min(axis=2)
        return (np.minimum(shell / self.grid_gate_m, 1.0) ** 2).sum(axis=1)

    def _rotations(self, b: int, values: np.ndarray) -> np.ndarray:
        """Rotations ``(G, 3, 3)`` of body ``b`` relative to its rest frame for hinge values ``(G, h)``."""
        tree = self.solver.tree
        rot = Rotation.identity(len(values))
        for k, h in enumerate(self._tables.hinge_slice[b]):  # parent-to-child order: R = R_1 R_2 R_3
            rot = rot * Rotation.from_rotvec(values[:, k : k + 1] * tree.hinge_axes[h])
        return rot.as_matrix()

    def _pair_cost(self, b: int, c: int, R_p: np.ndarray, t_b: np.ndarray, vb: np.ndarray, vc: np.ndarray,
                   tree: cKDTree) -> np.ndarray:
        """Capped nearest-point cost ``(Gb, Gc)`` of the markers of body ``b`` and its child ``c``
        for hinge values ``vb (Gb, 3)`` and ``vc (Gc, 1)``."""
        cs = self._tables
        R_b = R_p[None] @ self._rotations(b, vb)                                      # (Gb, 3, 3)
        t_c = t_b + R_b @ cs.rest_t[c]                                                 # (Gb, 3)
        R_c = (R_b @ cs.rest_R[c])[:, None] @ self._rotations(c, vc)[None]             # (Gb, Gc, 3, 3)
        cost = np.zeros((len(vb), len(vc)))
        own = cs.own_markers[b]
        if own.any():
            cost += self._capped(np.einsum("gij,kj->gki", R_b, cs.local_in_body[b][own]) + t_b, tree)[:, None]
        own_c = cs.own_markers[c]
        if own_c.any():
            cost += self._capped(np.einsum("ghij,kj->ghki", R_c, cs.local_in_body[c][own_c]) + t_c[:, None, None], tree)
        return cost

    def _pair_search(self, b: int, c: int, R_p: np.ndarray, t_b: np.ndarray, tree: cKDTree,
                     top: int = 4) -> tuple[np.ndarray, np.ndarray]:
        """Coarse grid over both bodies' hinges, then a local grid (half a step each way) around
        the ``top`` best coarse cells; returns the best ``(b hinge values, c hinge values)``."""
        cs = self._tables
        vb, vc = cs.grids[b].values, cs.grids[c].values
        cost = self._pair_cost(b, c, R_p, t_b, vb, vc, tree)
        step_b = np.array([np.ptp(np.unique(vb[:, k])) / max(len(np.unique(vb[:, k])) - 1, 1) for k in range(vb.shape[1])])
        step_c = np.ptp(vc[:, 0]) / max(len(vc) - 1, 1)
        lo = self.solver._hinge_lower
        hi = self.solver._hinge_upper
        hb, hc = cs.hinge_slice[b], cs.hinge_slice[c]
        best = (np.inf, vb[0], vc[0])
        offs = np.linspace(-0.5, 0.5, 5)
        for flat in np.argsort(cost, axis=None)[:top]:
            g, h = np.unravel_index(int(flat), cost.shape)
            local_b = np.stack(np.meshgrid(*[vb[g, k] + offs * step_b[k] for k in range(vb.shape[1])], indexing="ij"), -1).reshape(-1, vb.shape[1])
            local_b = np.clip(local_b, lo[hb], hi[hb])
            local_c = np.clip(vc[h, 0] + offs * step_c, lo[hc][0], hi[hc][0])[:, None]
            fine = self._pair_cost(b, c, R_p, t_b, local_b, local_c, tree)
            i, j = np.unravel_index(int(np.argmin(fine)), fine.shape)
            if fine[i, j] < best[0]:
                best = (float(fine[i, j]), local_b[i], local_c[j])
        return best[1], best[2]

    def _grid_pose(self, q: np.ndarray, points: np.ndarray, tree: cKDTree) -> np.ndarray:
        """Every body's hinges from the root outwards by a grid search on unlabelled points.

        A body with three hinges whose only child has one (shoulder and elbow, hip and knee) is
        searched together with that child: the child's markers fix the parent's axial rotation,
        which the parent's own two markers barely constrain.
        """
        cs = self._tables
        q = q.copy()
        n_b = len(cs.parent)
        R_w = np.zeros((n_b, 3, 3))
        t_w = np.zeros((n_b, 3))
        pin.framesForwardKinematics(self.solver.model, self.solver.data, q)
        R_w[0] = np.array(self.solver.data.oMf[self.solver._body_frames[0]].rotation)
        t_w[0] = np.array(self.solver.data.oMf[self.solver._body_frames[0]].translation)
        children = [np.flatnonzero(cs.parent == b) for b in range(n_b)]
        done = np.zeros(n_b, bool)
        done[0] = True
        # Points explained by bodies already placed are not offered to the next ones (an arm
        # searched over all points can settle on the head's markers).
        free = np.ones(len(points), bool)

        def claim(R: np.ndarray, t: np.ndarray, body: int) -> None:
            own_b = cs.own_markers[body]
            if own_b.any() and free.any():
                X = cs.local_in_body[body][own_b] @ R.T + t
                d, i = cKDTree(points[free]).query(X)
                near = np.flatnonzero(free)[i[d < 0.03]]
                free[near] = False

        def free_tree() -> cKDTree:
            return cKDTree(points[free]) if free.any() else cKDTree(np.full((1, 3), 1e6))

        claim(R_w[0], t_w[0], 0)
        for b in range(1, n_b):
            if done[b]:
                continue
            par = cs.parent[b]
            R_p = R_w[par] @ cs.rest_R[b]
            t_b = t_w[par] + R_w[par] @ cs.rest_t[b]
            grid = cs.grids[b]
            own = cs.own_markers[b]
            kid = cs.child_markers[b]
            pair = (grid is not None and len(cs.hinge_slice[b]) == 3 and len(children[b]) == 1
                    and cs.grids[children[b][0]] is not None and len(cs.hinge_slice[children[b][0]]) == 1)
            if pair:
                c = int(children[b][0])
                g_vals, h_vals = self._pair_search(b, c, R_p, t_b, free_tree())
                R_b = R_p @ self._rotations(b, g_vals[None])[0]
                R_w[b], t_w[b] = R_b, t_b
                t_w[c] = t_b + R_b @ cs.rest_t[c]
                R_w[c] = R_b @ cs.rest_R[c] @ self._rotations(c, h_vals[None])[0]
                q[7 + cs.hinge_slice[b]] = g_vals
                q[7 + cs.hinge_slice[c]] = h_vals
                done[b] = done[c] = True
                claim(R_w[b], t_w[b], b)
                claim(R_w[c], t_w[c], c)
                continue
            if grid is not None and (own.any() or kid.any()):
                R_c = R_p[None] @ grid.rotations  # (G, 3, 3)
                cost = np.zeros(len(R_c))
                if own.any():
                    cost += self._capped(np.einsum("gij,kj->gki", R_c, cs.local_in_body[b][own]) + t_b, free_tree())
                if kid.any():
                    centre = np.einsum("gij,kj->gki", R_c, cs.child_origin[b][kid]) + t_b   # (G, k, 3)
                    cost += self._shell(centre, cs.child_radius[kid], points[free] if free.any() else points)
                best = int(np.argmin(cost))
                q[7 + cs.hinge_slice[b]] = grid.values[best]
                R_w[b] = R_c[best]
            else:
                R_w[b] = R_p
            t_w[b] = t_b
            done[b] = True
            claim(R_w[b], t_w[b], b)
        return q

    def initialise(self, points: np.ndarray, trusted: np.ndarray) -> tuple[np.ndarray | None, np.ndarray, float]:
        M = len(self.labels)
        none = np.full(M, -1, dtype=np.intp)
        good = points[trusted]
        if len(good) < 4:
            return None, none, 0.0
        tree = cKDTree(good)
        best: tuple[np.ndarray | None, np.ndarray, float] = (None, none, 0.0)
        roots = self._root_candidates(points)
        if len(roots) > self.max_roots:
            # The grid search costs ~0.1 s per root: keep the roots whose trunk (the rigid
            # clusters' markers, spine at rest) lies best on the points.
            trunk = np.zeros(len(self.labels), bool)
            for _, own in self._clusters[:3]:
                trunk[own] = True
            cost = [self._capped(self.markers(self._state(q))[trunk], tree) for q in roots]
            roots = [roots[i] for i in np.argsort(cost)[: self.max_roots]]
        for q_root in roots:
            q = self._grid_pose(q_root, good, tree)
            q, idx = self._refine(q, points, (0.08, 0.04, 0.02, 0.015), 60, trusted=trusted)
            score = self._score(q, points, idx)
            if score > best[2]:
                best = (self._state(q), idx, score)
        return best

    def _score(self, q: np.ndarray, points: np.ndarray, idx: np.ndarray) -> float:
        """Labels explained, less a penalty for the residual (so ties go to the tighter fit)."""
        ok = idx >= 0
        if not ok.any():
            return 0.0
        res = np.linalg.norm(self.markers(q)[ok] - points[idx[ok]], axis=1)
        return float(ok.sum() - res.mean() / 0.02)

    # -------------------------------------------------------------- tracking
    def track(self, points: np.ndarray, trusted: np.ndarray, state: np.ndarray, previous: Sequence[np.ndarray],
              gates: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, float]:
        nq = self.solver.nq
        q_prev, v_prev = state[:nq], state[nq:]
        q_pred = pin.integrate(self.solver.model, q_prev, v_prev)
        q_pred[7:] = np.clip(q_pred[7:], self.solver._hinge_lower, self.solver._hinge_upper)
        pred = _constant_velocity(self.markers(np.concatenate([q_pred, v_prev])), previous)
        q, idx = self._refine(q_pred, points, (gates[0], gates[1]), self.solver.params.max_iterations,
                              prior=q_pred[7:], pred=pred, trusted=trusted)
        q, idx = self._recover_clusters(q, idx, points, gates)
        q, idx = self._recover_limbs(q, idx, points, trusted, gates)
        q, idx = self._shell_rescue(q, idx, points, trusted, gates)
        return self._state(q, q_prev), idx, self._score(q, points, idx)

    def _refit_with(self, q: np.ndarray, idx: np.ndarray, points: np.ndarray, gates: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """IK on the given labels, then every label assigned again within the tight gate."""
        ok = idx >= 0
        obs = np.full((len(self.labels), 3), np.nan)
        obs[ok] = points[idx[ok]]
        q, _ = self._fit(q, obs, ok, self.solver.params.max_iterations, prior=q[7:])
        return q, assign_to_predictions(self.markers(self._state(q)), points, gates[1])

    def _recover_clusters(self, q: np.ndarray, idx: np.ndarray, points: np.ndarray,
                          gates: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """A rigid body (three or more markers) whose labels are incomplete or inconsistent with
        its fixed marker distances is matched again as a rigid cluster among the points near it;
        the match is kept when the frame then explains more points. This finds a head that turned
        while only one of its markers was seen (its model pose drifted) when the others return."""
        cs = self._tables
        centres = None
        best_n = int((idx >= 0).sum())
        for b, own in self._clusters:
            lab = idx[own]
            have = lab >= 0
            if have.all():
                P = points[lab]
                L = cs.local_in_body[b][own]
                dm = np.linalg.norm(L[:, None] - L[None], axis=2)
                dp = np.linalg.norm(P[:, None] - P[None], axis=2)
                if np.abs(dp - dm).max() <= self.cluster_tol_m:
                    continue
            if centres is None:
                centres = self.solver.joint_centres(q)
            near = np.linalg.norm(points - centres[b], axis=1) < 0.4
            others = np.ones(len(points), bool)
            mine = np.zeros(len(points), bool)
            mine[lab[have]] = True
            others[idx[idx >= 0]] = False
            allowed = near & (others | mine)
            if allowed.sum() < 3:
                continue
            matches = match_rigid_cluster(cs.local_in_body[b][own], points, self.cluster_tol_m, max_matches=3, allowed=allowed)
            for _, _, mi, _ in matches:
                if (mi >= 0).sum() < max(3, have.sum()):
                    continue
                trial = idx.copy()
                trial[own] = mi
                q_try, idx_try = self._refit_with(q, trial, points, gates)
                n_try = int((idx_try >= 0).sum())
                if n_try > best_n:
                    q, idx, best_n = q_try, idx_try, n_try
                    centres = self.solver.joint_centres(q)
                    break
        return q, idx

    def _shell_rescue(self, q: np.ndarray, idx: np.ndarray, points: np.ndarray, trusted: np.ndarray,
                      gates: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """A marker still unlabelled takes a free point when that point is the only one at the
        marker's fixed distance from its body's joint centre (within 15 mm) and within twice the wide
        gate of the fitted model: a hand marker alone on its body is found this way after a fast
        wrist turn the refit did not follow."""
        missing = np.flatnonzero(idx < 0)
        free = np.ones(len(points), bool)  # untrusted points too: the shell test is the check
        free[idx[idx >= 0]] = False
        if missing.size == 0 or not free.any():
            return q, idx
        cs = self._tables
        if not hasattr(self, "_marker_body"):
            self._marker_body = np.argmax(np.array(cs.own_markers), axis=0)
            self._alone = np.array([cs.own_markers[b].sum() == 1 for b in self._marker_body])
        missing = missing[self._alone[missing]]  # markers alone on their body (hands): nothing else holds them
        if missing.size == 0:
            return q, idx
        centres = self.solver.joint_centres(q)                                   # (B, 3)
        X = self.markers(self._state(q))
        cand_pts = np.flatnonzero(free)
        taken = False
        for m in missing:
            r = np.linalg.norm(points[cand_pts] - centres[self._marker_body[m]], axis=1)
            near = np.linalg.norm(points[cand_pts] - X[m], axis=1) < 2.0 * gates[0]
            hit = cand_pts[near & (np.abs(r - cs.child_radius[m]) < 0.015)]
            if hit.size == 1 and hit[0] not in idx:
                idx = idx.copy()
                idx[m] = hit[0]
                taken = True
        if taken:
            ok = idx >= 0
            obs = np.full((len(self.labels), 3), np.nan)
            obs[ok] = points[idx[ok]]
            q, _ = self._fit(q, obs, ok, self.solver.params.max_iterations, prior=q[7:])
            # The refit must explain every label it was given; one it cannot is let go.
            res = np.linalg.norm(self.markers(self._state(q)) - obs, axis=1)
            idx = np.where(ok & (np.nan_to_num(res, nan=0.0) > gates[1]), -1, idx)
        return q, idx

    def _limbs(self) -> list[tuple[int, int, np.ndarray]]:
        """Limb chains ``(b, c, markers)``: a three-hinge body, its one-hinge child, and the markers
        of both and of the child's descendants (shoulder-elbow-hand, hip-knee-foot)."""
        if not hasattr(self, "_limb_cache"):
            cs = self._tables
            n_b = len(cs.parent)
            out = []
            for b in range(1, n_b):
                kids = np.flatnonzero(cs.parent == b)
                if len(cs.hinge_slice[b]) == 3 and len(kids) == 1 and len(cs.hinge_slice[kids[0]]) == 1:
                    c = int(kids[0])
                    sub = {b, c}
                    for d in range(n_b):  # descendants of c
                        a = d
                        while a > 0 and a not in (c,):
                            a = cs.parent[a]
                        if a == c:
                            sub.add(d)
                    mask = np.zeros(len(self.labels), bool)
                    for d in sub:
                        mask |= cs.own_markers[d]
                    out.append((b, c, mask))
            self._limb_cache = out
        return self._limb_cache

    def _recover_limbs(self, q: np.ndarray, idx: np.ndarray, points: np.ndarray, trusted: np.ndarray,
                       gates: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """A limb that lost markers while unlabelled points lie within its reach is searched again
        (grid over its hinges on the unlabelled points, the rest of the body fixed); the result is
        kept if the whole frame then explains more points."""
        cs = self._tables
        free = trusted.copy()
        free[idx[idx >= 0]] = False
        if not free.any():
            return q, idx
        best_n = int((idx >= 0).sum())
        for b, c, mask in self._limbs():
            # Only a limb that lost at least half its markers is searched again: one or two
            # markers missing are usually hidden, and the others hold the limb.
            if (idx[mask] < 0).sum() < max(1, mask.sum() // 2):
                continue
            pin.framesForwardKinematics(self.solver.model, self.solver.data, q)
            par = cs.parent[b]
            R_par = np.array(self.solver.data.oMf[self.solver._body_frames[par]].rotation)
            t_par = np.array(self.solver.data.oMf[self.solver._body_frames[par]].translation)
            R_p = R_par @ cs.rest_R[b]
            t_b = t_par + R_par @ cs.rest_t[b]
            reach = np.linalg.norm(points - t_b, axis=1) < 1.2
            cand = (free | np.isin(np.arange(len(points)), idx[mask & (idx >= 0)])) & reach
            if cand.sum() < 2 or not (free & reach).any():
                continue
            g_vals, h_vals = self._pair_search(b, c, R_p, t_b, cKDTree(points[cand]))
            q_try = q.copy()
            q_try[7 + cs.hinge_slice[b]] = g_vals
            q_try[7 + cs.hinge_slice[c]] = h_vals
            q_try, idx_try = self._refine(q_try, points, (gates[0], gates[1], gates[1]), self.solver.params.max_iterations,
                                          prior=q_try[7:], trusted=trusted)
            n_try = int((idx_try >= 0).sum())
            if n_try > best_n:
                q, idx, best_n = q_try, idx_try, n_try
                free = trusted.copy()
                free[idx[idx >= 0]] = False
        return q, idx


class ClusterMarkerModel:
    """Markers predicted from their most rigid neighbours, learned from a labelled trial.

    For captures without a skeleton: a *subject calibration* as commercial systems make it from a
    labelled range-of-motion trial. For every marker, the ``n_neighbours`` markers whose distance
    to it varies least over the trial are its neighbours; the marker is predicted from their
    current positions by the rigid (Kabsch) motion that takes their reference positions there,
    with at least three of them seen. Its gate is ``min_gate_m`` plus three times that
    prediction's RMS error over the trial, so a marker on soft tissue gets a wider gate than one
    on a rigid cluster.

    Parameters
    ----------
    labels : M names
    xyz : (F, M, 3) float
        The labelled trial, metres, NaN where a marker was not seen.
    """

    def __init__(self, labels: Sequence[str], xyz: np.ndarray, n_neighbours: int = 4, min_gate_m: float = 0.01) -> None:
        xyz = np.asarray(xyz, dtype=np.float64)
        F, M, _ = xyz.shape
        if M != len(labels):
            raise ValueError(f"ClusterMarkerModel: {len(labels)} labels for {M} trajectories")
        self.labels = list(labels)
        self.min_gate_m = min_gate_m
        ok = np.isfinite(xyz).all(axis=2)
        step = max(1, F // 400)  # a few hundred frames are plenty for the statistics
        X, okX = xyz[::step], ok[::step]
        D = np.linalg.norm(X[:, :, None] - X[:, None], axis=3)                # (F', M, M)
        both = okX[:, :, None] & okX[:, None, :]
        cnt = both.sum(axis=0)
        Dz = np.where(both, D, 0.0)
        mean = Dz.sum(axis=0) / np.maximum(cnt, 1)
        var = np.where(both, (D - mean) ** 2, 0.0).sum(axis=0) / np.maximum(cnt, 1)
        std = np.where(cnt >= max(3, len(X) // 5), np.sqrt(var), np.inf)
        np.fill_diagonal(std, np.inf)
        self.neighbours = np.argsort(std, axis=1)[:, :n_neighbours]          # (M, k)
        self.neighbour_std_m = np.take_along_axis(std, self.neighbours, axis=1)
        # Reference: for each marker, a frame where it and all its neighbours are seen.
        self.ref_self = np.full((M, 3), np.nan)
        self.ref_nb = np.full((M, n_neighbours, 3), np.nan)
        self.gate_m = np.full(M, np.inf)
        for m in range(M):
            nb = self.neighbours[m]
            frames = np.flatnonzero(ok[:, m] & ok[:, nb].all(axis=1))
            if frames.size == 0 or not np.isfinite(self.neighbour_std_m[m]).all():
                continue
            f0 = frames[frames.size // 2]
            self.ref_self[m], self.ref_nb[m] = xyz[f0, m], xyz[f0, nb]
            errs = []
            for f in frames[:: max(1, frames.size // 100)]:
                R, t = _kabsch(self.ref_nb[m], xyz[f, nb])
                errs.append(np.linalg.norm(self.ref_self[m] @ R.T + t - xyz[f, m]))
            self.gate_m[m] = min_gate_m + 3.0 * float(np.sqrt(np.mean(np.square(errs))))

    def markers(self, state: np.ndarray) -> np.ndarray:
        return state

    def predict(self, pos: np.ndarray) -> np.ndarray:
        """Every marker ``(M, 3)`` from its neighbours' labelled positions ``pos`` (NaN: unseen);
        NaN where fewer than three neighbours are seen."""
        out = np.full_like(pos, np.nan)
        seen = np.isfinite(pos).all(axis=1)
        for m in range(len(self.labels)):
            nb = self.neighbours[m]
            use = seen[nb] & np.isfinite(self.ref_nb[m]).all(axis=1)
            if use.sum() < 3:
                continue
            R, t = _kabsch(self.ref_nb[m][use], pos[nb[use]])
            out[m] = self.ref_self[m] @ R.T + t
        return out

    def _grow(self, idx: np.ndarray, points: np.ndarray, allowed: np.ndarray, rounds: int = 4) -> np.ndarray:
        """Label more points from the labelled ones' predictions, until nothing changes."""
        idx = idx.copy()
        for _ in range(rounds):
            pos = _positions(points, idx)
            pred = self.predict(pos)
            free = (idx < 0) & np.isfinite(pred).all(axis=1)
            if not free.any():
                break
            taken = allowed.copy()
            taken[idx[idx >= 0]] = False
            more = assign_to_predictions(np.where(free[:, None], pred, np.nan), points, self.gate_m, allowed=taken)
            if not (more >= 0).any():
                break
            idx = np.where(more >= 0, more, idx)
        return idx

    def initialise(self, points: np.ndarray, trusted: np.ndarray) -> tuple[np.ndarray | None, np.ndarray, float]:
        M = len(self.labels)
        idx = np.full(M, -1, dtype=np.intp)
        # Seeds: groups (a marker and its neighbours), most rigid first, each matched among the
        # points not yet labelled; every seed then grows through the neighbours' predictions.
        rigidity = np.nanmax(np.where(np.isfinite(self.neighbour_std_m), self.neighbour_std_m, np.inf), axis=1)
        for m in np.argsort(rigidity):
            if not np.isfinite(rigidity[m]):
                break
            if idx[m] >= 0:
                continue
            group = np.concatenate([[m], self.neighbours[m]])
            free = np.ones(len(points), bool)
            free[idx[idx >= 0]] = False
            local = np.vstack([self.ref_self[m], self.ref_nb[m]])
            tol = max(0.005, 3.0 * float(np.nanmax(self.neighbour_std_m[m])))
            matches = match_rigid_cluster(local, points, tol, max_matches=2, allowed=free)
            if not matches or int((matches[0][2] >= 0).sum()) < 4:
                continue
            if len(matches) > 1 and int((matches[1][2] >= 0).sum()) == int((matches[0][2] >= 0).sum()) \
                    and matches[1][3] < 1.5 * matches[0][3]:
                continue  # two places fit about as well (e.g. a left/right pair): not a seed
            mi = matches[0][2]
            for j, g in enumerate(group):
                if mi[j] >= 0 and idx[g] < 0 and free[mi[j]]:
                    idx[g] = mi[j]
            idx = self._grow(idx, points, np.ones(len(points), bool), rounds=8)
        n = int((idx >= 0).sum())
        if n < 3:
            return None, idx, 0.0
        pos = _positions(points, idx)
        state = np.where(np.isfinite(pos), pos, self.predict(pos))
        return state, idx, float(n)

    def track(self, points: np.ndarray, trusted: np.ndarray, state: np.ndarray, previous: Sequence[np.ndarray],
              gates: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, float]:
        pred = _constant_velocity(state, previous)
        idx = assign_to_predictions(pred, points, gates[0], allowed=trusted)
        # Veto: a label whose point disagrees with its neighbours' prediction loses it.
        pos = _positions(points, idx)
        model = self.predict(pos)
        bad = (idx >= 0) & np.isfinite(model).all(axis=1) & (np.linalg.norm(pos - model, axis=1) > self.gate_m)
        idx[bad] = -1
        idx = self._grow(idx, points, np.ones(len(points), bool))
        pos = _positions(points, idx)
        model = self.predict(pos)
        seen = idx >= 0
        state = np.where(seen[:, None], pos, np.where(np.isfinite(model), model, pred))
        return state, idx, float(seen.sum())


def _constant_velocity(model_pred: np.ndarray, previous: Sequence[np.ndarray]) -> np.ndarray:
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

    counts = np.array([int(t.sum()) for t in trusted])
    tries = np.unique(np.linspace(0, F - 1, min(p.init_frames, F)).round().astype(int))
    best = (-1, None, None, -np.inf)
    for f in tries:
        state, idx, score = init(int(f))
        if state is not None and score > best[3]:
            best = (int(f), state, idx, score)
        if state is not None and (idx >= 0).sum() >= 0.95 * min(M, counts[f]):
            break  # a fit that explains (nearly) every point: no need to look further
    if best[1] is None:
        for f in np.argsort(-counts):  # every frame, most points first, until one fits
            state, idx, score = init(int(f))
            if state is not None:
                best = (int(f), state, idx, score)
                break
    start, state0, idx0, _ = best
    if state0 is None:
        return PointLabels(list(model.labels), index, predicted, 0, 0)
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
            history = (history + [_positions(pts, idx_t)])[-2:]
            last_count = max(n_t, 1)
            if after is None:
                after = state_t
            f += direction
        return last_count, after

    n0 = int((idx0 >= 0).sum())
    _, next_state = run(start + 1, 1, state0, [_positions(frames[start].xyz, idx0)], n0)
    if next_state is not None:
        back_history = [_positions(frames[g].xyz, index[g]) for g in (start + 2, start + 1) if g < F]
        run(start, -1, next_state, back_history, max(int((index[start + 1] >= 0).sum()), 1))
    else:
        run(start - 1, -1, state0, [_positions(frames[start].xyz, idx0)], n0)
    return PointLabels(list(model.labels), index, predicted, start, reinit)


def _positions(points: np.ndarray, idx: np.ndarray) -> np.ndarray:
    out = np.full((len(idx), 3), np.nan)
    ok = idx >= 0
    out[ok] = points[idx[ok]]
    return out
