"""Another system's 3D results read back and scored against the ground truth like the project's.

:func:`read_results` takes what such systems write: C3D (axes from the file's own metadata,
:func:`mocap.exports.read_c3d`), TRC (``axes``: OpenSim's Y up, Pose2Sim's Y up turned 90 deg,
or Z up; :func:`mocap.exports.read_trc`) or the bench's CSV (:func:`mocap.exports.read_csv`).
:func:`score_results` matches its labels to the ground truth's markers by name and scores
them with :func:`eval.marker_metrics.summarize_markers` (3D RMSE, reconstructed fraction,
label swaps, percentiles, gap recovery): the same ``markers.*`` metrics as ``simbench run``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from eval import marker_metrics
from mocap.errors import InputFileError
from mocap.exports import CAPTURE_SUFFIXES, read_capture
from mocap.types import Trajectories

__all__ = ["RESULT_SUFFIXES", "read_results", "score_results", "align_to_frames"]

RESULT_SUFFIXES = CAPTURE_SUFFIXES


def read_results(path: str | os.PathLike, trc_axes: str = "opensim") -> Trajectories:
    """A system's labelled 3D markers in the world frame (Z up, metres), by extension (:func:`mocap.exports.read_capture`)."""
    path = Path(path)
    if not path.is_file() and path.suffix.lower() in RESULT_SUFFIXES:
        raise InputFileError(path, "file not found", f"the system must write its 3D result there ({', '.join(RESULT_SUFFIXES)})")
    return read_capture(path, trc_axes=trc_axes, what="3D result")


def align_to_frames(traj: Trajectories, times: np.ndarray, path: Path | str = "") -> np.ndarray:
    """The result's ``xyz`` on the ground truth's frames ``(F, M, 3)``: a result with one row per
    frame is taken as is; otherwise rows are matched by time (within half a frame), the rest NaN."""
    F = len(times)
    if traj.xyz.shape[0] == F:
        return traj.xyz
    out = np.full((F,) + traj.xyz.shape[1:], np.nan)
    half = 0.5 * float(np.median(np.diff(times))) if F > 1 else np.inf
    idx = np.searchsorted(traj.times, times)
    for f, i in enumerate(idx):
        for j in (i - 1, i):
            if 0 <= j < len(traj.times) and abs(traj.times[j] - times[f]) < half:
                out[f] = traj.xyz[j]
    if not np.isfinite(out).any():
        raise InputFileError(path, f"{traj.xyz.shape[0]} rows whose times match none of the take's {F} frames",
                             "write one row per frame of the inputs (inputs.json: times_s)")
    return out


def score_results(traj: Trajectories, true_xyz: np.ndarray, visible: np.ndarray, marker_names: list[str],
                  times: np.ndarray, path: Path | str = "") -> dict[str, float]:
    """``markers.*`` of a result against the truth ``true_xyz (F, M, 3)`` and ``visible (F, C, M)``.
    A marker the result does not name counts as never reconstructed (``markers.missing_labels``)."""
    xyz = align_to_frames(traj, times, path)
    est = np.full(true_xyz.shape, np.nan)
    index = {n: i for i, n in enumerate(traj.labels)}
    missing = [n for n in marker_names if n not in index]
    if len(missing) == len(marker_names):
        raise InputFileError(path, f"none of its labels ({', '.join(traj.labels[:5])}...) is a marker of the take",
                             "name the markers as inputs.json's markers / label_template.csv do")
    for m, n in enumerate(marker_names):
        if n in index:
            est[:, m] = xyz[:, index[n]]
    metrics = marker_metrics.summarize_markers(est, true_xyz, visible)
    metrics["markers.missing_labels"] = float(len(missing))
    return metrics
