"""Scores of the colour-shirt pipeline against ground truth (arrays in, numbers and arrays out).

* :func:`rmse_cm`: RMS distance of joint centres or surface vertices, centimetres
  (seed 001 reports the RMS of upper-body joints, and in its Fig. 9 of all mesh vertices);
* :func:`shoulder_angle_deg`: the shoulder angle trace of the paper's Fig. 10, here the
  angle between the upper arm (shoulder -> elbow) and the trunk's downward axis
  (neck -> lumbar joint), from joint centres only, so any skeleton parameterisation
  can be compared;
* :func:`frames_within_cm`: the share of frames where every named joint (e.g. elbows and
  wrists) is within a distance of the truth (seed 001's Fig. 11: the arms kept or lost);
* :func:`classification_roc`: correct against incorrect classifications while the
  classifier's threshold varies (the paper's Fig. 6); :class:`RocCounts` gathers the same
  figures frame by frame, at fixed thresholds, in memory that does not grow with the take.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["rmse_cm", "per_frame_rms_cm", "frames_within_cm", "fill_forward", "shoulder_angle_deg", "classification_roc",
           "RocCounts"]

ARM_JOINTS: tuple[str, ...] = ("forearm_l", "hand_l", "forearm_r", "hand_r")
"""Elbows (the forearms' origins) and wrists (the hands' origins)."""


def per_frame_rms_cm(est_m: np.ndarray, true_m: np.ndarray) -> np.ndarray:
    """RMS over points of each frame ``(F,)``, centimetres, for ``(F, N, 3)`` metres (NaN frames stay NaN)."""
    d2 = np.sum((np.asarray(est_m, float) - np.asarray(true_m, float)) ** 2, axis=-1)
    with np.errstate(invalid="ignore"):
        return np.sqrt(np.mean(d2, axis=-1)) * 100.0


def frames_within_cm(est_m: np.ndarray, true_m: np.ndarray, names: list[str] | tuple[str, ...],
                     joints: tuple[str, ...] = ARM_JOINTS, threshold_cm: float = 5.0) -> float:
    """Share of frames where each of ``joints`` is within ``threshold_cm`` of the truth (a NaN frame is not).

    Parameters
    ----------
    est_m, true_m : (F, J, 3) float
        Estimated and true joint centres, metres.
    names : sequence of str
        Body names of the J joints.
    """
    idx = [list(names).index(j) for j in joints]
    d_cm = np.linalg.norm(np.asarray(est_m, float)[:, idx] - np.asarray(true_m, float)[:, idx], axis=-1) * 100.0
    with np.errstate(invalid="ignore"):
        ok = np.all(d_cm < threshold_cm, axis=1)
    return float(np.mean(ok)) if len(ok) else float("nan")


def rmse_cm(est_m: np.ndarray, true_m: np.ndarray) -> float:
    """RMS over frames and points of the 3D distance, centimetres; points with NaN are skipped.

    Parameters
    ----------
    est_m, true_m : (F, N, 3) float
        Estimated and true positions, metres.
    """
    d2 = np.sum((np.asarray(est_m, float) - np.asarray(true_m, float)) ** 2, axis=-1)
    d2 = d2[np.isfinite(d2)]
    return float(np.sqrt(np.mean(d2)) * 100.0) if d2.size else float("nan")


def fill_forward(values: np.ndarray) -> np.ndarray:
    """Rows with any NaN replaced by the last complete row (a live system keeps showing its last pose).

    Leading incomplete rows stay NaN.
    """
    v = np.array(values, float, copy=True)
    flat = v.reshape(len(v), -1)
    last = None
    for i in range(len(flat)):
        if np.all(np.isfinite(flat[i])):
            last = flat[i].copy()
        elif last is not None:
            flat[i] = last
    return flat.reshape(v.shape)


def shoulder_angle_deg(joints_m: np.ndarray, names: list[str] | tuple[str, ...], side: str = "r") -> np.ndarray:
    """Angle ``(F,)`` in degrees between the upper arm and the trunk's downward axis.

    Parameters
    ----------
    joints_m : (F, J, 3) float
        Joint centres, metres.
    names : sequence of str
        Body names of the J joints; needs ``head`` (neck joint), ``abdomen`` (lumbar
        joint), ``upperarm_<side>`` (shoulder) and ``forearm_<side>`` (elbow).
    side : ``"l"`` or ``"r"``
    """
    names = list(names)
    j = np.asarray(joints_m, float)
    neck, lumbar = j[:, names.index("head")], j[:, names.index("abdomen")]
    shoulder, elbow = j[:, names.index(f"upperarm_{side}")], j[:, names.index(f"forearm_{side}")]
    down = lumbar - neck
    arm = elbow - shoulder
    with np.errstate(invalid="ignore"):
        c = np.sum(down * arm, axis=1) / (np.linalg.norm(down, axis=1) * np.linalg.norm(arm, axis=1))
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def classification_roc(score: np.ndarray, predicted: np.ndarray, truth: np.ndarray,
                       thresholds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Correct and incorrect classification rates of a thresholded classifier.

    A pixel is classified when its ``score`` is below the threshold; it is then
    *correct* if ``predicted == truth`` (a shirt colour) and *incorrect* otherwise
    (a wrong colour, or any colour on a pixel that is not shirt).

    Parameters
    ----------
    score : (N,) float
        The classifier's score of its best class (lower is more confident).
    predicted : (N,) int
        The best class.
    truth : (N,) int
        True class, -1 for pixels that are not shirt.
    thresholds : (T,) float

    Returns
    -------
    correct : (T,) float
        Correctly classified shirt pixels / all shirt pixels.
    incorrect : (T,) float
        Wrongly classified pixels / all pixels.
    """
    counts = RocCounts(np.asarray(thresholds, float))
    counts.add(score, predicted, truth)
    return counts.rates()


@dataclass
class RocCounts:
    """The counts behind :func:`classification_roc` at fixed ``thresholds (T,)``, summed over calls of :meth:`add`.

    A take's ROC from samples of every few frames: the counts are added frame by frame, so
    nothing grows with the take, and :meth:`rates` gives exactly what
    :func:`classification_roc` gives on all the samples at once.
    """

    thresholds: np.ndarray
    right_below: np.ndarray = field(init=False)  # (T,) correctly classified shirt pixels with score < threshold
    wrong_below: np.ndarray = field(init=False)  # (T,) the other pixels with score < threshold
    n_shirt: int = 0                             # shirt pixels
    n: int = 0                                   # all pixels

    def __post_init__(self) -> None:
        self.thresholds = np.asarray(self.thresholds, float).ravel()
        self.right_below = np.zeros(len(self.thresholds), np.int64)
        self.wrong_below = np.zeros(len(self.thresholds), np.int64)

    def add(self, score: np.ndarray, predicted: np.ndarray, truth: np.ndarray) -> None:
        """Add pixels: ``score``, ``predicted`` and ``truth`` as in :func:`classification_roc`."""
        s = np.asarray(score, float).ravel()
        t = np.asarray(truth).ravel()
        right = (np.asarray(predicted).ravel() == t) & (t >= 0)
        s_right, s_wrong = np.sort(s[right]), np.sort(s[~right])
        self.right_below += np.searchsorted(s_right, self.thresholds, side="left")
        self.wrong_below += np.searchsorted(s_wrong, self.thresholds, side="left")
        self.n_shirt += int((t >= 0).sum())
        self.n += len(s)

    def rates(self) -> tuple[np.ndarray, np.ndarray]:
        """``(correct, incorrect)`` at every threshold, as :func:`classification_roc` defines them."""
        return self.right_below / max(self.n_shirt, 1), self.wrong_below / max(self.n, 1)

    def rates_at(self, threshold: float) -> tuple[float, float]:
        """``(correct, incorrect)`` at one of the thresholds (exactly; ValueError for another)."""
        hit = np.flatnonzero(self.thresholds == float(threshold))
        if not len(hit):
            raise ValueError(f"RocCounts: {threshold} is not one of its thresholds")
        correct, incorrect = self.rates()
        return float(correct[hit[0]]), float(incorrect[hit[0]])
