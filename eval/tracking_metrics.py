"""2D label tracking scored against ground truth (seed 000's measures): arrays in, numbers out.

Definitions (the same for every tracker, category and video):

* **Loss** of a label in a video: at some frame ``f >= start_frame`` (frame 0 is the
  manual initialisation from the true positions) where its marker is *visible*, one of

  - ``"lost"``: the tracker declared the label lost (status 0);
  - ``"far"``: the label's posterior estimate is more than ``radius_px`` from the
    marker's true image position (this covers a label coasting away from a marker it
    no longer sees, and a label that followed the wrong marker once they separated);
  - ``"other"``: the label took a detection nearer to *another* marker's true position
    than to its own while the two markers are more than ``radius_px`` apart (a swap,
    caught at the frame it happens; closer markers give one merged blob, which is
    nobody's and counts for neither).

  :func:`label_losses` returns, per label, whether it was lost, the first such frame and
  the reason there, how many frames were bad and whether the label was still off at its
  marker's last visible frame (a loss it never recovered from); a video counts one loss
  in seed 000's Table I when any label was lost (:func:`video_lost`).
* **Prediction error** (Tables II-IV): distance in pixels between a label's predicted
  position (the prior, before the frame's update) and its measured position (the
  detection associated with it), over the frames ``>= start_frame`` where the label had a
  detection (:func:`prediction_errors`).
* **99 % confidence interval** of the mean prediction error: Student's t interval,
  ``mean +- t(0.995, n-1) * s / sqrt(n)`` (:func:`mean_confidence_interval`), with the
  Shapiro-Wilk test of normality of the errors (:func:`shapiro_wilk`), as the paper
  reports them.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Iterable, Mapping

import numpy as np
from scipy import stats

from mocap.types import LOST

#: Reason codes of :class:`LabelLosses` (``reason`` and the per-frame ``flags``).
REASON_NONE = 0
REASON_LOST = 1
REASON_FAR = 2
REASON_OTHER = 3
REASON_NAMES = {REASON_NONE: "", REASON_LOST: "lost", REASON_FAR: "far", REASON_OTHER: "other"}


@dataclass(frozen=True)
class LabelLosses:
    """Loss of each label in one video (see the module docstring).

    Attributes
    ----------
    lost : (M,) bool
        Label lost at least once.
    first_frame : (M,) int
        First frame of the loss, -1 for labels never lost.
    reason : (M,) int
        Reason code at the first frame (:data:`REASON_LOST`, ``_FAR``, ``_OTHER``; 0 none).
    flags : (F, M) int
        Reason code of every frame (0 where the label was fine or the marker not
        visible); where several apply, the lowest code wins (lost < far < other).
    bad_frames : (M,) int
        Number of scored frames with a loss.
    at_end : (M,) bool
        Still lost at the marker's last visible frame (not recovered).
    """

    lost: np.ndarray
    first_frame: np.ndarray
    reason: np.ndarray
    flags: np.ndarray
    bad_frames: np.ndarray
    at_end: np.ndarray

    def reason_names(self) -> list[str]:
        """Reason of each label's first loss as text (``""`` when not lost)."""
        return [REASON_NAMES[int(r)] for r in self.reason]


def label_losses(
    true_xy: np.ndarray,
    visible: np.ndarray,
    estimate: np.ndarray,
    status: np.ndarray,
    measured_xy: np.ndarray,
    radius_px: float,
    start_frame: int = 1,
) -> LabelLosses:
    """Which labels lost their marker in one video, when and why.

    Parameters
    ----------
    true_xy : (F, M, 2) float
        True image position of each labelled marker, px.
    visible : (F, M) bool
        Marker visible (detectable on its own) in that frame.
    estimate : (F, M, 2) float
        Each label's posterior estimate after the frame's update, px (NaN while lost).
    status : (F, M) int
        Tracker status, 0 lost, 1 tracked, 2 coasting.
    measured_xy : (F, M, 2) float
        Detection associated with each label, px; NaN where it had none.
    radius_px : float
        Loss radius, px (> 0).
    start_frame : int, default 1
        First frame scored (frame 0 is the initialisation).

    Returns
    -------
    LabelLosses
    """
    true_xy = np.asarray(true_xy, dtype=np.float64)
    F, M = true_xy.shape[:2]
    shapes = {"visible": (np.shape(visible), (F, M)), "estimate": (np.shape(estimate), (F, M, 2)),
              "status": (np.shape(status), (F, M)), "measured_xy": (np.shape(measured_xy), (F, M, 2))}
    for name, (got, want) in shapes.items():
        if tuple(got) != want:
            raise ValueError(f"{name} must have shape {want} to match true_xy {true_xy.shape}, got {tuple(got)}")
    if not radius_px > 0:
        raise ValueError(f"radius_px must be > 0, got {radius_px}")
    if not 0 <= start_frame:
        raise ValueError(f"start_frame must be >= 0, got {start_frame}")
    vis = np.asarray(visible, dtype=bool).copy()
    vis[:start_frame] = False
    est = np.asarray(estimate, dtype=np.float64)
    meas = np.asarray(measured_xy, dtype=np.float64)
    stat = np.asarray(status)

    is_lost = stat == LOST
    err = np.linalg.norm(est - true_xy, axis=-1)  # (F, M) px, NaN while lost
    far = ~is_lost & ~(err <= radius_px)  # NaN estimate of a not-lost label is far too
    # Distances of each label's detection to every marker (F, M labels, M markers).
    d = np.linalg.norm(meas[:, :, None, :] - true_xy[:, None, :, :], axis=-1)
    sep = np.linalg.norm(true_xy[:, :, None, :] - true_xy[:, None, :, :], axis=-1)  # (F, M, M)
    own = np.einsum("fmm->fm", d)
    eye = np.eye(M, dtype=bool)[None]
    nearer_other = (d < own[:, :, None]) & (sep > radius_px) & ~eye
    other = nearer_other.any(axis=2) & np.isfinite(own)

    flags = np.zeros((F, M), dtype=np.int64)
    flags[other] = REASON_OTHER
    flags[far] = REASON_FAR
    flags[is_lost] = REASON_LOST
    flags[~vis] = REASON_NONE
    bad = flags > 0
    lost = bad.any(axis=0)
    first = np.where(lost, bad.argmax(axis=0), -1)
    reason = np.where(lost, flags[np.maximum(first, 0), np.arange(M)], REASON_NONE)
    seen = vis.any(axis=0)
    last = F - 1 - vis[::-1].argmax(axis=0)  # last visible frame of each marker
    at_end = seen & bad[last, np.arange(M)]
    return LabelLosses(lost=lost, first_frame=first, reason=reason, flags=flags,
                       bad_frames=bad.sum(axis=0), at_end=at_end)


def video_lost(losses: LabelLosses) -> bool:
    """A video counts one loss (seed 000's Table I) when any of its labels was lost."""
    return bool(np.any(losses.lost))


def merged_markers(true_xy: np.ndarray, merge_px: float) -> np.ndarray:
    """(F, M) bool: markers with another marker closer than ``merge_px`` in the image
    (their blobs merge into one, so neither is visible on its own).

    Parameters
    ----------
    true_xy : (F, M, 2) float
        True image positions, px.
    merge_px : float
        Centre distance below which two blobs merge, px.
    """
    xy = np.asarray(true_xy, dtype=np.float64)
    d = np.linalg.norm(xy[:, :, None, :] - xy[:, None, :, :], axis=-1)  # (F, M, M)
    d[:, np.arange(xy.shape[1]), np.arange(xy.shape[1])] = np.inf
    return (d < merge_px).any(axis=2)


def count_losses(records: Iterable[tuple[str, str, bool]]) -> dict[str, dict[str, int]]:
    """Table I from per-video records.

    Parameters
    ----------
    records : iterable of (category, tracker, video_lost)

    Returns
    -------
    dict category -> dict tracker -> int
        Number of videos with a loss (categories and trackers in first-seen order).
    """
    table: dict[str, dict[str, int]] = {}
    for category, tracker, lost in records:
        row = table.setdefault(category, {})
        row[tracker] = row.get(tracker, 0) + int(bool(lost))
    return table


def total_losses(table: Mapping[str, Mapping[str, int]]) -> dict[str, int]:
    """Sum of a Table I over categories, per tracker."""
    out: dict[str, int] = {}
    for row in table.values():
        for tracker, n in row.items():
            out[tracker] = out.get(tracker, 0) + int(n)
    return out


def prediction_errors(predicted: np.ndarray, measured: np.ndarray, start_frame: int = 1) -> np.ndarray:
    """Distances between predicted and measured positions, px.

    Parameters
    ----------
    predicted : (F, M, 2) float
        Prior prediction of each label before the frame's update, px.
    measured : (F, M, 2) float
        Detection associated with each label, px (NaN where none).
    start_frame : int, default 1
        Frame 0 holds the initial positions, not a prediction.

    Returns
    -------
    (n,) float
        One distance per frame ``>= start_frame`` and label with both positions finite,
        frame-major order.
    """
    predicted = np.asarray(predicted, dtype=np.float64)
    measured = np.asarray(measured, dtype=np.float64)
    if predicted.shape != measured.shape or predicted.ndim != 3 or predicted.shape[-1] != 2:
        raise ValueError(f"predicted and measured must both be (F, M, 2), got {predicted.shape} and {measured.shape}")
    e = np.linalg.norm(predicted[start_frame:] - measured[start_frame:], axis=-1)
    return e[np.isfinite(e)]


@dataclass(frozen=True)
class MeanInterval:
    """Mean of a sample with its two-sided confidence interval.

    n : int, lower : float, mean : float, upper : float, level : float (e.g. 0.99)
    """

    n: int
    lower: float
    mean: float
    upper: float
    level: float


def mean_confidence_interval(values: np.ndarray, level: float = 0.99) -> MeanInterval:
    """Student's t confidence interval of the mean (``scipy.stats.t.interval``).

    NaN limits for fewer than two values (NaN mean for none).
    """
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    n = len(v)
    if n == 0:
        return MeanInterval(0, float("nan"), float("nan"), float("nan"), level)
    mean = float(v.mean())
    if n < 2:
        return MeanInterval(1, float("nan"), mean, float("nan"), level)
    sem = float(stats.sem(v))
    if sem == 0.0:
        return MeanInterval(n, mean, mean, mean, level)
    lo, hi = stats.t.interval(level, n - 1, loc=mean, scale=sem)
    return MeanInterval(n, float(lo), mean, float(hi), level)


@dataclass(frozen=True)
class NormalityTest:
    """Shapiro-Wilk test: ``statistic`` W, ``p_value``, and ``normal`` = p >= alpha
    (normality not rejected). NaN / False for fewer than 3 values."""

    statistic: float
    p_value: float
    normal: bool
    alpha: float


def shapiro_wilk(values: np.ndarray, alpha: float = 0.01) -> NormalityTest:
    """Shapiro-Wilk test of normality (``scipy.stats.shapiro``).

    Above 5000 values scipy's p-value is approximate (its warning is silenced here);
    seed 000's samples are ~1000-1700 values per tracker.
    """
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if len(v) < 3 or np.ptp(v) == 0.0:
        return NormalityTest(float("nan"), float("nan"), False, alpha)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        res = stats.shapiro(v)
    return NormalityTest(float(res.statistic), float(res.pvalue), bool(res.pvalue >= alpha), alpha)


@dataclass(frozen=True)
class ErrorSummary:
    """One row of seed 000's Tables II-IV: sample count, 99 % CI of the mean, normality."""

    interval: MeanInterval
    normality: NormalityTest

    @property
    def n(self) -> int:
        return self.interval.n


def summarise_errors(values: np.ndarray, level: float = 0.99, alpha: float = 0.01) -> ErrorSummary:
    """Confidence interval of the mean and Shapiro-Wilk test of prediction errors."""
    return ErrorSummary(mean_confidence_interval(values, level), shapiro_wilk(values, alpha))
