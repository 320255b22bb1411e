"""The skeleton fit's hinge bridging: hinges the measured markers leave undetermined for a
few frames are interpolated across them from the determined frames on both sides.

Split from :mod:`mocap.skeleton`: :meth:`~mocap.skeleton.SkeletonSolver.solve` fits every
frame, then calls :func:`bridge_fit` (unless ``bridge=False``), which proposes the
interpolated hinges (:func:`bridge_undetermined_hinges`) and keeps each only where it moves
no measured marker away from the fit.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

#: How far (mm) interpolating undetermined hinges may move a measured marker from the fit.
BRIDGE_TOLERANCE_MM = 1.0


def bridge_undetermined_hinges(q: np.ndarray, angle_std_rad: np.ndarray, valid: np.ndarray, times: np.ndarray,
                               max_std_rad: float, max_frames: int, context: int = 3) -> np.ndarray:
    """Hinge values interpolated across the frames where the markers do not determine them.

    Where a limb's markers are all hidden for a few frames, the per-frame fit holds its hinges
    near their previous values (the regularisation), and a swinging leg stays frozen: on the
    CMU walk seen by 4 cameras the right knee was 12 deg off for the 5 frames its markers were
    gone. A monotone cubic (PCHIP) through the determined frames on both sides of such a run
    follows the swing, as gap filling does for marker trajectories.

    Parameters
    ----------
    q : (F, nq) float
        Pinocchio configurations (root position, quaternion, hinges); hinge ``h`` is
        ``q[:, 7 + h]``.
    angle_std_rad : (F, H) float
        Predicted angle std per frame and hinge (NaN where unknown).
    valid : (F,) bool
        Solved frames.
    times : (F,) float
        Seconds.
    max_std_rad : float
        Above this a hinge is undetermined in that frame.
    max_frames : int
        Longest run of undetermined frames bridged; longer runs, and runs at the take's ends,
        are left as solved.
    context : int
        Determined frames used on each side of a run.

    Returns
    -------
    (F, H) float
        The interpolated hinge angles (rad); NaN where a hinge is left as solved.
    """
    F, H = angle_std_rad.shape
    t = np.asarray(times, dtype=np.float64)
    out = np.full((F, H), np.nan)
    for h in range(H):
        good = valid & (np.nan_to_num(angle_std_rad[:, h], nan=np.inf) <= max_std_rad)
        bad = valid & ~good
        f = 0
        while f < F:
            if not bad[f]:
                f += 1
                continue
            end = f
            while end < F and not good[end]:
                end += 1
            # run [f, end): undetermined or unsolved frames between determined ones
            before = np.flatnonzero(good[:f])[-context:]
            after = end + np.flatnonzero(good[end:])[:context]
            if end - f <= max_frames and len(before) and len(after) and before[-1] == f - 1 and after[0] == end:
                knots = np.concatenate([before, after])
                run = np.arange(f, end)[valid[f:end]]
                if len(knots) >= 2 and len(run):
                    out[run, h] = PchipInterpolator(t[knots], q[knots, 7 + h])(t[run])
            f = end
    return out


def bridge_fit(solver, q_out: np.ndarray, std: np.ndarray, valid: np.ndarray, times: np.ndarray, obs_all: np.ndarray,
               finite: np.ndarray, errors: np.ndarray, centres: np.ndarray) -> None:
    """Interpolate the undetermined hinges (:func:`bridge_undetermined_hinges`) of a fit of
    ``solver`` (a :class:`mocap.skeleton.SkeletonSolver`), in place.

    A hinge can be undetermined in one direction and still carry measured markers (two
    markers on a segment leave its twist free), so each hinge's interpolated value is kept
    only where it moves no measured marker away from the fit's by more than
    ``BRIDGE_TOLERANCE_MM``; ``errors`` and ``centres`` follow the changed frames."""
    p = solver.params
    proposed = bridge_undetermined_hinges(q_out, std, valid, times, np.radians(p.bridge_std_deg), p.bridge_max_frames)
    for f in np.flatnonzero(np.isfinite(proposed).any(axis=1)):
        ok = finite[f]
        base = errors[f, ok]
        q = q_out[f].copy()
        for h in np.flatnonzero(np.isfinite(proposed[f])):
            trial = q.copy()
            trial[7 + h] = proposed[f, h]
            err = 1000.0 * np.linalg.norm(solver.marker_positions(trial)[ok] - obs_all[f, ok], axis=1)
            if not err.size or np.max(err - base) <= BRIDGE_TOLERANCE_MM:
                q = trial
        if not np.array_equal(q, q_out[f]):
            q_out[f] = q
            errors[f, ok] = 1000.0 * np.linalg.norm(solver.marker_positions(q)[ok] - obs_all[f, ok], axis=1)
            centres[f] = solver.joint_centres(q)
