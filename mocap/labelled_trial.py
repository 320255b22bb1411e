"""A labelled trial of the subject as the labelling model of a capture without a skeleton.

Input: a capture file of the same subject and marker set whose markers are already labelled
(C3D, TRC or the pipeline's CSV; a range-of-motion take, or an earlier capture), and the label
template's marker names. Output: a :class:`LabelledTrial` holding the
:class:`~mocap.cluster_labelling.ClusterMarkerModel` that :func:`mocap.marker_pipeline.capture_from_detections`
labels with (``marker_model=``). This is the subject calibration commercial systems make from a
labelled trial. The model uses only the markers' positions relative to their neighbours, so the
trial may come from another session, calibration or world frame; its length unit is read from
the file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mocap.cluster_labelling import ClusterMarkerModel
from mocap.errors import InputFileError
from mocap.label_template import LabelTemplate

__all__ = ["STATIC_TRAVEL_M", "LabelledTrial", "load_labelled_trial", "reference_frame", "template_from_trial"]

STATIC_TRAVEL_M = 0.05
"""Below this :attr:`LabelledTrial.travel_m` a trial is static: the shared data's two standing trials
(``Sample_Static.c3d`` 9 mm, ``Res16bits.c3d`` 34 mm) against 0.9-12.7 m for its takes of motion."""


@dataclass(frozen=True)
class LabelledTrial:
    """A labelled trial read for a capture.

    Attributes
    ----------
    model : ClusterMarkerModel
        Of the template's markers that the trial holds, in the template's order.
    frames : int
        Frames of the trial with three or more of those markers seen.
    missing : tuple[str, ...]
        Template markers the trial does not hold: a capture leaves them unlabelled.
    template : LabelTemplate
        The trial's own template of those markers (:func:`template_from_trial`), for a capture given no other.
    travel_m : float
        How far the marker that moves most moves over the trial (the largest extent of its
        positions, metres). Rigidity is learned from motion: in a static trial every distance is
        constant, and the clusters follow nearness alone (:data:`STATIC_TRAVEL_M`). Not a median
        over markers: a trial that moves only the arms (the quickstart's first 1.5 s: median 21 mm,
        largest 666 mm) teaches the arms' clusters.
    """

    model: ClusterMarkerModel
    frames: int
    missing: tuple[str, ...]
    template: LabelTemplate
    travel_m: float

    @property
    def is_static(self) -> bool:
        """Whether the markers barely move (a standing calibration trial rather than a range of motion)."""
        return self.travel_m < STATIC_TRAVEL_M


def reference_frame(xyz: np.ndarray) -> int:
    """The first frame of a labelled trial ``xyz (F, M, 3)`` with the most markers present."""
    return int(np.argmax(np.isfinite(xyz).all(axis=2).sum(axis=1)))


def template_from_trial(labels: Sequence[str], xyz: np.ndarray) -> LabelTemplate:
    """A :class:`~mocap.label_template.LabelTemplate` of markers ``labels`` from a labelled trial ``xyz (F, M, 3)``
    metres: its :func:`reference_frame`, in the subject-local frame the template wants.

    Shifted horizontally so the markers' centroid is at the origin (heights kept; the labelling searches every
    heading). A marker missing in the reference frame takes its position from the nearest frame where it is
    present, moved by how far the centroid of the markers present in both frames moved (an approximation: the
    labelling tolerates a few centimetres).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    ref = reference_frame(xyz)
    present = np.isfinite(xyz).all(axis=2)  # (F, M)
    pos = xyz[ref].copy()
    for m in np.flatnonzero(~present[ref]):
        frames = np.flatnonzero(present[:, m])
        f = int(frames[np.argmin(np.abs(frames - ref))])
        both = present[ref] & present[f]
        drift = xyz[ref, both].mean(axis=0) - xyz[f, both].mean(axis=0) if both.any() else np.zeros(3)
        pos[m] = xyz[f, m] + drift
    pos[:, :2] -= pos[:, :2].mean(axis=0)
    return LabelTemplate(tuple(labels), pos)


def load_labelled_trial(path: str | os.PathLike, names: Sequence[str] | None = None) -> LabelledTrial:
    """Read a labelled trial (``.c3d``, ``.trc`` or ``.csv``) and learn the rigid marker clusters of
    the markers ``names`` (the label template's; None: every marker of the trial) from it.

    Raises :class:`~mocap.errors.InputFileError` (naming the file) for another file type, a file
    the readers refuse, fewer than three of ``names`` in it, or fewer than two frames that see
    three of them (rigidity is learned from motion).
    """
    from mocap.exports import read_capture

    traj = read_capture(path, what="labelled trial")
    names = list(traj.labels) if names is None else list(names)
    shared = [n for n in names if n in traj.labels]
    if len(shared) < 3:
        raise InputFileError(path, f"holds {len(shared)} of the template's {len(names)} markers "
                             f"({', '.join(shared) or 'none of them'}; the trial has {', '.join(list(traj.labels)[:6]) or 'no labels'}"
                             f"{', ...' if len(traj.labels) > 6 else ''})",
                             "give a trial labelled with the template's marker names (3 or more of them)")
    xyz = np.asarray(traj.xyz, dtype=np.float64)[:, [list(traj.labels).index(n) for n in shared]]
    frames = int((np.isfinite(xyz).all(axis=2).sum(axis=1) >= 3).sum())
    if frames < 2:
        raise InputFileError(path, f"has {frames} frame{'' if frames == 1 else 's'} with 3 or more of the template's markers",
                             "give a trial of the subject moving (a range of motion): the clusters are learned from motion")
    with np.errstate(all="ignore"):  # a marker never seen has no extent (NaN), left out
        extent = np.nanmax(np.nanmax(xyz, axis=0) - np.nanmin(xyz, axis=0), axis=1)
    travel = float(np.nanmax(extent)) if np.isfinite(extent).any() else 0.0
    return LabelledTrial(ClusterMarkerModel(shared, xyz), frames, tuple(n for n in names if n not in shared),
                         template_from_trial(shared, xyz), travel)
