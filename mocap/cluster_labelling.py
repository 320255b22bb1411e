"""Markers predicted from their most rigid neighbours: a labelling model for captures without a
skeleton (:func:`mocap.model_labelling.label_points`), learned from a labelled trial."""

from __future__ import annotations

import warnings
from itertools import combinations, permutations
from typing import Sequence

import numpy as np

from mocap.model_labelling import assign_to_predictions, constant_velocity, kabsch, match_rigid_cluster, point_positions

__all__ = ["ClusterMarkerModel"]


def _prediction_rms(xyz: np.ndarray, ok: np.ndarray, m: int, nb: np.ndarray) -> tuple[float, int] | None:
    """How well neighbours ``nb`` predict marker ``m`` over a labelled trial ``xyz (F, M, 3)``
    (``ok``: seen): ``(RMS error m, reference frame)``, the reference being the middle frame
    where all of them are seen and the error taken over up to ~100 such frames by the rigid
    (Kabsch) motion of the neighbours from the reference; None where no frame has them all."""
    frames = np.flatnonzero(ok[:, m] & ok[:, nb].all(axis=1))
    if frames.size == 0:
        return None
    f0 = int(frames[frames.size // 2])
    use = frames[:: max(1, frames.size // 100)]
    src, dst = xyz[f0, nb], xyz[use][:, nb]                              # (k, 3), (T, k, 3)
    cs, cd = src.mean(axis=0), dst.mean(axis=1)
    H = np.einsum("ki,tkj->tij", src - cs, dst - cd[:, None])
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    d = np.sign(np.linalg.det(V @ np.swapaxes(U, 1, 2)))
    D = np.zeros((len(use), 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    R = V @ D @ np.swapaxes(U, 1, 2)                                      # (T, 3, 3): dst ~ R src + t
    pred = np.einsum("tij,j->ti", R, xyz[f0, m] - cs) + cd
    err = np.linalg.norm(pred - xyz[use, m], axis=1)
    return float(np.sqrt(np.mean(err**2))), f0


#: A rigid group may take a point from a label outside it only if that turns it less than this
#: since the previous frame (c3d_racing_propulsion's glove triads turn at most 46 deg a frame).
MAX_TURN_RAD = np.radians(60.0)


def _label_orderings(group: np.ndarray, n: int) -> np.ndarray:
    """``(P, n)`` every ordered choice of ``n`` labels of ``group``, in ``itertools.permutations`` order."""
    return np.array(list(permutations(group.tolist(), n)), dtype=np.intp).reshape(-1, n)


def _turn(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) of the rotation that takes points ``a`` onto ``b`` (least squares)."""
    R, _ = kabsch(a, b)
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def _distance_statistics(xyz: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation ``(M, M)`` m of every marker pair's distance over the trial
    ``xyz (F, M, 3)`` where both are seen (``ok (F, M)``); the deviation is inf on the diagonal and
    for pairs seen together too rarely."""
    step = max(1, len(xyz) // 400)  # a few hundred frames are plenty for the statistics
    X, okX = xyz[::step], ok[::step]
    D = np.linalg.norm(X[:, :, None] - X[:, None], axis=3)                # (F', M, M)
    both = okX[:, :, None] & okX[:, None, :]
    cnt = both.sum(axis=0)
    Dz = np.where(both, D, 0.0)
    mean = Dz.sum(axis=0) / np.maximum(cnt, 1)
    var = np.where(both, (D - mean) ** 2, 0.0).sum(axis=0) / np.maximum(cnt, 1)
    # A pair's distance statistics count once the two were seen together in a fifth of the
    # frames, or in 20 (enough for a mean and spread): c3d_basket_sprint's ForearmL:Marker4 is
    # in 25 of its 180 frames, had no model under the fifth alone and was never labelled
    # (3 of 4 gaps recovered; 4 of 4 with the 20), and Qualisys with gaps seeded in 20 % of
    # its markers re-labels 22 of 22 gaps rather than 18 (0.64 mm, 0 swaps; 2.6 mm, 1 before).
    std = np.where(cnt >= max(3, min(len(X) // 5, 20)), np.sqrt(var), np.inf)
    np.fill_diagonal(std, np.inf)
    return mean, std


class ClusterMarkerModel:
    """Markers predicted from their most rigid neighbours, learned from a labelled trial.

    For captures without a skeleton: a *subject calibration* as commercial systems make it from a
    labelled range-of-motion trial. The marker is predicted from its ``n_neighbours`` neighbours'
    current positions by the rigid (Kabsch) motion that takes their reference positions there,
    with at least three of them seen. Its neighbours are the markers whose distance to it varies
    least over the trial, taken first among those within ``max_reach_m`` (0.5 m, about a body
    segment) on average: a far marker's distance can stay constant while its direction turns
    (trc_sprint_start: the left acromion, 73 cm from the right wrist, distance SD 2.6 mm, made the
    wrist's prediction 27-29 mm wrong as the sprinter rose, 4-6 mm without it; c3d_walking2: the
    neck marker C7 predicting a shank marker gave it a 309 mm gate). Its gate is ``min_gate_m``
    plus three times that prediction's RMS error over the trial, so a marker on soft tissue gets a
    wider gate than one on a rigid cluster. While tracking, two labelled neighbours closer than
    their gates exchange points where the model fits the exchange clearly better
    (:meth:`exchange_neighbours`).

    Parameters
    ----------
    labels : M names
    xyz : (F, M, 3) float
        The labelled trial, metres, NaN where a marker was not seen.
    max_reach_m : float or None
        Markers farther than this on average are neighbours only when too few nearer ones are
        (None: by distance variation alone, as before).
    n_spare : int
        Candidates beyond ``n_neighbours`` among which the ``n_neighbours`` that predict the marker
        best over the trial are chosen (0: none). Tried at 3: worse on trc_ballet (1.68 mm, 1 swap)
        and trc_sprint_start (0.947 reconstructed) than at 0 (0.27 mm; 0.997).
    """

    def __init__(self, labels: Sequence[str], xyz: np.ndarray, n_neighbours: int = 4, min_gate_m: float = 0.01,
                 n_spare: int = 0, max_reach_m: float | None = 0.5, rigid_std_m: float = 0.0015) -> None:
        xyz = np.asarray(xyz, dtype=np.float64)
        F, M, _ = xyz.shape
        if M != len(labels):
            raise ValueError(f"ClusterMarkerModel: {len(labels)} labels for {M} trajectories")
        self.labels = list(labels)
        self.min_gate_m = min_gate_m
        ok = np.isfinite(xyz).all(axis=2)
        mean, std = _distance_statistics(xyz, ok)
        # Neighbours: the markers whose distance to the marker varies least, those within
        # ``max_reach_m`` on average first (then the farther ones, then those never seen with it);
        # with ``n_spare``, the ``n_neighbours`` of the first ``n_neighbours + n_spare`` that
        # predict it best over the trial.
        far = (mean > max_reach_m) if max_reach_m is not None else np.zeros_like(std, bool)
        ranked = np.lexsort((std, np.where(np.isfinite(std), far.astype(int), 2)), axis=1)
        self.neighbours = ranked[:, :n_neighbours].copy()                     # (M, k)
        self.ref_self = np.full((M, 3), np.nan)
        self.ref_nb = np.full((M, n_neighbours, 3), np.nan)
        self.gate_m = np.full(M, np.inf)
        for m in range(M):
            pool = [int(j) for j in ranked[m, : n_neighbours + n_spare] if np.isfinite(std[m, j])]
            best = None
            for nb in combinations(pool, n_neighbours):
                fit = _prediction_rms(xyz, ok, m, np.array(nb))
                if fit is not None and (best is None or fit[0] < best[0] - 1e-12):
                    best = (fit[0], fit[1], np.array(nb))
            if best is None:
                continue
            rms, f0, nb = best
            self.neighbours[m] = nb
            self.ref_self[m], self.ref_nb[m] = xyz[f0, m], xyz[f0, nb]
            self.gate_m[m] = min_gate_m + 3.0 * rms
        self.neighbour_std_m = np.take_along_axis(std, self.neighbours, axis=1)
        # Rigid groups: a marker and those of its neighbours whose distances to it and to each other
        # vary less than ``rigid_std_m`` over the trial (a plate or a triad of markers), three at least.
        self.mean_dist_m = mean
        groups = set()
        for m in range(M):
            g = [m] + [int(j) for j in self.neighbours[m] if std[m, j] < rigid_std_m]
            g = [a for a in g if all(std[a, b] < rigid_std_m for b in g if b != a)]
            if len(g) >= 3:
                groups.add(tuple(sorted(g)))
        self.rigid_groups = [np.array(g) for g in sorted(groups)]
        self.shape_tol_m = 0.005
        self.group_local, self.group_reach = [], []
        for g in self.rigid_groups:
            frames = np.flatnonzero(ok[:, g].all(axis=1))
            self.group_local.append(xyz[frames[frames.size // 2], g])
            self.group_reach.append(float(mean[np.ix_(g, g)].max()) + 0.01)
        # Each group's surroundings: the other markers' places in the group's own frame over the
        # trial (mean and RMS spread), those within 0.3 m whose place varies least (at most 60 mm).
        self.group_context = []
        for g, local in zip(self.rigid_groups, self.group_local):
            frames = np.flatnonzero(ok[:, g].all(axis=1))
            frames = frames[:: max(1, frames.size // 100)]
            loc = np.full((len(frames), M, 3), np.nan)
            for k, f in enumerate(frames):
                R, t = kabsch(local, xyz[f, g])
                loc[k] = (xyz[f] - t) @ R
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                mu = np.nanmean(loc, axis=0)
                spread = np.sqrt(np.nanmean(((loc - mu) ** 2).sum(axis=2), axis=0))
            near = np.linalg.norm(mu - local.mean(axis=0), axis=1) < 0.3
            cand = [j for j in np.argsort(np.nan_to_num(spread, nan=np.inf))
                    if j not in g and near[j] and spread[j] < 0.06 and np.isfinite(spread[j])][:4]
            cand = np.array(cand, dtype=int)
            self.group_context.append((cand, mu[cand], np.maximum(spread[cand], 0.005)))
        self.group_partners = self._learn_partners(xyz, ok)

    def _learn_partners(self, xyz: np.ndarray, ok: np.ndarray) -> list[list[tuple[int, np.ndarray, float]]]:
        """For each rigid group, the groups within 0.3 m whose orientation relative to it stayed
        within 90 deg of its mean over the trial: ``(other group, mean relative rotation, largest
        deviation (rad))``. A forearm triad and its glove's turn at the wrist up to 77-84 deg from
        their mean relative orientation (c3d_racing_propulsion); a glove triad's two labels
        exchanged turn it 180 deg about an axis in its plane, at least 96 deg from it."""
        rot = []
        for g, local in zip(self.rigid_groups, self.group_local):
            R = np.full((len(xyz), 3, 3), np.nan)
            for f in np.flatnonzero(ok[:, g].all(axis=1)):
                R[f] = kabsch(local, xyz[f, g])[0]
            rot.append(R)
        partners: list[list[tuple[int, np.ndarray, float]]] = [[] for _ in self.rigid_groups]
        for a, b in permutations(range(len(self.rigid_groups)), 2):
            both = np.isfinite(rot[a][:, 0, 0]) & np.isfinite(rot[b][:, 0, 0])
            far = np.linalg.norm(self.group_local[a].mean(axis=0) - self.group_local[b].mean(axis=0)) > 0.3
            if both.sum() < 10 or far:
                continue
            rel = np.einsum("fji,fjk->fik", rot[a][both], rot[b][both])     # R_a^T R_b
            U, _, Vt = np.linalg.svd(rel.sum(axis=0))                        # chordal mean rotation
            mean = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
            dev = np.arccos(np.clip((np.einsum("fij,ij->f", rel, mean) - 1.0) / 2.0, -1.0, 1.0))
            if dev.max() < np.radians(90.0):
                partners[a].append((b, mean, float(dev.max())))
        return partners

    def markers(self, state: np.ndarray) -> np.ndarray:
        return state

    def predict(self, pos: np.ndarray, which: np.ndarray | None = None) -> np.ndarray:
        """Every marker ``(M, 3)`` (or those in ``which``) from its neighbours' labelled positions
        ``pos`` (NaN: unseen); NaN where fewer than three neighbours are seen."""
        markers = np.arange(len(self.labels)) if which is None else np.asarray(which)
        out = np.full((len(markers), 3), np.nan)
        seen = np.isfinite(pos).all(axis=1)
        for j, m in enumerate(markers):
            nb = self.neighbours[m]
            use = seen[nb] & np.isfinite(self.ref_nb[m]).all(axis=1)
            if use.sum() < 3:
                continue
            R, t = kabsch(self.ref_nb[m][use], pos[nb[use]])
            out[j] = self.ref_self[m] @ R.T + t
        return out

    def disagreement(self, pos: np.ndarray, which: np.ndarray) -> float:
        """How far the labelled markers ``which`` lie from their neighbours' prediction: the sum
        of ``(distance / gate)^2`` over those that can be predicted."""
        d = np.linalg.norm(pos[which] - self.predict(pos, which), axis=1) / self.gate_m[which]
        return float(np.nansum(d**2))

    def exchange_neighbours(self, idx: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Labelled neighbours whose points lie within each other's gate exchange them where that
        makes them, and the markers predicted from them, agree with the model by at least one
        whole gate better.

        Why: motion alone cannot keep two close markers apart once one of them has taken a point
        merged from both (c3d_codamotion_walk, frame 61: the right shank label took a knee and
        shank point 16 mm from either marker; extrapolated at that point's velocity, it took the
        knee marker's point 32 mm away at frame 62 and the knee label the shank's, and the leg's
        labels never recovered). Exchanged, the pair fits the neighbour model far better (a sum
        of 5.3 -> 0.4 there). The margin of one gate leaves a pair that fits either way about as
        well (a sacral wand's two markers, 3-25 mm apart) as the motion assigned it."""
        idx = idx.copy()
        for a, b in self._close_labelled_pairs(idx, points):
            which = self._dependants(a, b)
            which = which[idx[which] >= 0]
            pos = point_positions(points, idx)
            before = self.disagreement(pos, which)
            pos[[a, b]] = pos[[b, a]]
            if self.disagreement(pos, which) < before - 1.0:
                idx[[a, b]] = idx[[b, a]]
        return idx

    def keep_rigid_orientation(self, idx: np.ndarray, points: np.ndarray, last: np.ndarray) -> np.ndarray:
        """Within each rigid group, give its points to the labels that turn the group least since
        the previous frame (``last``: the previous frame's markers, labelled or predicted, NaN where
        neither), then to those that fit its surroundings (:meth:`_fit_surroundings`).

        Why: a group whose shape is (nearly) symmetric, such as the equilateral 43 mm triads of
        c3d_racing_propulsion, fits its own shape as well with its labels permuted, and so do the
        neighbour predictions made from it; only its motion tells the permutations apart. At 70 Hz
        a glove triad moves up to 92 mm and turns up to 46 deg between frames, so each marker's
        constant-velocity prediction can lie nearer another marker of the triad (its errors reach
        65 mm, the markers are 43 mm apart), while a permuted triad turns at least 86 deg from the
        previous frame. The placements of the group among the points near its labelled ones that
        keep its shape (within ``shape_tol_m``) are tried; the one with the most points, then the
        least turn, is kept where it turns the group by less than half the turn of the labels it
        has (any turn where those were fewer than three), or takes more points turning less than
        :data:`MAX_TURN_RAD` (a label outside the group that held one of them loses it). Two points
        alone go to the two labels whose segment turns least. Groups with fewer than three markers
        known in the previous frame are left as they are."""
        idx = idx.copy()
        for g, local, reach in zip(self.rigid_groups, self.group_local, self.group_reach):
            have = g[idx[g] >= 0]
            if len(have) < 2 or np.isfinite(last[g]).all(axis=1).sum() < 3:
                continue
            near = np.flatnonzero(np.linalg.norm(points - points[idx[have]].mean(axis=0), axis=1) < reach)
            current = _turn(last[have], points[idx[have]]) if len(have) >= 3 and np.isfinite(last[have]).all() else np.inf
            best = None
            for _, _, mi, _ in match_rigid_cluster(local, points[near], self.shape_tol_m, max_matches=12):
                use = mi >= 0
                labels, pts = g[use], near[mi[use]]
                seen = np.isfinite(last[labels]).all(axis=1)
                if seen.sum() < 3:
                    continue
                key = (-int(use.sum()), _turn(last[labels[seen]], points[pts[seen]]))
                if best is None or key < best[0]:
                    best = (key, labels, pts)
            if best is None and len(have) == 2 and np.isfinite(last[g]).all():
                # Two points: the labels whose segment turns least (a transposed pair turns the
                # segment by 180 deg less the true turn).
                pts2 = idx[have]
                v = points[pts2[1]] - points[pts2[0]]
                for a, b in permutations(g, 2):
                    if abs(self.mean_dist_m[a, b] - np.linalg.norm(v)) > self.shape_tol_m:
                        continue
                    w = last[b] - last[a]
                    angle = float(np.arccos(np.clip(v @ w / (np.linalg.norm(v) * np.linalg.norm(w)), -1.0, 1.0)))
                    if (a, b) == tuple(have):
                        current = angle
                    if best is None or angle < best[0][1]:
                        best = ((-2, angle), np.array([a, b]), pts2)
            if best is None:
                continue
            (n_neg, turn), labels, pts = best
            if sorted(zip(labels.tolist(), pts.tolist())) == sorted(zip(have.tolist(), idx[have].tolist())):
                continue
            if turn < 0.5 * current or (-n_neg > len(have) and turn < MAX_TURN_RAD):
                idx[np.isin(idx, pts)] = -1  # a label outside the group that held one of its points loses it
                idx[g] = -1
                idx[labels] = pts
        for gi in range(len(self.rigid_groups)):
            idx = self._fit_surroundings(gi, idx, points)
        return idx

    def _fit_surroundings(self, gi: int, idx: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Give a rigid group's points to the labels that put its labelled surroundings where the
        trial had them in the group's frame, where that fits clearly better than the labels it has.

        Motion keeps a group's labels only if they were right before; this is what sets them right
        again. A glove triad permuted by 120 deg moves its hand marker (c3d_racing_propulsion's NAR,
        82 mm from the triad's centre, 8 mm RMS spread in its frame) by about 140 mm there. Applied
        only when the present labels put the surroundings more than three spreads away on average
        and another labelling fits four times better."""
        g, local = self.rigid_groups[gi], self.group_local[gi]
        ctx, mu, spread = self.group_context[gi]
        have = g[idx[g] >= 0]
        seen = ctx[idx[ctx] >= 0] if len(ctx) else ctx
        if len(have) < 3 or len(seen) == 0:
            return idx
        k = np.searchsorted(ctx, seen) if np.all(np.diff(ctx) > 0) else np.array([list(ctx).index(j) for j in seen])
        pts = idx[have]
        d_now = np.linalg.norm(points[pts][:, None] - points[pts][None], axis=2)
        current, best = None, None
        # Every ordering of the group's labels over its points at once (at most 5! = 120), the
        # shape test vectorised: a static take's 35 groups made this loop a third of the labelling
        # (Res16bits, 100 frames: 37 of 105 s). Same orderings, same order, same figures.
        perms = _label_orderings(g, len(have))
        shape_ok = ~(np.abs(self.mean_dist_m[perms[:, :, None], perms[:, None, :]] - d_now).max(axis=(1, 2)) > self.shape_tol_m)
        for labels in perms[shape_ok]:
            R, t = kabsch(local[np.searchsorted(g, labels)], points[pts])
            loc = (points[idx[seen]] - t) @ R
            score = float(np.mean((np.linalg.norm(loc - mu[k], axis=1) / spread[k]) ** 2))
            if np.array_equal(labels, have):
                current = score
            if best is None or score < best[0]:
                best = (score, labels)
        if current is None or best is None or np.array_equal(best[1], have):
            return idx
        if current > 9.0 and best[0] < current / 4.0:
            idx = idx.copy()
            idx[g] = -1
            idx[best[1]] = pts
        return idx

    def reacquire_groups(self, idx: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Label again a rigid group with fewer than two labelled members where its shape appears
        among the free points at one place only, with its labels put so that its labelled
        surroundings sit where the trial had them in the group's frame.

        Why: nothing else brings such a group back. Its members are predicted from each other
        (a triad's neighbours are two of its own and two across a joint), so with the group lost
        whole none is predicted, and extrapolated from where it was lost it takes whatever point
        comes near (c3d_racing_propulsion: the right scapula triad, lost whole in frames 103-110,
        was never labelled again; the left forearm triad, lost in frames 41-42, came back on the
        glove's points). The placement is taken only where it is unambiguous: it fits the labelled
        surroundings (one at least) within three spreads on average, and every other placement
        or labelling of the free points fits four times worse, or else exactly one of those within
        four times turns the group, relative to a partner group (:meth:`_learn_partners`), as the
        trial ever did and none of the others within 1.5 times that (the left glove's one hand
        marker, near the triad's axis, fitted two labellings about as well in frames 36-43, and the
        glove's points, unlabelled there, were filled 51 mm RMS off). Asking for two of the
        surroundings left both scapula triads, each the other's surroundings, unlabelled together
        (481 against 94 samples reconstructed but unlabelled there)."""
        idx = idx.copy()
        for gi, (g, local) in enumerate(zip(self.rigid_groups, self.group_local)):
            have = g[idx[g] >= 0]
            ctx, mu, spread = self.group_context[gi]
            seen = np.flatnonzero(idx[ctx] >= 0) if len(ctx) else np.zeros(0, int)
            if len(have) >= 2 or len(seen) == 0:
                continue
            free = np.ones(len(points), bool)
            free[idx[idx >= 0]] = False
            free[idx[have]] = True  # a lone labelled member may keep its point in the group
            scored = []
            for R, t, mi, _ in match_rigid_cluster(local, points, self.shape_tol_m, max_matches=60, allowed=free):
                use = mi >= 0
                if use.sum() < min(len(g), 4) or any(mi[list(g).index(m)] != idx[m] for m in have):
                    continue
                loc = (points[idx[ctx[seen]]] - t) @ R
                score = float(np.mean((np.linalg.norm(loc - mu[seen], axis=1) / spread[seen]) ** 2))
                scored.append((score, g[use], mi[use]))
            if not scored:
                continue
            scored.sort(key=lambda s: s[0])
            score, labels, pts = scored[0]
            if score > 9.0:
                continue
            rivals = [s for s in scored if s[0] < 4.0 * score]
            if len(rivals) > 1:
                # Surroundings that cannot tell the rivals apart (one hand marker near the triad's
                # axis): the partner group's orientation may, where exactly one lies within the trial's.
                dev = [self._partner_deviation(gi, lab, p, idx, points) for _, lab, p in rivals]
                inside = [k for k, d in enumerate(dev) if d is not None and d <= 1.0]
                if len(inside) != 1 or any(d is None or (d <= 1.5 and k != inside[0]) for k, d in enumerate(dev)):
                    continue
                score, labels, pts = rivals[inside[0]]
            idx[have] = -1
            idx[labels] = pts
        return idx

    def _partner_deviation(self, gi: int, labels: np.ndarray, pts: np.ndarray, idx: np.ndarray,
                           points: np.ndarray) -> float | None:
        """How far group ``gi`` with ``labels`` on points ``pts`` turns from where the trial had it
        relative to its fully labelled partners (:meth:`_learn_partners`) that keep their shape:
        the largest deviation over them, as a fraction of the trial's largest; None without any."""
        worst = None
        for gj, mean, limit in self.group_partners[gi]:
            other = self.rigid_groups[gj]
            if not (idx[other] >= 0).all():
                continue
            q = points[idx[other]]
            shape = np.linalg.norm(q[:, None] - q[None], axis=2) - self.mean_dist_m[np.ix_(other, other)]
            if np.abs(shape).max() > self.shape_tol_m:
                continue  # a partner on a wrong point would turn this group wrong
            g = self.rigid_groups[gi]
            R = kabsch(self.group_local[gi][np.searchsorted(g, labels)], points[pts])[0]
            R_other = kabsch(self.group_local[gj], q)[0]
            rel = R.T @ R_other
            dev = float(np.arccos(np.clip((np.trace(rel @ mean.T) - 1.0) / 2.0, -1.0, 1.0))) / limit
            worst = dev if worst is None else max(worst, dev)
        return worst

    def rigidly_placed(self, idx: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Labels ``(M,)`` bool whose point keeps its rigid group's shape with at least two other
        labelled members (every distance among them within ``shape_tol_m`` of the trial's).

        The veto spares them: such a marker's neighbours beyond its group sit across a joint
        (a glove triad's fourth neighbour is on the forearm), and their prediction can be off by
        more than the marker's gate while the triad itself holds its shape to a millimetre."""
        out = np.zeros(len(idx), bool)
        for g in self.rigid_groups:
            have = g[idx[g] >= 0]
            if len(have) < 3:
                continue
            p = points[idx[have]]
            d = np.abs(np.linalg.norm(p[:, None] - p[None], axis=2) - self.mean_dist_m[np.ix_(have, have)])
            ok = (d <= self.shape_tol_m).sum(axis=1) >= 3  # itself and two others
            out[have[ok]] = True
        return out

    def _close_labelled_pairs(self, idx: np.ndarray, points: np.ndarray) -> list[tuple[int, int]]:
        """Neighbour pairs ``(a, b)``, each once, both labelled, whose points are closer than
        both their gates (either label could have taken the other's point)."""
        pairs = set()
        for a in np.flatnonzero(idx >= 0):
            for b in self.neighbours[a]:
                gap = np.linalg.norm(points[idx[a]] - points[idx[b]]) if idx[b] >= 0 else np.inf
                if gap < min(self.gate_m[a], self.gate_m[b]):
                    pairs.add((min(a, b), max(a, b)))
        return sorted(pairs)

    def _adrift(self, previous: Sequence[np.ndarray]) -> np.ndarray:
        """Members ``(M,)`` bool of rigid groups that the previous frame (``previous[-1]``, its
        labelled positions) neither labelled nor could predict from their neighbours: their
        position is where they were lost, and a fast hand's triad is 40-90 mm from there a frame
        later (c3d_racing_propulsion), nearer another triad's points than its own."""
        out = np.zeros(len(self.labels), bool)
        if not previous or not self.rigid_groups:
            return out
        prev = previous[-1]
        members = np.unique(np.concatenate(self.rigid_groups))
        known = np.isfinite(prev[members]).all(axis=1) | np.isfinite(self.predict(prev, members)).all(axis=1)
        out[members[~known]] = True
        return out

    def _dependants(self, a: int, b: int) -> np.ndarray:
        """Markers ``a``, ``b`` and those predicted from either."""
        uses = (self.neighbours == a).any(axis=1) | (self.neighbours == b).any(axis=1)
        return np.union1d([a, b], np.flatnonzero(uses))

    def _grow(self, idx: np.ndarray, points: np.ndarray, allowed: np.ndarray, rounds: int = 4,
              gate_m: np.ndarray | None = None) -> np.ndarray:
        """Label more of the ``allowed`` points from the labelled ones' predictions (each label
        within ``gate_m``, default its own gate), until nothing changes."""
        gate_m = self.gate_m if gate_m is None else gate_m
        idx = idx.copy()
        for _ in range(rounds):
            pos = point_positions(points, idx)
            pred = self.predict(pos)
            free = (idx < 0) & np.isfinite(pred).all(axis=1)
            if not free.any():
                break
            taken = allowed.copy()
            taken[idx[idx >= 0]] = False
            more = assign_to_predictions(np.where(free[:, None], pred, np.nan), points, gate_m, allowed=taken)
            if not (more >= 0).any():
                break
            idx = np.where(more >= 0, more, idx)
        return idx

    def _seed(self, idx: np.ndarray, points: np.ndarray, which: np.ndarray, allowed: np.ndarray | None = None) -> np.ndarray:
        """Label more of the ``allowed`` points (default all) by matching groups (a marker of ``which``
        and its neighbours) among the points not yet labelled, most rigid first, each seed then grown
        through the predictions."""
        allowed = np.ones(len(points), bool) if allowed is None else allowed
        idx = idx.copy()
        which = set(int(m) for m in which)
        # Seeds: groups (a marker and its neighbours), most rigid first, each matched among the
        # points not yet labelled; every seed then grows through the neighbours' predictions.
        rigidity = np.nanmax(np.where(np.isfinite(self.neighbour_std_m), self.neighbour_std_m, np.inf), axis=1)
        for m in np.argsort(rigidity):
            if not np.isfinite(rigidity[m]):
                break
            if idx[m] >= 0 or m not in which:
                continue
            group = np.concatenate([[m], self.neighbours[m]])
            free = allowed.copy()
            free[idx[idx >= 0]] = False
            # Members of the group labelled by an earlier seed anchor the match on their own points:
            # a cluster whose other neighbours an earlier seed took (the head of c3d_sample_static,
            # four markers and a torso marker) could otherwise never be matched (4 markers needed)
            # nor grown (3 labelled neighbours needed), and stayed unlabelled through the take.
            anchor = idx[group]
            usable = free.copy()
            usable[anchor[anchor >= 0]] = True
            local = np.vstack([self.ref_self[m], self.ref_nb[m]])
            tol = max(0.005, 3.0 * float(np.nanmax(self.neighbour_std_m[m])))
            matches = match_rigid_cluster(local, points, tol, max_matches=2, allowed=usable)
            if not matches or int((matches[0][2] >= 0).sum()) < 4:
                continue
            if len(matches) > 1 and int((matches[1][2] >= 0).sum()) == int((matches[0][2] >= 0).sum()) \
                    and matches[1][3] < 1.5 * matches[0][3]:
                continue  # two places fit about as well (e.g. a left/right pair): not a seed
            mi = matches[0][2]
            if ((anchor >= 0) & (mi >= 0) & (mi != anchor)).any() or (~free[mi[(mi >= 0) & (anchor < 0)]]).any():
                continue  # a labelled member, or a labelled point, taken by another marker of the group
            for j, g in enumerate(group):
                if mi[j] >= 0 and idx[g] < 0 and free[mi[j]]:
                    idx[g] = mi[j]
            idx = self._grow(idx, points, allowed, rounds=8)
        return idx

    def initialise(self, points: np.ndarray, trusted: np.ndarray) -> tuple[np.ndarray | None, np.ndarray, float]:
        M = len(self.labels)
        idx = self._seed(np.full(M, -1, dtype=np.intp), points, np.arange(M))
        n = int((idx >= 0).sum())
        if n < 3:
            return None, idx, 0.0
        pos = point_positions(points, idx)
        state = np.where(np.isfinite(pos), pos, self.predict(pos))
        return state, idx, float(n)

    def track(self, points: np.ndarray, trusted: np.ndarray, state: np.ndarray, previous: Sequence[np.ndarray],
              gates: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, float]:
        last = state  # the previous frame's markers (labelled, else predicted)
        pred = constant_velocity(state, previous)
        # A rigid group's member neither labelled nor predicted in the previous frame takes a point
        # by motion only within the tight gate: its group's shape brings it back
        # (:meth:`reacquire_groups`), not the wide gate around where it was lost.
        adrift = self._adrift(previous)
        idx = assign_to_predictions(np.where(adrift[:, None], np.nan, pred), points, gates[0], allowed=trusted)
        if adrift.any():
            free_points = trusted.copy()
            free_points[idx[idx >= 0]] = False
            more = assign_to_predictions(np.where(adrift[:, None], pred, np.nan), points, gates[1],
                                         allowed=free_points)
            idx = np.where(more >= 0, more, idx)
        # Ambiguous two-view points: only within the tight gate of the motion prediction.
        free_points = ~trusted
        free_points[idx[idx >= 0]] = False
        more = assign_to_predictions(np.where((idx < 0)[:, None], pred, np.nan), points, gates[1], allowed=free_points)
        idx = np.where(more >= 0, more, idx)
        # Before the veto: a crossed pair would make their neighbours' predictions veto right labels.
        idx = self.exchange_neighbours(idx, points)
        idx = self.keep_rigid_orientation(idx, points, last)
        # Veto: a label whose point disagrees with its neighbours' prediction loses it.
        pos = point_positions(points, idx)
        model = self.predict(pos)
        bad = (idx >= 0) & np.isfinite(model).all(axis=1) & (np.linalg.norm(pos - model, axis=1) > self.gate_m)
        idx[bad & ~self.rigidly_placed(idx, points)] = -1
        idx = self.reacquire_groups(idx, points)
        # Growth takes trusted points within the marker's gate, and ambiguous two-view points
        # only within the tight gate (the MarkerModel rule): a knee marker's two-view point 32 mm
        # from the shank marker lost to a merged point was inside the shank marker's 49 mm gate,
        # and the labels of the two crossed for the rest of c3d_codamotion_walk.
        idx = self._grow(idx, points, trusted)
        idx = self._grow(idx, points, np.ones(len(points), bool), gate_m=np.minimum(self.gate_m, gates[1]))
        idx = self.reacquire_groups(idx, points)
        idx = self.keep_rigid_orientation(idx, points, last)
        pos = point_positions(points, idx)
        model = self.predict(pos)
        seen = idx >= 0
        state = np.where(seen[:, None], pos, np.where(np.isfinite(model), model, pred))
        return state, idx, float(seen.sum())
