"""The rules that keep a rigid group's labels (a plate or triad of markers whose distances hardly
vary) right from frame to frame: by its motion, its surroundings and its partner groups; and that
find a group lost whole again by its shape. A mixin of :class:`mocap.cluster_labelling.ClusterMarkerModel`,
which learns the groups from a labelled trial (``rigid_groups``, ``group_local``, ``group_reach``,
``group_context``, ``group_partners``, ``mean_dist_m``, ``shape_tol_m``)."""

from __future__ import annotations

from itertools import permutations

import numpy as np

from mocap.model_labelling import kabsch, match_rigid_cluster

__all__ = ["MAX_TURN_RAD", "PARTNER_MARGIN", "PARTNER_OUTSIDE", "RigidGroupRules"]

#: A rigid group may take a point from a label outside it only if that turns it less than this
#: since the previous frame (c3d_racing_propulsion's glove triads turn at most 46 deg a frame).
MAX_TURN_RAD = np.radians(60.0)

#: A rigid group's labels are taken for wrong where they turn it relative to a partner group by
#: more than this many times the trial's largest deviation: c3d_racing_propulsion's glove triads
#: with two labels exchanged turn 1.39-2.34 times it relative to their forearm triad; points 5 mm
#: off bend a 43 mm triad by about 0.15 times it.
PARTNER_OUTSIDE = 1.3

#: Without surroundings seen, a labelling within the trial's turn relative to the partner replaces
#: wrong ones only where every other turns at least this many times more.
PARTNER_MARGIN = 1.5


def _label_orderings(group: np.ndarray, n: int) -> np.ndarray:
    """``(P, n)`` every ordered choice of ``n`` labels of ``group``, in ``itertools.permutations`` order."""
    return np.array(list(permutations(group.tolist(), n)), dtype=np.intp).reshape(-1, n)


def _turn(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) of the rotation that takes points ``a`` onto ``b`` (least squares)."""
    R, _ = kabsch(a, b)
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


class RigidGroupRules:
    """Rigid-group labelling rules over the attributes a :class:`~mocap.cluster_labelling.ClusterMarkerModel` learns."""

    def _learn_partners(self, xyz: np.ndarray, ok: np.ndarray) -> list[list[tuple[int, np.ndarray, float]]]:
        """For each rigid group, the groups within 0.3 m whose orientation relative to it stayed
        within 90 deg of its mean over the trial: ``(other group, mean relative rotation, largest
        deviation (rad), at least the two groups' turn noise together, :meth:`_turn_noise`)``. A
        forearm triad and its glove's turn at the wrist up to 77-84 deg from their mean relative
        orientation (c3d_racing_propulsion); a glove triad's two labels
        exchanged turn it 180 deg about an axis in its plane, at least 96 deg from it."""
        rot = []
        for g, local in zip(self.rigid_groups, self.group_local):
            R = np.full((len(xyz), 3, 3), np.nan)
            for f in np.flatnonzero(ok[:, g].all(axis=1)):
                R[f] = kabsch(local, xyz[f, g])[0]
            rot.append(R)
        partners: list[list[tuple[int, np.ndarray, float]]] = [[] for _ in self.rigid_groups]
        noise = self._turn_noise()
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
                partners[a].append((b, mean, max(float(dev.max()), float(np.hypot(noise[a], noise[b])))))
        return partners

    def _turn_noise(self) -> np.ndarray:
        """Per rigid group, the turn (rad) that points off their markers by ``shape_tol_m`` (what
        its shape check lets through) can give its fitted orientation: the angle that tolerance
        subtends at the markers' RMS distance from the group's least determined axis (its longest).

        Why: the largest deviation over a near-static trial is noise, not a range of motion
        (Res16bits.c3d: 0.1-3 deg, against 2-9 deg of this), so reconstructed points turned a
        correctly labelled group "outside the trial" and its labels were given away (2 swaps and a
        91 mm error in `c3d_res16bits_static`'s first 0.9 s). A partner's limit is at least the two
        groups' turns together; c3d_racing_propulsion's partners' (29-84 deg) are all above it."""
        out = np.empty(len(self.group_local))
        for gi, local in enumerate(self.group_local):
            s = np.linalg.svd(local - local.mean(axis=0), compute_uv=False)
            out[gi] = np.arctan(self.shape_tol_m / max(float(np.sqrt((s[1:] ** 2).sum() / len(local))), 1e-9))
        return out

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
        partner_rot: dict = {}  # the partner groups' rotations on this frame's points
        for gi in range(len(self.rigid_groups)):
            idx = self._fit_surroundings(gi, idx, points)
            idx = self._fit_partners(gi, idx, points, partner_rot)
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
        shape = np.abs(self.mean_dist_m[perms[:, :, None], perms[:, None, :]] - d_now).max(axis=(1, 2))
        # The labellings that keep the shape within ``shape_tol_m``, or as well as the present one
        # where its points bend it more (blobs of a fast hand off by 6-7 mm: c3d_racing_propulsion's
        # right glove in frames 164 and 203 fitted no labelling within 5 mm, and GloveR1 and
        # GloveR2 stayed exchanged, the surroundings scoring 142 against 6 for the right labels).
        own = shape[np.flatnonzero((perms == have).all(axis=1))[0]]
        shape_ok = ~(shape > max(self.shape_tol_m, own))
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

    def _fit_partners(self, gi: int, idx: np.ndarray, points: np.ndarray, partner_rot: dict | None = None) -> np.ndarray:
        """Give a rigid group's points to other labels of it where its labels turn it, relative to a
        partner group (:meth:`_learn_partners`), clearly beyond anything the trial had
        (:data:`PARTNER_OUTSIDE` times its largest deviation) and another labelling lies within the
        trial's: the one whose surroundings fit four times better than any other within, or, with
        none of the surroundings seen, the one turning :data:`PARTNER_MARGIN` times less than any other.

        Why: motion keeps a group's labels only if they were right before, and a symmetric triad
        whose points smear for a frame or two (a fast hand, blobs 5 mm off their markers) can come
        out of it with two labels exchanged, which every later frame then keeps by turning least
        (c3d_racing_propulsion: the right glove's GloveR2 and GloveR3 in frames 7-24, the left
        glove's GloveL2 and GloveL3 in frames 67-81). The surroundings do not tell: the right glove's
        hand marker is unseen there, the left's moves 43 mm RMS in the glove's frame. Relative to
        the forearm triad, though, the glove turned at most 77-84 deg from its mean over the trial,
        and with two labels exchanged it turns 1.4-2.3 times that. The labellings of the same points
        are tried that keep the group's shape within ``shape_tol_m`` of how the present one keeps it
        (blobs off by 5 mm bend the triad by as much)."""
        g = self.rigid_groups[gi]
        have = g[idx[g] >= 0]
        if len(have) < 3 or not self.group_partners[gi]:
            return idx
        pts = idx[have]
        current = self._partner_deviation(gi, have, pts, idx, points, partner_rot)
        if current is None or current <= PARTNER_OUTSIDE:
            return idx
        q = points[pts]
        perms = _label_orderings(g, len(have))
        shape = np.abs(self.mean_dist_m[perms[:, :, None], perms[:, None, :]]
                       - np.linalg.norm(q[:, None] - q[None], axis=2)).max(axis=(1, 2))
        own = shape[np.flatnonzero((perms == have).all(axis=1))[0]]
        ctx, mu, spread = self.group_context[gi]
        seen = np.flatnonzero(idx[ctx] >= 0) if len(ctx) else np.zeros(0, int)
        rivals = []  # (deviation, surroundings score, labels) of every other labelling
        for labels in perms[shape <= own + self.shape_tol_m]:
            order = np.argsort(labels)
            dev = self._partner_deviation(gi, labels[order], pts[order], idx, points, partner_rot)
            if dev is None or np.array_equal(labels, have):
                continue
            score = np.inf
            if len(seen):
                R, t = kabsch(self.group_local[gi][np.searchsorted(g, labels)], q)
                loc = (points[idx[ctx[seen]]] - t) @ R
                score = float(np.mean((np.linalg.norm(loc - mu[seen], axis=1) / spread[seen]) ** 2))
            rivals.append((dev, score, labels))
        inside = sorted((r for r in rivals if r[0] <= 1.0), key=lambda r: r[1])
        if not inside:
            return idx
        if len(seen):
            # Within the trial's turn, a cyclic relabelling too (the glove's hand marker, 100 mm
            # off the triad's centre, moves 170 mm with it): the surroundings choose.
            if inside[0][1] > 9.0 or any(r[1] < 4.0 * inside[0][1] for r in inside[1:]):
                return idx
            labels = inside[0][2]
        else:
            rivals.sort(key=lambda r: r[0])
            if len(rivals) > 1 and rivals[1][0] < PARTNER_MARGIN * rivals[0][0]:
                return idx
            labels = rivals[0][2]
        idx = idx.copy()
        idx[have] = -1
        idx[labels] = pts
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
            elif (dev := self._partner_deviation(gi, labels, pts, idx, points)) is not None and dev > PARTNER_OUTSIDE:
                # A lone placement that turns the group relative to a partner beyond anything the
                # trial had is another group's points: c3d_racing_propulsion's right scapula triad,
                # two of its markers seen, fitted the left triad's three points with only Head1
                # (56 mm spread) around it, and without this both triads came back mirrored for frames 0-23
                # (the run's RMSE 34 mm).
                continue
            idx[have] = -1
            idx[labels] = pts
        return idx

    def _partner_deviation(self, gi: int, labels: np.ndarray, pts: np.ndarray, idx: np.ndarray,
                           points: np.ndarray, partner_rot: dict | None = None) -> float | None:
        """How far group ``gi`` with ``labels`` on points ``pts`` turns from where the trial had it
        relative to its fully labelled partners (:meth:`_learn_partners`) that keep their shape:
        the largest deviation over them, as a fraction of the trial's largest; None without any.
        ``partner_rot``: the partners' rotations already found on these ``points``
        (:meth:`_partner_rotation`)."""
        worst = None
        R = None
        for gj, mean, limit in self.group_partners[gi]:
            R_other = self._partner_rotation(gj, idx, points, partner_rot)
            if R_other is None:
                continue
            if R is None:  # the same for every partner
                g = self.rigid_groups[gi]
                R = kabsch(self.group_local[gi][np.searchsorted(g, labels)], points[pts])[0]
            rel = R.T @ R_other
            dev = float(np.arccos(np.clip((np.trace(rel @ mean.T) - 1.0) / 2.0, -1.0, 1.0))) / limit
            worst = dev if worst is None else max(worst, dev)
        return worst

    def _partner_rotation(self, gj: int, idx: np.ndarray, points: np.ndarray,
                          partner_rot: dict | None) -> np.ndarray | None:
        """Group ``gj``'s rotation on its labelled points, or None unless every member is labelled
        and the points keep its shape (a partner on a wrong point would turn the other group wrong).

        Kept in ``partner_rot`` (one frame's ``points``), keyed by the group and its points: a
        group is the partner of some 14 others, each of whose labellings asks for it, and
        recomputing it was two thirds of labelling a real capture (Res16bits.c3d, frames 50-99:
        202 434 Kabsch fits, 50 of 75 profiled seconds; 61 606 fits with this)."""
        other = self.rigid_groups[gj]
        on = idx[other]
        if not (on >= 0).all():
            return None
        key = (gj, on.tobytes())
        if partner_rot is not None and key in partner_rot:
            return partner_rot[key]
        q = points[on]
        shape = np.linalg.norm(q[:, None] - q[None], axis=2) - self.mean_dist_m[np.ix_(other, other)]
        R_other = None if np.abs(shape).max() > self.shape_tol_m else kabsch(self.group_local[gj], q)[0]
        if partner_rot is not None:
            partner_rot[key] = R_other
        return R_other

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
