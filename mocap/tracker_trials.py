"""Seed 000's failure categories as synthetic 2D trials: a quick robustness check of the trackers.

:func:`synthetic_trial` draws a short 2D sequence of one of seed 000's categories
(``slow``, ``rapid`` zigzags, ``acceleration``, ``occlusion`` by a barrier, ``swap`` of two
markers crossing closely, whose blobs merge when they overlap -- both labelled, or, as in
seed 000, a labelled marker and an unlabelled one) directly as detections,
without rendering; :func:`run_robustness_check` counts per category and tracker the
videos in which a label lost its marker. The rendered study (``simbench study
trackers``) is the reference; this is the fast stand-in used by the tests and while
tuning a tracker.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mocap.trackers import available_trackers
from mocap.tracking import track_camera

__all__ = ["CATEGORIES", "IMAGE_SIZE", "SyntheticTrial", "synthetic_trial", "trial_losses", "run_trial",
           "RobustnessTable", "run_robustness_check", "format_robustness_table"]

#: Seed 000's five categories of test video (Table I).
CATEGORIES = ("slow", "rapid", "acceleration", "occlusion", "swap")
IMAGE_SIZE = (640, 480)  # (width, height) px of the synthetic image


@dataclass
class SyntheticTrial:
    """One synthetic 2D test video, as detections.

    Attributes
    ----------
    category : str
    true_xy : (F, M, 2) float
        True marker positions, px; the first ``n_labels`` markers are labelled, the
        others are unlabelled blobs (seed 000's "NULL" marker).
    visible : (F, M) bool
        Marker detectable on its own (not behind the barrier, not merged with another).
    detections : list of F (n, 2) float arrays
        Detected centroids, px, shuffled.
    owner : list of F (n,) int arrays
        Marker index of each detection, -1 for merged blobs.
    dt : float
        Frame interval, s.
    """

    category: str
    true_xy: np.ndarray
    visible: np.ndarray
    detections: list[np.ndarray]
    owner: list[np.ndarray]
    dt: float
    n_labels: int


def _integrate(start: np.ndarray, speed: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """(F, 2) positions from a start point and per-frame speeds (px/frame) and headings (rad)."""
    step = np.stack([speed * np.cos(heading), speed * np.sin(heading)], axis=1)
    return start + np.concatenate([np.zeros((1, 2)), np.cumsum(step[:-1], axis=0)])


def _zigzag(n_frames: int, rng: np.random.Generator) -> np.ndarray:
    W, H = IMAGE_SIZE
    margin = 40.0
    speed = rng.uniform(8.0, 14.0)  # px/frame
    pos = np.array([rng.uniform(200, W - 200), rng.uniform(150, H - 150)])
    heading = rng.uniform(0, 2 * np.pi)
    out = np.empty((n_frames, 2))
    left = int(rng.integers(5, 11))
    for f in range(n_frames):  # generation only, not a hot path
        out[f] = pos
        left -= 1
        if left == 0:  # zigzag corner: turn sharply, either way
            heading += rng.choice([-1.0, 1.0]) * rng.uniform(np.radians(90), np.radians(160))
            left = int(rng.integers(5, 11))
        nxt = pos + speed * np.array([np.cos(heading), np.sin(heading)])
        if not margin <= nxt[0] <= W - margin:
            heading = np.pi - heading
        if not margin <= nxt[1] <= H - margin:
            heading = -heading
        pos = pos + speed * np.array([np.cos(heading), np.sin(heading)])
    return out


def synthetic_trial(category: str, rng: np.random.Generator, n_frames: int = 80, noise_px: float = 0.2,
                    merge_px: float = 6.0, dt: float = 1.0 / 30.0) -> SyntheticTrial:
    """Draw one synthetic test sequence of a seed 000 category.

    Parameters
    ----------
    category : {"slow", "rapid", "acceleration", "occlusion", "swap"}
    rng : numpy.random.Generator
    n_frames : int, default 80
    noise_px : float, default 0.2
        Detection noise, px.
    merge_px : float, default 6.0
        Two markers closer than this give one blob, detected at their midpoint.
    dt : float, default 1/30

    Returns
    -------
    SyntheticTrial
    """
    F = n_frames
    barrier = None
    if category == "slow":
        xy = _slow_path(F, rng)
    elif category == "rapid":
        xy = _zigzag(F, rng)[:, None]
    elif category == "acceleration":
        xy = _acceleration_path(F, rng)
    elif category == "occlusion":
        xy, barrier = _occlusion_path(F, rng)
    elif category == "swap":
        xy = _crossing_paths(F, rng)
    else:
        raise ValueError(f"unknown category {category!r}; expected one of {', '.join(CATEGORIES)}")

    M = xy.shape[1]
    n_labels = M
    if category == "swap" and rng.random() < 0.5:
        n_labels = 1  # seed 000's variant: the second marker is unlabelled ("NULL")
    visible = np.ones((F, M), dtype=bool)
    if barrier is not None:
        visible &= ~((xy[..., 0] > barrier[0]) & (xy[..., 0] < barrier[1]))
    merged = np.zeros((F, M), dtype=bool)
    if M == 2:
        merged[:] = (np.linalg.norm(xy[:, 0] - xy[:, 1], axis=1) < merge_px)[:, None]
    dets, owners = _detect(xy, visible, merged, noise_px, rng)
    return SyntheticTrial(category, xy, visible & ~merged, dets, owners, dt, n_labels)


def _slow_path(F: int, rng: np.random.Generator) -> np.ndarray:
    """"slow": one marker at 1.5-3.5 px/frame near the image centre, turning gently; ``(F, 1, 2)`` px."""
    W, H = IMAGE_SIZE
    t = np.arange(F)
    speed = np.full(F, rng.uniform(1.5, 3.5))
    turn = rng.uniform(0.03, 0.08) * np.sin(2 * np.pi * t / rng.uniform(25, 60))  # rad/frame
    heading = rng.uniform(0, 2 * np.pi) + np.cumsum(turn)
    return _integrate(np.array([W / 2, H / 2]) + rng.uniform(-60, 60, 2), speed, heading)[:, None]


def _acceleration_path(F: int, rng: np.random.Generator) -> np.ndarray:
    """"acceleration": one marker speeding up from ~1 to ~11 px/frame (or braking), across the image; ``(F, 1, 2)`` px."""
    W, H = IMAGE_SIZE
    t = np.arange(F)
    s0, s1 = rng.uniform(0.5, 1.5), rng.uniform(9.0, 13.0)
    speed = s0 + (s1 - s0) * (t / (F - 1)) ** rng.uniform(1.0, 2.0)
    if rng.random() < 0.5:  # braking instead of speeding up
        speed = speed[::-1]
    heading = rng.uniform(-0.4, 0.4) + np.cumsum(np.full(F, rng.uniform(-0.01, 0.01)))
    dist = speed.sum()
    x0 = (W - dist * np.cos(heading).mean()) / 2
    xy = _integrate(np.array([x0, H / 2 + rng.uniform(-60, 60)]), speed, heading)[:, None]
    if rng.random() < 0.5:  # right to left
        xy[..., 0] = W - xy[..., 0]
    return xy


def _occlusion_path(F: int, rng: np.random.Generator) -> tuple[np.ndarray, tuple[float, float]]:
    """"occlusion": one marker at 4-7 px/frame behind a vertical barrier 30-110 px wide at the image centre.

    Returns the path ``(F, 1, 2)`` px and the barrier's ``(x_left, x_right)`` px.
    """
    W, H = IMAGE_SIZE
    width = rng.uniform(30.0, 110.0)  # barrier width, px
    speed = np.full(F, rng.uniform(4.0, 7.0))
    curved = rng.random() < 0.5
    turn = np.full(F, rng.uniform(-0.012, 0.012) if curved else 0.0)
    heading = rng.uniform(-0.3, 0.3) + np.cumsum(turn) - turn[0]
    start = np.array([W / 2 - speed[0] * F / 2, H / 2 + rng.uniform(-50, 50)])
    xy = _integrate(start, speed, heading)[:, None]
    return xy, (W / 2 - width / 2, W / 2 + width / 2)


def _crossing_paths(F: int, rng: np.random.Generator) -> np.ndarray:
    """"swap": two markers on straight lines crossing at 5-25 deg, 0-4 px apart, mid-sequence; ``(F, 2, 2)`` px."""
    W, H = IMAGE_SIZE
    t = np.arange(F)
    angle = np.radians(rng.uniform(5.0, 25.0))  # crossing angle
    speeds = rng.uniform(3.0, 6.0, 2)
    base = rng.uniform(0, 2 * np.pi)
    headings = base + np.array([-angle / 2, angle / 2])
    miss = rng.uniform(0.0, 4.0)  # closest distance at the crossing, px
    t_cross = F / 2 + rng.uniform(-5, 5)
    centre = np.array([W / 2, H / 2])
    normal = np.array([-np.sin(base), np.cos(base)])
    xy = np.empty((F, 2, 2))
    for k in range(2):  # two markers
        v = speeds[k] * np.array([np.cos(headings[k]), np.sin(headings[k])])
        xy[:, k] = centre + (k - 0.5) * miss * normal + (t[:, None] - t_cross) * v
    return xy


def _detect(xy: np.ndarray, visible: np.ndarray, merged: np.ndarray, noise_px: float,
            rng: np.random.Generator) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Noisy detections of the markers ``xy (F, M, 2)`` px, in random order per frame.

    A marker is detected where ``visible (F, M)`` and not ``merged (F, M)``; merged markers
    that are all visible give one blob at their mean (owner -1). Returns per frame the
    detections ``(n, 2)`` px and their owners ``(n,)`` (marker index or -1).
    """
    noisy = xy + rng.normal(0.0, noise_px, xy.shape)
    dets, owners = [], []
    for f in range(len(xy)):
        own = np.flatnonzero(visible[f] & ~merged[f])
        pts = [noisy[f, own]]
        ids = [own]
        if merged[f].any() and visible[f].all():
            pts.append(noisy[f].mean(axis=0, keepdims=True))
            ids.append(np.array([-1]))
        p, i = np.concatenate(pts), np.concatenate(ids)
        order = rng.permutation(len(p))
        dets.append(p[order])
        owners.append(i[order])
    return dets, owners


def trial_losses(trial: SyntheticTrial, idx: np.ndarray) -> np.ndarray:
    """(M,) bool: labels that ever missed or took a wrong detection while visible.

    Parameters
    ----------
    idx : (F, M) int
        Detection index chosen by each label per frame (-1 for none).
    """
    F, M = idx.shape
    lost = np.zeros(M, dtype=bool)
    for f in range(1, F):
        owner = np.append(trial.owner[f], -2)  # index -1 (no detection) -> owner -2
        own = owner[idx[f]]
        lost |= trial.visible[f, :M] & (own != np.arange(M))
    return lost


def run_trial(trial: SyntheticTrial, tracker: str, rng: np.random.Generator, **params) -> tuple[np.ndarray, np.ndarray]:
    """Track a synthetic trial from its true first-frame positions.

    Returns
    -------
    idx : (F, M) int
        Detection index per label and frame (M = ``trial.n_labels``).
    predicted : (F, M, 2) float
        Prior prediction per label and frame, px.
    """
    M = trial.n_labels
    res = track_camera(trial.detections, trial.true_xy[0, :M], [f"m{m}" for m in range(M)], tracker, trial.dt, rng, **params)
    idx = res.index
    return idx, res.predicted


@dataclass
class RobustnessTable:
    """Result of :func:`run_robustness_check`.

    Attributes
    ----------
    losses : dict category -> dict tracker -> int
        Videos in which some label lost its marker.
    prediction_error_px : dict category -> dict tracker -> float
        Mean distance between prediction and true position over visible frames of the
        videos without a loss (seed 000 Tables II-IV), px.
    videos_per_category : int
    """

    losses: dict[str, dict[str, int]]
    prediction_error_px: dict[str, dict[str, float]]
    videos_per_category: int


def run_robustness_check(trackers: Sequence[str] | None = None, videos_per_category: int = 20, n_frames: int = 80,
                         seed: int = 0, categories: Sequence[str] = CATEGORIES) -> RobustnessTable:
    """Count losses per category and tracker on synthetic 2D trials (same trials for all)."""
    names = list(trackers) if trackers is not None else available_trackers()
    losses = {c: {n: 0 for n in names} for c in categories}
    errors: dict[str, dict[str, list[float]]] = {c: {n: [] for n in names} for c in categories}
    root = np.random.default_rng(seed)
    for c in categories:
        for trial_rng in root.spawn(videos_per_category):
            trial = synthetic_trial(c, trial_rng, n_frames)
            for n in names:
                idx, pred = run_trial(trial, n, np.random.default_rng(0))
                if trial_losses(trial, idx).any():
                    losses[c][n] += 1
                else:
                    M = trial.n_labels
                    err = np.linalg.norm(pred[2:] - trial.true_xy[2:, :M], axis=-1)[trial.visible[2:, :M]]
                    errors[c][n].extend(err.tolist())
    mean_err = {c: {n: float(np.mean(v)) if v else float("nan") for n, v in d.items()} for c, d in errors.items()}
    return RobustnessTable(losses, mean_err, videos_per_category)


def format_robustness_table(table: RobustnessTable) -> str:
    """Seed 000 Table I layout (losses per category), plus mean prediction errors."""
    names = list(next(iter(table.losses.values())))
    lines = [f"Videos with a lost label (of {table.videos_per_category} per category)",
             f"{'':14s}" + "".join(f"{n:>14s}" for n in names)]
    for c, row in table.losses.items():
        lines.append(f"{c:14s}" + "".join(f"{row[n]:>14d}" for n in names))
    lines.append(f"{'total':14s}" + "".join(f"{sum(r[n] for r in table.losses.values()):>14d}" for n in names))
    lines.append("")
    lines.append("Mean prediction error, px (videos without a loss)")
    for c, row in table.prediction_error_px.items():
        lines.append(f"{c:14s}" + "".join(f"{row[n]:>14.2f}" for n in names))
    return "\n".join(lines) + "\n"
