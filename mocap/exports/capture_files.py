"""Reading other systems' capture files: what is a physical marker, which axis is up.

:func:`mocap.exports.read_c3d` and :func:`mocap.exports.read_trc` return a
:class:`CaptureTrajectories` (world axes, Z up, metres) and set aside, each with its reason,
model outputs, virtual and unlabelled points, empty entries and repeated labels
(:func:`_classify_points`); without axis metadata the data decide the up axis
(:func:`_decide_up_axis`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from mocap.exports._common import _Z_UP_TO_Y_UP
from mocap.types import Trajectories

@dataclass
class CaptureTrajectories(Trajectories):
    """Trajectories read from a capture file, and what the reader set aside.

    Attributes (besides :class:`~mocap.types.Trajectories`' ones: world axes, Z up, metres)
    ----------
    set_aside : dict[str, str]
        Entries of the file that are not returned, ``label -> reason`` (a repeated label
        is keyed ``"<label> (entry <k>)"``, ``k`` counting the file's points from 1).
    source_units : str
        Length unit of the file (``"mm"``, ``"m"``, ...); the positions are in metres.
    source_up_axis : str
        The file's vertical axis (``"x"``, ``"y"`` or ``"z"``), rotated onto world Z.
    up_axis_reason : str
        How ``source_up_axis`` was decided (a parameter, the caller, or the data).
    point_rate_hz : float
        The file's own frame rate (C3D ``POINT:RATE``, TRC ``DataRate``), exactly.
    """

    set_aside: dict[str, str] = field(default_factory=dict)
    source_units: str = "m"
    source_up_axis: str = "z"
    up_axis_reason: str = ""
    point_rate_hz: float = float("nan")


# Plug-in Gait's model outputs that are points (segment origins and axes, e.g. PELO,
# LFEA, RTIL, HEDO, TRXP) and joint centres (LHJC, RKJC, LeftHipCenter, ...): computed
# by a model from the markers, never a marker themselves.
_SEGMENT_POINT = re.compile(r"^(PEL|HED|TRX|CSP|[LR](FE|TI|FO|TO|CL|HU|RA|HN))[OALP]$")
_JOINT_CENTRE = re.compile(r"(^|[a-z0-9_])[A-Z]{0,3}JC$|(?i:(hip|knee|ankle|joint|shoulder|elbow|wrist)_?cent(er|re))")
_CENTRE_OF_MASS = re.compile(r"(?i)cent(er|re)_?of_?mass|^com$")
# Kinetic and angle outputs by name, for files without POINT:ANGLES/FORCES/... lists.
_KINETIC_NAME = re.compile(r"[a-z](Angles?|Force|GRF|Moment|Power)$")
# Vicon's "*12": a reconstructed trajectory nobody labelled.
_UNLABELLED = re.compile(r"^\*\d*$")
# C3D point groups that hold model outputs (POINT:TYPE_GROUPS may name more).
_OUTPUT_GROUPS = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS")
# Heuristic up axis (see _decide_up_axis): every marker sample between these heights (m).
_FLOOR_TOLERANCE_M, _CEILING_M = 0.1, 2.6


def _bare_name(label: str) -> str:
    """Label without a subject prefix (``"Matt:LKNE"`` -> ``"LKNE"``)."""
    return label.rsplit(":", 1)[-1].strip()


def _output_name_reason(label: str, all_labels: set[str]) -> str | None:
    """Why a label names a model output, or None.

    A Plug-in Gait segment writes four points (origin ``O`` and axis ends ``A``, ``L``,
    ``P``): a name of that form counts only when its three siblings are in the file too,
    since the same letters can be a marker's name (``RCLA``, a clavicle marker in c3d.org's
    sub_labels.c3d, where no ``RCLO`` exists).
    """
    name = _bare_name(label)
    if _SEGMENT_POINT.match(name) and all(label[:-1] + axis in all_labels for axis in "OALP"):
        return "model output: Plug-in Gait segment origin/axis point"
    if _JOINT_CENTRE.search(name):
        return "model output: joint centre"
    if _CENTRE_OF_MASS.search(name):
        return "model output: centre of mass"
    if _KINETIC_NAME.search(name):
        return "model output: angle/force/moment/power (by name)"
    return None


def _classify_points(
    labels: list[str],
    present: np.ndarray,
    output_groups: dict[str, str],
) -> tuple[list[int], dict[str, str]]:
    """Which entries are physical markers; the others with the reason.

    Parameters
    ----------
    labels : list[str], length N
        The file's point labels, in file order.
    present : (F, N) bool
        Where each entry has a sample.
    output_groups : dict[str, str]
        ``label -> group`` for labels listed in a model-output group (``POINT:ANGLES`` ...).

    Returns
    -------
    kept : list[int]
        Indices of the physical markers, in file order.
    set_aside : dict[str, str]
        ``label -> reason`` of every other entry (see :class:`CaptureTrajectories`).
    """
    N = len(labels)
    reason: list[str | None] = [None] * N
    point_outputs: list[int] = []  # name-identified outputs that are positions
    all_labels = set(labels)
    for i, label in enumerate(labels):
        if label in output_groups:
            reason[i] = f"model output: listed in POINT:{output_groups[label]}"
        elif label == "":
            reason[i] = "virtual point: no label"
        elif label == "#":
            reason[i] = "virtual point: '#' (the separator Vicon writes before model outputs)"
        elif _UNLABELLED.match(label):
            reason[i] = "unlabelled trajectory: Vicon's '*N', not identified as any marker"
        else:
            why = _output_name_reason(label, all_labels)
            if why is not None:
                reason[i] = why
                if "angle/force" not in why:
                    point_outputs.append(i)
    F = present.shape[0]
    for i in range(N):
        if reason[i] is None and not present[:, i].any():
            reason[i] = "empty for the whole trial"
    # A model writes all its points in exactly the frames where it could run: an
    # unnamed point present in exactly the frames of a joint centre or segment point
    # (and not throughout the trial, where every marker would match) is computed too,
    # e.g. walking2.c3d's condyle and malleolus landmarks RLFC ... LLMAL beside LAJC.
    masks = {present[:, i].tobytes(): labels[i] for i in point_outputs if 0 < present[:, i].sum() < F}
    for i in range(N):
        if reason[i] is None and present[:, i].tobytes() in masks:
            k = np.flatnonzero(present[:, i])
            reason[i] = (f"virtual point: present in exactly the frames of the model output "
                         f"{masks[present[:, i].tobytes()]!r} (frames {k[0]}-{k[-1]}), as a model's computed points are")
    first: dict[str, int] = {}
    for i in range(N):
        if reason[i] is None:
            if labels[i] in first:
                reason[i] = f"duplicate label: entry {i + 1} repeats the label of entry {first[labels[i]] + 1}, which is kept"
            else:
                first[labels[i]] = i
    kept = [i for i in range(N) if reason[i] is None]
    set_aside: dict[str, str] = {}
    for i in range(N):
        if reason[i] is not None:
            key = labels[i] if labels[i] not in set_aside and labels[i] not in first else f"{labels[i]} (entry {i + 1})"
            set_aside[key] = reason[i]
    return kept, set_aside


_UP_TO_Z = {
    "z": np.eye(3),
    "y": _Z_UP_TO_Y_UP.T,  # (x, y, z) -> (x, -z, y): +90 deg about X, as opensim_to_world
    "x": np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]),  # (x, y, z) -> (-z, y, x): -90 deg about Y
}


def _decide_up_axis(xyz_m: np.ndarray, context: str, default: str) -> tuple[str, str]:
    """The up axis of file data ``xyz_m (F, M, 3)`` without axis metadata, and why.

    The data decide when exactly one axis has every sample between -0.1 m and 2.6 m:
    markers on people and their equipment stand on a floor near 0 and stay below 2.6 m,
    while the horizontal axes of a lab cross zero or reach far. Otherwise ``default``.
    """
    finite = xyz_m[np.isfinite(xyz_m).all(axis=-1)]
    if len(finite):
        fits = [a for k, a in enumerate("xyz")
                if finite[:, k].min() >= -_FLOOR_TOLERANCE_M and finite[:, k].max() <= _CEILING_M]
        if len(fits) == 1:
            return fits[0], (f"{context}; from the data: only {fits[0].upper()} keeps every marker between "
                             f"{-_FLOOR_TOLERANCE_M:g} and {_CEILING_M:g} m, as heights above a floor do")
    return default, f"{context}; the data do not tell, {default.upper()} assumed"


def _rotate_to_z_up(xyz: np.ndarray, up: str) -> np.ndarray:
    return xyz if up == "z" else xyz @ _UP_TO_Z[up].T
