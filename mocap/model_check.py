"""The model check: which labelled 3D points the fitted skeleton cannot explain.

Inputs: labelled trajectories ``(F, M, 3)`` m, a :class:`mocap.skeleton.SkeletonSolver`.
Output: the skeleton fit and the trajectories without the points it cannot explain.

A wrong point (a ghost, or a neighbour's detection under another label) pulls the
least-squares fit towards it, so the fit then misses the *correct* points beside it too. Dropping
every point over the limit at once removes those as well: on CMU 94_15 (Indian dance) a
mislabelled left wrist pulled the forearm 12-24 mm off, and the correct elbow, forearm and
other wrist points (0.3-1.5 mm from the truth) were dropped with it in 8 frames. The check
therefore drops only each frame's worst point, refits, and repeats (as robust IK does); a frame
where more than ``max_drops`` points had to go is one the fit cannot be trusted on (three
wrong points on one leg let the fit twist the foot until a toe label on the heel's detection
fitted, CMU 135_04 frame 75), and there every point over the limit of the first fit goes.
(That costs correct points: on the CMU walk seen by 4 cameras, 91 of the 99 correct points the
check dropped were two-view points 5-9 mm from a first fit pulled by wrong ones. Dropping only
those over the full limit halved that on synthetic frames with 3-4 wrong leg or arm points, but
kept a wrong point in 1 of 12; trusting the last fit within half the limit kept 6: the refits
bend the limb to the wrong points. A wrong point costs more than a gap.) What the fallback
dropped is then judged again by the fit without any point over the first fit's limit, which no
wrong point over it has pulled: a point it explains comes back when, refitted with it, every kept
point of its frame still fits (:func:`_readmit`; on that walk 27 points came back, none wrong).
Where the fallback emptied a whole limb that fit cannot judge the limb's points (it holds the
limb near its last solved pose), so the rest of them are taken back one per frame and round,
the one the current fit misses least first, each only if, refitted with it, every kept point of
its frame still fits and another point vouches for it (:func:`_grow`): the limb is rebuilt from
the root outwards (on that walk frames 3-7 had the right arm's correct upper-arm and elbow points
dropped with a wrong wrist and finger).
"""

from __future__ import annotations

import numpy as np

from mocap.types import Trajectories


def model_markers(solver, fit, labels: list[str]) -> np.ndarray:
    """Markers of the fitted model ``(F, M, 3)`` m in ``labels`` order (NaN where unsolved)."""
    F = fit.q.shape[0]
    out = np.full((F, len(labels), 3), np.nan)
    order = [fit.marker_labels.index(n) if n in fit.marker_labels else -1 for n in labels]
    for f in range(F):
        if np.isfinite(fit.q[f]).all():
            pos = solver.marker_positions(fit.q[f])
            for j, i in enumerate(order):
                if i >= 0:
                    out[f, j] = pos[i]
    return out


def model_error_mm(solver, fit, traj: Trajectories) -> np.ndarray:
    """``(F, M)`` mm: distance of each labelled point from the fitted model's marker (NaN where
    either is missing); unlike ``fit.marker_errors_mm`` also for points left out of the fit."""
    return 1000.0 * np.linalg.norm(traj.xyz - model_markers(solver, fit, list(traj.labels)), axis=2)


def without_points(traj: Trajectories, drop: np.ndarray) -> Trajectories:
    """``traj`` with the points where ``drop (F, M)`` is True removed (gaps, 0 views)."""
    xyz = traj.xyz.copy()
    xyz[drop] = np.nan
    return Trajectories(list(traj.labels), xyz, traj.times, np.asarray(traj.filled, bool) & ~drop,
                        traj.residual_px, np.where(drop, 0, traj.n_views))


def view_limits_mm(max_mm: float) -> tuple[float, float]:
    """The model check's limit ``(two views, more views)`` in mm. A point from two views cannot
    check itself (any two rays meet within the epipolar gate): a partly hidden blob biases it by
    several millimetres unseen, so the model is held to half the tolerance there."""
    return 0.5 * max_mm, max_mm


def error_limit_mm(traj: Trajectories, max_mm: float) -> np.ndarray:
    """``(F, M)`` mm: the model check's limit per point (:func:`view_limits_mm`)."""
    two, more = view_limits_mm(max_mm)
    return np.where(np.asarray(traj.n_views) == 2, two, more)


def robust_skeleton_fit(traj: Trajectories, solver, max_mm: float, rounds: int = 4,
                        max_drops: int = 2, grow_rounds: int = 6) -> tuple[object, Trajectories]:
    """Fit, then up to ``rounds`` times drop each frame's worst point over the limit and refit.

    Parameters
    ----------
    traj : Trajectories
        Labelled points ``(F, M, 3)`` m.
    solver : mocap.skeleton.SkeletonSolver
    max_mm : float
        A point farther than this from the fitted model's marker is not explained (half of it
        for two-view points, :func:`error_limit_mm`).
    rounds : int
        Refits at most (each drops at most one point per frame).
    max_drops : int
        In a frame where more points than this had to go, every point over the limit of the
        first fit is dropped too.
    grow_rounds : int
        Rounds of :func:`_grow` in those frames (each takes back at most one point a frame).

    Returns
    -------
    fit : SkeletonFit
        The fit to the points kept.
    kept : Trajectories
        ``traj`` without the points the fit cannot explain.
    """
    limit = error_limit_mm(traj, max_mm)
    fit = solver.solve(traj, bridge=False)
    over_first = np.nan_to_num(model_error_mm(solver, fit, traj), nan=0.0) > limit
    drop = np.zeros(limit.shape, bool)
    rows = np.arange(len(limit))
    for _ in range(rounds):
        ratio = np.nan_to_num(model_error_mm(solver, fit, traj) / limit, nan=0.0)
        ratio[drop] = 0.0
        worst = ratio.argmax(axis=1)
        frames = np.flatnonzero(ratio[rows, worst] > 1.0)
        if len(frames) == 0:
            break
        drop[frames, worst[frames]] = True
        fit = solver.solve(without_points(traj, drop), bridge=False)
    bad = np.nan_to_num(model_error_mm(solver, fit, traj), nan=0.0) > limit
    untrusted = drop.sum(axis=1) > max_drops
    fallback = np.zeros_like(bad)
    fallback[untrusted] = over_first[untrusted] & ~bad[untrusted]
    bad |= fallback
    if not untrusted.any():
        return fit, without_points(traj, bad)
    fit, kept = _readmit(traj, solver, solver.solve(without_points(traj, bad), bridge=False), bad, fallback, limit)
    out = np.isfinite(traj.xyz[..., 0]) & ~np.isfinite(kept.xyz[..., 0])
    return _grow(traj, solver, fit, out, fallback & out, limit, grow_rounds)


def _readmit(traj: Trajectories, solver, fit, bad: np.ndarray, fallback: np.ndarray,
             limit: np.ndarray) -> tuple[object, Trajectories]:
    """Take back the points only the fallback dropped that the fit without every suspect point
    explains within the limit, in the frames where, refitted with them, every point kept still
    fits; returns ``(fit, kept)``.

    The fallback drops every point the first fit missed, and that fit was pulled by the wrong
    ones: on the CMU walk seen by 4 cameras, 91 of 99 correct points it dropped were two-view
    points 5-9 mm from it. The fit without all of them has seen no wrong point over the limit,
    so it does not bend towards one (trusting the rounds' last fit instead kept wrong points in
    6 of 12 synthetic frames: the refits had bent the limb to them). The second refit guards
    against a point the clean fit happens to explain but that pulls the rest off."""
    err = np.nan_to_num(model_error_mm(solver, fit, traj), nan=np.inf)
    back = fallback & (err <= limit)
    if not back.any():
        return fit, without_points(traj, bad)
    trial = bad & ~back
    refit = solver.solve(without_points(traj, trial), bridge=False)
    still = ~((np.nan_to_num(model_error_mm(solver, refit, traj), nan=0.0) > limit) & ~trial).any(axis=1)
    if not still.all():
        back &= still[:, None]
        trial = bad & ~back
        refit = solver.solve(without_points(traj, trial), bridge=False)
    return refit, without_points(traj, trial)


def _grow(traj: Trajectories, solver, fit, out: np.ndarray, candidates: np.ndarray, limit: np.ndarray,
          rounds: int) -> tuple[object, Trajectories]:
    """Take ``candidates`` (``(F, M)`` bool, among the points left ``out``) back one per frame and
    round, the one ``fit`` misses least (relative to its limit) first; one stays back only if,
    refitted with it, every kept point of its frame fits and another point vouches for it (see
    below). Returns ``(fit, kept)``."""
    out, candidates = out.copy(), candidates.copy()
    rows = np.arange(len(out))
    for _ in range(rounds):
        if not candidates.any():
            break
        ratio = np.nan_to_num(model_error_mm(solver, fit, traj) / limit, nan=np.inf)
        ratio[~candidates] = np.inf
        pick = ratio.argmin(axis=1)
        frames = np.flatnonzero(np.isfinite(ratio[rows, pick]))
        if len(frames) == 0:
            break
        trial = out.copy()
        trial[frames, pick[frames]] = False
        refit = solver.solve(without_points(traj, trial), bridge=False)
        after = np.nan_to_num(model_error_mm(solver, refit, traj), nan=np.inf) <= limit
        fits = ~(~after & ~trial & np.isfinite(traj.xyz[..., 0])).any(axis=1)
        # A point alone on a limb the fit leaves free always fits (one marker places its body), so
        # one comes back only where others vouch for it: the fit without it explained it already,
        # or with it the fit explains another candidate it did not explain before (RUPA placing
        # the upper arm explains RELB; a wrong foot point explains none of the foot's others).
        before = ratio <= 1.0
        vouched = before[frames, pick[frames]] | (after & ~before & candidates & trial)[frames].any(axis=1)
        back = frames[fits[frames] & vouched]
        candidates[frames, pick[frames]] = False
        if len(back):
            out[back, pick[back]] = False
            fit = solver.solve(without_points(traj, out), bridge=False)
    return fit, without_points(traj, out)
