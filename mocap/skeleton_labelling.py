"""The subject's skeleton with its markers as a labelling model (:func:`mocap.model_labelling.label_points`).

Global search from any pose (rigid-cluster matches for the root, grid search over every body's
hinges on unlabelled points), tracking by Hungarian assignment around the refitted skeleton, and
recovery of what tracking lost (rigid clusters matched again, limbs searched again, lone hand
markers taken back by their fixed distance from the joint)."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pinocchio as pin
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from mocap.skeleton import SkeletonSolver
from mocap.skeleton_cold_start import place_body
from mocap.model_labelling import assign_to_predictions, constant_velocity, match_rigid_cluster

__all__ = ["SkeletonMarkerModel"]


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
            R_c = cost = None
            if grid is not None and (own.any() or kid.any()):
                R_c = R_p[None] @ grid.rotations  # (G, 3, 3)
                cost = np.zeros(len(R_c))
                if own.any():
                    cost += self._capped(np.einsum("gij,kj->gki", R_c, cs.local_in_body[b][own]) + t_b, free_tree())
                if kid.any():
                    centre = np.einsum("gij,kj->gki", R_c, cs.child_origin[b][kid]) + t_b   # (G, k, 3)
                    cost += self._shell(centre, cs.child_radius[kid], points[free] if free.any() else points)
            place_body(cs, b, q, R_w, t_w, t_b, R_p, R_c, cost)
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
        pred = constant_velocity(self.markers(np.concatenate([q_pred, v_prev])), previous)
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
