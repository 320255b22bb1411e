"""The motion check: labelled 3D points of markers alone on their body that no limb could have reached.

Inputs: labelled trajectories ``(F, M, 3)`` m with their times, which labels to judge, a speed
limit. Output: the measured samples to veto ``(F, M)`` bool, or the trajectories without them.

The model check (:mod:`mocap.model_check`) judges a point by the subject's other markers: on a
body with two or more markers a point off its body is off the fit. A marker alone on its body
(every marker of the 15-marker ``sparse_joints`` set but those sharing the thorax or a thigh;
the fingers of Plug-in Gait) is placed by its own point: the joints above it turn until the
model meets it wherever the limb can reach, and a wrist label on the head marker's blobs
(a hand on the head is a pose the arm can take) is "explained". Motion can still judge it: a
label whose point moves faster than any limb can has a wrong point on one side of that step.

The limit is on speed between a label's measured samples, however far apart in time (a gap
allows more distance). The fastest true marker speeds in the bench's motions are 10.7 m/s
(a toe in the CMU kick), 10.1 (a toe in the CMU walk), 8.7 (Indian dance), 4.8 (a wrist in
dim_gym_noisy's jumping jacks); punches and kicks reach 10-14 m/s. The default limit
(:data:`MAX_MARKER_SPEED_MPS`, 15 m/s: 0.5 m between two frames at 30 fps) is several m/s beyond
them; a wrist label that moves to the head marker 0.8-0.9 m away in one frame (25-28 m/s) is
over it, one that takes three frames for it (7 m/s) is not (at 30 fps no speed limit a real
limb keeps can tell that from motion).

Which side of a too-fast step is wrong: the steps over the limit cut the label's samples into
runs. A run the label leaves by such a step and returns from (the samples just before and just
after it are within the limit of each other across the run's time) is an excursion and goes.
A run at the start or end of the take never returns; it goes when it has fewer samples than the
run it jumps from or to (the label spent less of the take there). Runs are judged the smallest
first, one at a time, and the runs recut after each. Only measured samples are judged (a gap
fill is a spline through its neighbours, wrong ones included); a label that lost samples has its
gap fills made again without them (:func:`without_motion_outliers`).

On dim_gym_noisy's stored detections (4 cameras, 60 frames) this vetoes 35 samples: RWRI frames
43-59 (the label on the head marker's blobs, 250-950 mm off; it entered them by an 18 m/s step
and never came back) and 18 of LWRI's frames 29-59, 13 of them wrong (300-1200 mm off, with 14-20
m/s steps between them) and 5 right (29-31 and 58-59). That is the end-run rule's weakness: it
counts samples, and LWRI's run of frames 29-48 (3 right, 9 wrong) had fewer than its frames 0-28
(18 right, 3 wrong); a wrong point over the limit on one side only can cost the right run beside
it in the same way. The run's RMSE goes from 157 to 10 mm (swaps 5 -> 0) with the
same 493 points within 20 mm of the truth. What it cannot see: LWRI's wrong points of frames 22,
25 and 28 and RWRI's of frame 26 are 3-4 frames from right ones, 4-7 m/s away (a wrist in those
jumping jacks moves at up to 4.8 m/s), and still bend the fit of frames 23-28 until the model
check's fallback leaves 0-1 points a frame there. On the other stored takes (Plug-in Gait: only the
fingers are alone on their body) nothing is vetoed.
"""

from __future__ import annotations

import numpy as np

from mocap.smoothing import fill_gaps
from mocap.types import Trajectories

#: Default speed limit of a marker (m/s); see the module's docstring for the numbers behind it.
MAX_MARKER_SPEED_MPS = 15.0


def lone_markers(subject, labels: list[str]) -> np.ndarray:
    """``(M,)`` bool: labels of markers that are the only one of ``labels`` on their body in
    ``subject`` (:class:`mocap.subject.SubjectModel`); unknown labels are False."""
    body = {m.name: m.body for m in subject.markers}
    bodies = [body.get(n) for n in labels]
    return np.array([b is not None and bodies.count(b) == 1 for b in bodies], bool)


def too_fast(xyz: np.ndarray, times: np.ndarray, ok: np.ndarray, max_speed_mps: float) -> np.ndarray:
    """``(F,)`` bool: the samples of one label (``xyz (F, 3)`` m at ``times (F,)`` s, ``ok (F,)``
    the samples to judge) on runs that :func:`motion_outliers` vetoes: runs entered or left by a
    step faster than ``max_speed_mps`` that return (interior runs whose neighbours are within the
    limit of each other) or that are shorter than the run beside them (at the take's start or end);
    see the module's docstring."""
    t = np.asarray(times, float)
    keep = np.asarray(ok, bool).copy()
    while True:
        fr = np.flatnonzero(keep)
        if len(fr) < 2:
            break
        step = np.linalg.norm(np.diff(xyz[fr], axis=0), axis=1)
        cuts = np.flatnonzero(step > max_speed_mps * np.diff(t[fr])) + 1
        if len(cuts) == 0:
            break
        runs = np.split(np.arange(len(fr)), cuts)
        worst = None
        for i, run in enumerate(runs):
            if 0 < i < len(runs) - 1:
                a, b = fr[runs[i - 1][-1]], fr[runs[i + 1][0]]
                goes = np.linalg.norm(xyz[b] - xyz[a]) <= max_speed_mps * (t[b] - t[a])
            else:
                goes = len(run) < len(runs[1] if i == 0 else runs[-2])
            if goes and (worst is None or len(run) < len(runs[worst])):
                worst = i
        if worst is None:
            break
        keep[fr[runs[worst]]] = False
    return np.asarray(ok, bool) & ~keep


def motion_outliers(traj: Trajectories, judge: np.ndarray, max_speed_mps: float = MAX_MARKER_SPEED_MPS) -> np.ndarray:
    """``(F, M)`` bool: measured samples (not gap fills) of the labels ``judge (M,)`` that moved
    faster than ``max_speed_mps`` from the label's other samples and did not come back
    (:func:`too_fast`)."""
    filled = np.zeros(traj.xyz.shape[:2], bool) if traj.filled is None else np.asarray(traj.filled, bool)
    measured = np.isfinite(traj.xyz).all(axis=2) & ~filled
    out = np.zeros(measured.shape, bool)
    for m in np.flatnonzero(judge):
        out[:, m] = too_fast(traj.xyz[:, m], traj.times, measured[:, m], max_speed_mps)
    return out


def without_motion_outliers(traj: Trajectories, veto: np.ndarray, max_gap_frames: int, method: str,
                            context_frames: int) -> Trajectories:
    """``traj`` without the samples ``veto (F, M)``; a label that lost any has its gap fills made
    again from its other measured samples (the old ones were splines through the vetoed points),
    with :func:`mocap.smoothing.fill_gaps`' ``max_gap_frames``, ``method`` and ``context_frames``."""
    cols = np.flatnonzero(veto.any(axis=0))
    if len(cols) == 0:
        return traj
    xyz = traj.xyz.copy()
    filled = np.zeros(veto.shape, bool) if traj.filled is None else np.asarray(traj.filled, bool).copy()
    n_views = np.where(veto, 0, traj.n_views) if traj.n_views is not None else None
    residual = np.where(veto, np.nan, traj.residual_px) if traj.residual_px is not None else None
    sub = xyz[:, cols].copy()
    sub[veto[:, cols] | filled[:, cols]] = np.nan
    refilled, new = fill_gaps(sub, traj.times, max_gap_frames, method, context_frames) if max_gap_frames > 0 else (sub, np.zeros(sub.shape[:2], bool))
    xyz[:, cols] = refilled
    filled[:, cols] = new
    if n_views is not None:
        n_views[:, cols] = np.where(new, 0, n_views[:, cols])
    return Trajectories(list(traj.labels), xyz, traj.times, filled, residual, n_views)
