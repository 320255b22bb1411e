"""Markers predicted from their most rigid neighbours: a labelling model for captures without a
skeleton (:func:`mocap.model_labelling.label_points`), learned from a labelled trial."""

from __future__ import annotations

import warnings
from itertools import combinations
from typing import Sequence

import numpy as np

from mocap.model_labelling import assign_to_predictions, constant_velocity, kabsch, match_rigid_cluster, point_positions
from mocap.rigid_groups import RigidGroupRules

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


class ClusterMarkerModel(RigidGroupRules):
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
        # A rigid group's member neither labelled nor predicted in the previous frame takes no point
        # by motion: its group's shape brings it back (:meth:`reacquire_groups`). Its prediction is
        # where it was last seen, frames ago, and a sibling 40 mm away can sit inside even the tight
        # gate around it (c3d_racing_propulsion, both scapula triads lost in frames 24-36 and 65-76:
        # ScapulaL2's place from frame 37 was 31-48 mm off and took ScapulaL1's or ScapulaL3's
        # point in frames 23, 63 and 64, 40-43 mm off, 3 of the run's 6 swaps).
        adrift = self._adrift(previous)
        idx = assign_to_predictions(np.where(adrift[:, None], np.nan, pred), points, gates[0], allowed=trusted)
        # Ambiguous two-view points: only within the tight gate of the motion prediction.
        free_points = ~trusted
        free_points[idx[idx >= 0]] = False
        more = assign_to_predictions(np.where(((idx < 0) & ~adrift)[:, None], pred, np.nan), points, gates[1],
                                     allowed=free_points)
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
