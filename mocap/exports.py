"""Standard motion-capture files: C3D, TRC (OpenSim), CSV for markers; BVH for the solved skeleton.

Every writer writes a temporary file next to the target and renames it into place, so an
error never leaves a half-written file behind (and an existing file stays intact).

Axes and units
--------------
Inside the pipeline: world Z up, metres, seconds (``docs/humanoid_spec.md``). Files:

* **C3D** (ezc3d): world axes (Z up), millimetres (``POINT:UNITS = "mm"``), ``POINT:RATE``,
  ``POINT:LABELS``. The 4th word of each point holds the residual as C3D defines it: ``-1``
  for a gap, ``0`` for a point filled by interpolation, ``> 0`` for a measured point. The
  pipeline's residual is the mean *reprojection* residual in pixels, so that is what is
  stored (in steps of 0.01 px, truncated, saturating at 2.55 px, ``POINT:SCALE = -0.01``), and a
  ``SIMBENCH`` parameter group says so (``RESIDUAL_UNITS = "px"``) and keeps the exact time
  of the first frame (``FIRST_TIME_S``). Other programs ignore that group.
* **TRC** (OpenSim): millimetres, OpenSim's axes by default: ``X`` forward, ``Y`` up, ``Z``
  to the subject's right, i.e. ``(x, y, z)_trc = (x, z, -y)_world`` (a rotation of -90 deg
  about X; our humanoid faces +X, as OpenSim models do). ``axes="world"`` keeps Z up.
  Gaps are written ``NaN``, which OpenSim reads as missing.
* **CSV**: world axes, millimetres: ``frame, time_s``, then ``<label>_x_mm, <label>_y_mm,
  <label>_z_mm`` per marker, then ``<label>_filled`` (0/1) per marker; gaps are empty fields.
* **BVH**: Y up by default (the usual BVH convention; ``up_axis="z"`` keeps the world axes),
  centimetres, angles in degrees; see :func:`write_bvh`.

Reading other systems' files
----------------------------
:func:`read_c3d` and :func:`read_trc` return a :class:`CaptureTrajectories`: world axes
(Z up), metres, seconds, and by default only the **physical markers**. Model outputs
(Plug-in Gait angles, forces, moments, powers, segment axes, joint centres), virtual and
unlabelled points, entries empty for the whole trial and repeated labels are set aside,
each with the reason, in ``CaptureTrajectories.set_aside``; the file's units and up axis
and how the up axis was decided are kept too. See :func:`read_c3d` for the rules.
"""

from __future__ import annotations

import contextlib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Literal

import ezc3d
import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from mocap.errors import InputFileError, MocapInputError
from mocap.skeleton import KinematicTree, SkeletonFit
from mocap.subject import SubjectModel
from mocap.types import Trajectories

__all__ = [
    "CaptureTrajectories",
    "write_c3d",
    "read_c3d",
    "write_trc",
    "read_trc",
    "write_csv",
    "read_csv",
    "write_bvh",
    "world_to_opensim",
    "opensim_to_world",
]

# (x, y, z)_opensim = P @ (x, y, z)_world: -90 deg about X (Z up -> Y up, Y left -> Z right).
_Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
_UNIT_TO_M = {"mm": 1e-3, "m": 1.0, "cm": 1e-2, "dm": 0.1, "in": 0.0254}
_C3D_RESIDUAL_STEP = 0.01  # |POINT:SCALE|: residual resolution in the 4th word
_C3D_RESIDUAL_MAX = 255 * _C3D_RESIDUAL_STEP  # the residual is stored in one byte


def world_to_opensim(xyz: np.ndarray) -> np.ndarray:
    """``(..., 3)`` world (Z up) -> OpenSim axes (Y up, Z right): ``(x, z, -y)``."""
    return np.asarray(xyz, dtype=np.float64) @ _Z_UP_TO_Y_UP.T


def opensim_to_world(xyz: np.ndarray) -> np.ndarray:
    """Inverse of :func:`world_to_opensim`."""
    return np.asarray(xyz, dtype=np.float64) @ _Z_UP_TO_Y_UP


# Pose2Sim's TRC files (its ``zup2yup``: "X->Y, Y->Z, Z->X") hold ``(y, z, x)`` of its Z-up
# calibration world: Y up like OpenSim's, but turned 90 deg about the vertical from
# :func:`world_to_opensim`'s ``(x, z, -y)``. Rows: world axes from the file's (world = M @ file).
_POSE2SIM_TO_WORLD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def world_to_pose2sim(xyz: np.ndarray) -> np.ndarray:
    """``(..., 3)`` world (Z up) -> Pose2Sim's TRC axes (Y up): ``(y, z, x)``."""
    return np.asarray(xyz, dtype=np.float64) @ _POSE2SIM_TO_WORLD


def pose2sim_to_world(xyz: np.ndarray) -> np.ndarray:
    """Inverse of :func:`world_to_pose2sim`: a Pose2Sim TRC's ``(X, Y, Z)`` -> world ``(Z, X, Y)``."""
    return np.asarray(xyz, dtype=np.float64) @ _POSE2SIM_TO_WORLD.T


@contextlib.contextmanager
def _atomic_target(path: Path, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` if the block succeeds."""
    path = Path(path)
    if not path.parent.is_dir():
        raise MocapInputError(f"{path}: the folder {str(path.parent)!r} does not exist; create it or choose another output path")
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}{suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _rate(traj_times: np.ndarray, rate_hz: float | None, what: str) -> float:
    if rate_hz is not None:
        rate = float(rate_hz)
    elif len(traj_times) >= 2:
        rate = float(1.0 / np.median(np.diff(traj_times)))
    else:
        rate = float("nan")
    if not (np.isfinite(rate) and rate > 0):
        raise MocapInputError(f"{what}: cannot tell the frame rate from {len(traj_times)} timestamps; pass rate_hz=")
    return rate


# ---------------------------------------------------------------------------------------- C3D
def write_c3d(path: str | os.PathLike, traj: Trajectories, *, rate_hz: float | None = None) -> Path:
    """Write labelled markers as a C3D file (ezc3d).

    Parameters
    ----------
    path : path-like
        Output file (``.c3d``).
    traj : Trajectories
        ``(F, M, 3)`` metres, world frame; NaN gaps.
    rate_hz : float, optional
        Point rate (default: from the median time step of ``traj.times``). C3D stores a
        constant rate: frame ``i`` is at ``times[0] + i / rate``.

    Returns
    -------
    Path
    """
    path = Path(path)
    rate = _rate(traj.times, rate_hz, str(path))
    F, M = traj.xyz.shape[:2]
    valid = np.isfinite(traj.xyz).all(axis=2)  # (F, M)
    points = np.ones((4, M, F))
    points[:3] = np.where(valid[..., None], traj.xyz * 1000.0, np.nan).transpose(2, 1, 0)
    res_px = np.asarray(traj.residual_px, dtype=np.float64)
    measured = np.clip(np.nan_to_num(res_px, nan=_C3D_RESIDUAL_STEP), _C3D_RESIDUAL_STEP, _C3D_RESIDUAL_MAX)
    residual = np.where(~valid, -1.0, np.where(np.asarray(traj.filled, dtype=bool), 0.0, measured))

    c3d = ezc3d.c3d()
    point = c3d["parameters"]["POINT"]
    point["RATE"]["value"] = [rate]
    point["UNITS"]["value"] = ["mm"]
    point["SCALE"]["value"] = [-_C3D_RESIDUAL_STEP]  # negative: floating-point storage
    point["LABELS"]["value"] = [str(label) for label in traj.labels]
    point["DESCRIPTIONS"]["value"] = ["" for _ in traj.labels]
    c3d.add_parameter("POINT", "X_SCREEN", ["+X"])  # world axes: Z up (read_c3d takes the up axis from Y_SCREEN)
    c3d.add_parameter("POINT", "Y_SCREEN", ["+Z"])
    first_time = float(traj.times[0]) if F else 0.0
    c3d["header"]["points"]["first_frame"] = max(int(round(first_time * rate)), 0)
    c3d.add_parameter("SIMBENCH", "RESIDUAL_UNITS", ["px"])
    c3d.add_parameter("SIMBENCH", "FIRST_TIME_S", [first_time])
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residual.T[None, :, :]}
    with _atomic_target(path, ".c3d") as tmp:  # ezc3d appends .c3d to names without it
        c3d.write(str(tmp))
    return path


# ------------------------------------------------------------------------------ reading real files
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


def read_c3d(
    path: str | os.PathLike,
    *,
    physical_only: bool = True,
    up_axis: Literal["auto", "x", "y", "z"] = "auto",
) -> CaptureTrajectories:
    """Read the markers of a C3D file (any writer) as trajectories: world Z up, metres, seconds.

    Points with a negative residual (C3D's "invalid") are NaN. For files written by
    :func:`write_c3d` the filled flags and the pixel residuals come back too; other files
    get ``filled = False`` (vendors disagree on what a zero residual means) and NaN residuals.

    **Physical markers only** (``physical_only=True``, the default). Set aside, in this order,
    each with its reason in ``set_aside``:

    1. labels listed in ``POINT:ANGLES``, ``FORCES``, ``MOMENTS``, ``POWERS``, ``SCALARS``,
       ``REACTIONS`` and any other group ``POINT:TYPE_GROUPS`` names (model outputs stored
       as points: they are not positions);
    2. virtual and unlabelled points: an empty label, Vicon's ``#`` separator, ``*N``;
    3. model outputs by name (any subject prefix ``Name:`` ignored): Plug-in Gait segment
       points (``PELO``, ``LFEA``, ``RTIL``, ``HEDP``, ``TRXO`` ...), joint centres (``LHJC``,
       ``RKJC``, ``LeftHipCenter``, ``RightHipCenterScore``), centre of mass, and names
       ending in ``Angle(s)``, ``Force``, ``GRF``, ``Moment``, ``Power``;
    4. entries with no sample in the whole trial;
    5. points present in exactly the frames of a joint centre or segment point of 3. (not
       throughout the trial): a model computes all its points in the same frames, so
       these are its landmarks (e.g. the condyles and malleoli of ``walking2.c3d``);
    6. a label repeated: the first entry is kept, later ones set aside.

    ``physical_only=False`` returns every entry as it is (``set_aside`` empty), and so does a
    file written by :func:`write_c3d` (the pipeline's labelled markers, a label with no
    sample included, so that a round trip keeps every label).

    **Units**: ``POINT:UNITS`` (mm, m, cm, dm, in) to metres.

    **Axes**: the result is Z up. The file's up axis is ``up_axis`` if given, else the
    letter of ``POINT:Y_SCREEN`` (the axis drawn vertically; its sign is ignored: Qualisys
    writes ``-Z`` for Z-up data), else ``Z`` for files written by :func:`write_c3d`, else
    the one axis along which every physical marker lies between -0.1 and 2.6 m, else Z.
    A Y-up file becomes ``(x, y, z) -> (x, -z, y)`` (+90 deg about X: Y onto Z, X kept), an
    X-up one ``(x, y, z) -> (-z, y, x)``. ``source_up_axis`` and ``up_axis_reason`` say which.

    **Time**: ``times = first_frame / rate + k / rate`` with the exact ``POINT:RATE``
    (kept in ``point_rate_hz``; it may be non-integer, e.g. 69.9926 Hz).

    Returns
    -------
    CaptureTrajectories
    """
    path = Path(path)
    c3d = _open_c3d(path, up_axis)
    params = c3d["parameters"]
    point = params["POINT"]
    units, rate = _c3d_units_and_rate(path, point)
    labels, xyz, residual, invalid = _c3d_points(c3d, _c3d_strings(point, "LABELS"), units)
    F, n = invalid.shape
    ours = "SIMBENCH" in params and "RESIDUAL_UNITS" in params["SIMBENCH"]

    if physical_only and not ours:  # write_c3d's files hold the pipeline's labelled markers only: kept whole
        kept, set_aside = _classify_points(labels, ~invalid, _c3d_output_groups(point))
    else:
        kept, set_aside = list(range(n)), {}
    up, why = _c3d_up_axis(point, up_axis, ours, xyz[:, kept])
    xyz = _rotate_to_z_up(xyz, up)

    if ours and "FIRST_TIME_S" in params["SIMBENCH"]:
        t0 = float(np.asarray(params["SIMBENCH"]["FIRST_TIME_S"]["value"]).ravel()[0])
    else:
        t0 = float(c3d["header"]["points"]["first_frame"]) / rate
    times = t0 + np.arange(F) / rate
    if ours:
        filled = (residual == 0) & ~invalid
        residual_px = np.where((residual > 0) & ~invalid, residual, np.nan)
    else:
        filled = np.zeros((F, n), dtype=bool)
        residual_px = np.full((F, n), np.nan)
    return CaptureTrajectories(
        [labels[i] for i in kept], xyz[:, kept], times, filled=filled[:, kept], residual_px=residual_px[:, kept],
        set_aside=set_aside, source_units=units, source_up_axis=up, up_axis_reason=why, point_rate_hz=rate,
    )


def _open_c3d(path: Path, up_axis: str) -> ezc3d.c3d:
    """The parsed C3D file at ``path`` (ezc3d), after checking that it exists and ``up_axis`` is known."""
    if not path.is_file():
        raise InputFileError(path, "no such file", "give the path of an existing .c3d file")
    if up_axis not in ("auto", "x", "y", "z"):
        raise MocapInputError(f"{path}: up_axis must be 'auto', 'x', 'y' or 'z', got {up_axis!r}")
    try:
        return ezc3d.c3d(str(path))
    except (OSError, RuntimeError, ValueError) as exc:
        raise InputFileError(path, f"not a readable C3D file ({exc})", "give a C3D file (e.g. one written by write_c3d, Vicon, Qualisys)") from None


def _c3d_units_and_rate(path: Path, point: dict) -> tuple[str, float]:
    """``POINT:UNITS`` (lower case, ``"mm"`` when absent; one of :data:`_UNIT_TO_M`) and ``POINT:RATE`` (Hz, > 0)."""
    units = str(point["UNITS"]["value"][0]).strip().lower() if "UNITS" in point and len(point["UNITS"]["value"]) else "mm"
    if units not in _UNIT_TO_M:
        raise InputFileError(path, f"POINT:UNITS is {units!r}", f"use a file in one of {sorted(_UNIT_TO_M)}", field="POINT:UNITS")
    rate = float(np.asarray(point["RATE"]["value"]).ravel()[0])
    if not (np.isfinite(rate) and rate > 0):
        raise InputFileError(path, f"POINT:RATE is {rate!r}", "give a file with a positive point rate", field="POINT:RATE")
    return units, rate


def _c3d_points(c3d: ezc3d.c3d, labels: list[str], units: str) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """The file's points in metres (file axes), invalid samples NaN.

    Returns
    -------
    labels : list[str], length N
        The labels that have a point (``N = min(points, labels)``).
    xyz : (F, N, 3) float
        Metres, the file's axes; NaN where ``invalid``.
    residual : (F, N) float
        The 4th word as stored (``< 0`` invalid, ``0`` filled, ``> 0`` measured).
    invalid : (F, N) bool
        Negative residual or a non-finite coordinate.
    """
    pts = np.asarray(c3d["data"]["points"], dtype=np.float64)  # (4, M', F)
    n = min(pts.shape[1], len(labels))
    labels = labels[:n]
    xyz = pts[:3, :n].transpose(2, 1, 0) * _UNIT_TO_M[units]  # (F, M, 3), file axes
    residual = np.asarray(c3d["data"]["meta_points"]["residuals"], dtype=np.float64)[0, :n].T  # (F, M)
    invalid = (residual < 0) | ~np.isfinite(xyz).all(axis=2)
    xyz[invalid] = np.nan
    return labels, xyz, residual, invalid


def _c3d_output_groups(point: dict) -> dict[str, str]:
    """``label -> group`` for every label listed in a model-output group of ``POINT``.

    The groups are :data:`_OUTPUT_GROUPS` and those ``POINT:TYPE_GROUPS`` names (pairs
    ``group, type``); a label in several keeps the first.
    """
    groups = [g for g in _OUTPUT_GROUPS]
    if "TYPE_GROUPS" in point:  # pairs (group, type): ANGLES, ANGLE, FORCES, FORCE, ...
        groups += [g.strip() for g in list(point["TYPE_GROUPS"]["value"])[0::2]]
    output_groups: dict[str, str] = {}
    for g in dict.fromkeys(groups):
        if g in point and g not in ("LABELS", "DESCRIPTIONS", "UNITS"):
            for name in _c3d_strings(point, g):
                output_groups.setdefault(name, g)
    return output_groups


def _c3d_up_axis(point: dict, up_axis: str, ours: bool, xyz_kept: np.ndarray) -> tuple[str, str]:
    """The file's up axis (``"x"``, ``"y"`` or ``"z"``) and why (see :func:`read_c3d`, **Axes**).

    The caller's ``up_axis`` unless ``"auto"``, else ``POINT:Y_SCREEN``'s letter, else Z for
    simbench's own files (``ours``), else the data ``xyz_kept (F, M, 3)`` metres decide.
    """
    if up_axis != "auto":
        return up_axis, f"up_axis = {up_axis!r} given by the caller"
    if "Y_SCREEN" in point and len(point["Y_SCREEN"]["value"]) and str(point["Y_SCREEN"]["value"][0]).strip()[-1:].lower() in "xyz":
        y_screen = str(point["Y_SCREEN"]["value"][0]).strip()
        return y_screen[-1].lower(), f"POINT:Y_SCREEN = {y_screen!r}"
    if ours:
        return "z", "written by simbench (world axes, Z up)"
    return _decide_up_axis(xyz_kept, "no POINT:Y_SCREEN", "z")  # Z: the usual C3D lab frame


def _c3d_strings(group: dict, name: str) -> list[str]:
    """A string parameter and its continuations (``LABELS``, ``LABELS2``, ...), stripped."""
    values: list[str] = []
    key, i = name, 2
    while key in group:
        values += [str(v).strip() for v in group[key]["value"]]
        key, i = f"{name}{i}", i + 1
    return values


# ---------------------------------------------------------------------------------------- TRC
def write_trc(
    path: str | os.PathLike,
    traj: Trajectories,
    *,
    rate_hz: float | None = None,
    axes: Literal["opensim", "pose2sim", "world"] = "opensim",
) -> Path:
    """Write labelled markers as an OpenSim TRC file (tab-separated, millimetres).

    Header: ``PathFileType 4 (X/Y/Z) <file name>``; then the keys ``DataRate CameraRate
    NumFrames NumMarkers Units OrigDataRate OrigDataStartFrame OrigNumFrames`` and their
    values (``Units = mm``; both rates = ``rate_hz``); then ``Frame# Time <label>...`` and
    ``X1 Y1 Z1 X2 ...``; a blank line; one row per frame (frame numbers from 1, time in s).

    Parameters
    ----------
    path : path-like
    traj : Trajectories
        Metres, world frame (Z up).
    rate_hz : float, optional
        DataRate (default: from the median time step). The Time column keeps the real times.
    axes : {"opensim", "world"}
        ``"opensim"`` (default): Y up, ``(x, z, -y)`` of the world; ``"pose2sim"``: Y up as
        Pose2Sim writes, ``(y, z, x)`` of the world; ``"world"``: as is (Z up).

    Returns
    -------
    Path
    """
    path = Path(path)
    rate = _rate(traj.times, rate_hz, str(path))
    xyz = _axes_out(traj.xyz, axes, path)
    F, M = xyz.shape[:2]
    for label in traj.labels:
        if not label or any(ch in label for ch in "\t\r\n"):
            raise MocapInputError(f"{path}: marker label {label!r} cannot go in a TRC header; rename it (no tabs or line breaks, not empty)")
    header = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{rate:.10g}\t{rate:.10g}\t{F}\t{M}\tmm\t{rate:.10g}\t1\t{F}",
        "Frame#\tTime\t" + "\t\t\t".join(traj.labels),
        "\t\t" + "\t".join(f"{a}{i + 1}" for i in range(M) for a in "XYZ"),
        "",
    ]
    table = pd.DataFrame(xyz.reshape(F, 3 * M) * 1000.0)
    table.insert(0, "time", np.asarray(traj.times, dtype=np.float64))
    table.insert(0, "frame", np.arange(1, F + 1))
    body = table.to_csv(sep="\t", header=False, index=False, na_rep="NaN", float_format="%.10g", lineterminator="\n")
    with _atomic_target(path) as tmp:
        tmp.write_text("\n".join(header) + "\n" + body)
    return path


def read_trc(
    path: str | os.PathLike,
    *,
    axes: Literal["opensim", "pose2sim", "world", "auto"] = "opensim",
    physical_only: bool = True,
) -> CaptureTrajectories:
    """Read a TRC file (ours, OpenSim's or a Motion Analysis one) as trajectories: world Z up, metres.

    Parameters
    ----------
    path : path-like
    axes : {"opensim", "world", "auto"}
        Axes of the file. ``"opensim"`` (default, as :func:`write_trc` writes): Y up, rotated
        back to the world's Z up by :func:`opensim_to_world`, ``(x, y, z) -> (x, -z, y)``;
        ``"pose2sim"``: Y up as Pose2Sim writes its TRC files (its ``zup2yup``), rotated back
        by :func:`pose2sim_to_world`, ``(x, y, z) -> (z, x, y)`` (read as ``"opensim"``, such
        a file comes out turned 90 deg about the vertical);
        ``"world"``: Z up, taken as is; ``"auto"``: TRC files do not say, so the data decide
        (the one axis along which every marker stays between -0.1 and 2.6 m is up, as
        :func:`read_c3d` does), and Y (OpenSim's convention) when they cannot. The result
        is Z up in every case; ``source_up_axis`` and ``up_axis_reason`` say what was done.
    physical_only : bool
        Set aside model outputs by name, entries empty for the whole trial and repeated
        labels (the rules 3, 4 and 6 of :func:`read_c3d`; TRC has no parameter groups).

    Returns
    -------
    CaptureTrajectories
        Gaps (empty or ``NaN`` fields) are NaN. ``times`` are ``Time[0] + k / DataRate``
        when the Time column agrees with that to within half a frame (some writers round
        it, e.g. to 0.033 s at 30 Hz), else the Time column as written.
    """
    path = Path(path)
    if axes not in ("opensim", "pose2sim", "world", "auto"):
        raise MocapInputError(f"{path}: axes must be 'opensim' (Y up), 'pose2sim' (Y up, Pose2Sim's), 'world' (Z up) or 'auto', got {axes!r}")
    lines = _trc_lines(path)
    units, rate, labels = _trc_header(path, lines)
    n_markers = len(labels)
    data = _trc_rows(path, lines[5:], 2 + 3 * n_markers)
    F = len(data)
    xyz = data[:, 2:].reshape(F, n_markers, 3) * _UNIT_TO_M[units]
    times, rate = _trc_times(data[:, 1], rate)
    if physical_only:
        kept, set_aside = _classify_points(labels, np.isfinite(xyz).all(axis=2), {})
    else:
        kept, set_aside = list(range(n_markers)), {}
    if axes == "auto":
        up, why = _decide_up_axis(xyz[:, kept], "axes = 'auto' (TRC does not say)", "y")  # Y: OpenSim's convention
    else:
        up = "y" if axes in ("opensim", "pose2sim") else "z"
        why = f"axes = {axes!r} given by the caller"
    xyz = pose2sim_to_world(xyz) if axes == "pose2sim" else _rotate_to_z_up(xyz, up)
    return CaptureTrajectories([labels[i] for i in kept], xyz[:, kept], times, set_aside=set_aside, source_units=units,
                               source_up_axis=up, up_axis_reason=why, point_rate_hz=float(rate))


def _trc_lines(path: Path) -> list[str]:
    """The TRC file's lines (at least 5, the first ``PathFileType ...``)."""
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise InputFileError(path, f"cannot read ({exc.strerror})", "give the path of a .trc file") from None
    except UnicodeDecodeError:
        raise InputFileError(path, "not a text file", "give a TRC (tab-separated text) file") from None
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise InputFileError(path, "first line does not start with PathFileType", "give a TRC file (OpenSim / Motion Analysis format)", field="PathFileType")
    return lines


def _trc_header(path: Path, lines: list[str]) -> tuple[str, float, list[str]]:
    """From a TRC's header lines 2-4: ``Units`` (lower case, a key of :data:`_UNIT_TO_M`),
    ``DataRate`` (Hz; NaN if not a number) and the marker labels (``NumMarkers`` of them)."""
    keys = [k for k in lines[1].split("\t") if k.strip()]
    values = [v for v in lines[2].split("\t") if v.strip()]
    meta = dict(zip((k.strip() for k in keys), (v.strip() for v in values)))
    for key in ("DataRate", "NumMarkers", "Units"):
        if key not in meta:
            raise InputFileError(path, f"header has no {key}", "write the TRC header keys DataRate CameraRate NumFrames NumMarkers Units ...", field=key)
    units = meta["Units"].lower()
    if units not in _UNIT_TO_M:
        raise InputFileError(path, f"Units is {meta['Units']!r}", f"use one of {sorted(_UNIT_TO_M)}", field="Units")
    try:
        n_markers = int(meta["NumMarkers"])
    except ValueError:
        raise InputFileError(path, f"NumMarkers is {meta['NumMarkers']!r}", "write the number of markers", field="NumMarkers") from None
    try:
        rate = float(meta["DataRate"])
    except ValueError:
        rate = float("nan")
    labels = [t.strip() for t in lines[3].split("\t")[2:] if t.strip()]
    if len(labels) != n_markers:
        raise InputFileError(path, f"{len(labels)} marker names on line 4 but NumMarkers = {n_markers}", "make the header agree with the columns", field="NumMarkers")
    return units, rate, labels


def _trc_rows(path: Path, body: list[str], n_cols: int) -> np.ndarray:
    """The data rows (the lines after the 5-line header; blank ones skipped) as ``(F, n_cols)`` floats.

    Columns ``Frame#, Time, X1, Y1, Z1, ...`` in the file's units; empty or missing fields NaN.
    """
    rows = [ln.rstrip("\r") for ln in body if ln.strip()]
    data = np.full((len(rows), n_cols), np.nan)
    for i, row in enumerate(rows):
        fields = row.split("\t")[:n_cols]
        try:
            data[i, : len(fields)] = [float(v) if v.strip() else np.nan for v in fields]
        except ValueError:
            raise InputFileError(path, f"data row {i + 1} has a field that is not a number", "fix or remove that row", field=f"line {i + 7}") from None
    return data


def _trc_times(times: np.ndarray, rate: float) -> tuple[np.ndarray, float]:
    """The frame times (s) and rate (Hz) of a TRC's ``Time (F,)`` column and ``DataRate``.

    ``Time[0] + k / DataRate`` when the column agrees with it within half a frame, else the
    column as written; with no usable ``DataRate`` the rate comes from the median time step.
    """
    F = len(times)
    if np.isfinite(rate) and rate > 0 and F and np.isfinite(times).all():
        grid = times[0] + np.arange(F) / rate
        if np.abs(times - grid).max() < 0.5 / rate:
            times = grid
    else:
        rate = 1.0 / np.median(np.diff(times)) if F > 1 else float("nan")
    return times, rate


def _axes_out(xyz: np.ndarray, axes: str, path: Path) -> np.ndarray:
    if axes == "opensim":
        return world_to_opensim(xyz)
    if axes == "pose2sim":
        return world_to_pose2sim(xyz)
    if axes == "world":
        return np.asarray(xyz, dtype=np.float64)
    raise MocapInputError(f"{path}: axes must be 'opensim' (Y up), 'pose2sim' (Y up, Pose2Sim's) or 'world' (Z up), got {axes!r}")


# ---------------------------------------------------------------------------------------- CSV
def write_csv(path: str | os.PathLike, traj: Trajectories) -> Path:
    """Write labelled markers as CSV: world axes (Z up), millimetres, empty fields in gaps.

    Columns: ``frame`` (from 0), ``time_s``, ``<label>_x_mm``, ``<label>_y_mm``,
    ``<label>_z_mm`` for each marker, then ``<label>_filled`` (1 where the point was filled
    by interpolation) for each marker.

    Returns
    -------
    Path
    """
    path = Path(path)
    F, M = traj.xyz.shape[:2]
    coords = pd.DataFrame(
        traj.xyz.reshape(F, 3 * M) * 1000.0,
        columns=[f"{label}_{a}_mm" for label in traj.labels for a in "xyz"],
    )
    flags = pd.DataFrame(np.asarray(traj.filled, dtype=np.int8), columns=[f"{label}_filled" for label in traj.labels])
    table = pd.concat([pd.DataFrame({"frame": np.arange(F), "time_s": np.asarray(traj.times, dtype=np.float64)}), coords, flags], axis=1)
    with _atomic_target(path) as tmp:
        table.to_csv(tmp, index=False, na_rep="", float_format="%.10g", lineterminator="\n")
    return path


def read_csv(path: str | os.PathLike) -> Trajectories:
    """Read a CSV written by :func:`write_csv` back into trajectories (metres)."""
    path = Path(path)
    try:
        table = pd.read_csv(path)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"not a readable CSV ({exc})", "give a CSV written by mocap.exports.write_csv") from None
    if "time_s" not in table.columns:
        raise InputFileError(path, "no time_s column", "give a CSV written by mocap.exports.write_csv", field="time_s")
    labels = [c[: -len("_x_mm")] for c in table.columns if c.endswith("_x_mm")]
    try:
        cols = [f"{label}_{a}_mm" for label in labels for a in "xyz"]
        xyz = table[cols].to_numpy(dtype=np.float64).reshape(len(table), len(labels), 3) / 1000.0
    except KeyError as exc:
        raise InputFileError(path, f"missing column {exc}", "every marker needs _x_mm, _y_mm and _z_mm columns") from None
    filled_cols = [f"{label}_filled" for label in labels]
    filled = table[filled_cols].to_numpy(dtype=bool) if all(c in table.columns for c in filled_cols) else None
    return Trajectories(labels, xyz, table["time_s"].to_numpy(dtype=np.float64), filled=filled)


# ---------------------------------------------------------------------------------------- BVH
_AXIS_NAMES = "XYZ"


def _hinge_channel(axis: np.ndarray, P: np.ndarray, where: str) -> tuple[int, float]:
    """BVH channel (0 = X, 1 = Y, 2 = Z) and sign of a hinge axis given in body coordinates."""
    a = P @ axis
    k = int(np.argmax(np.abs(a)))
    if abs(abs(a[k]) - 1.0) > 1e-6:
        raise MocapInputError(f"{where}: hinge axis {axis.round(4).tolist()} is not a body axis; BVH channels rotate about X, Y or Z only")
    return k, float(np.sign(a[k]))


def write_bvh(
    path: str | os.PathLike,
    fit: SkeletonFit,
    subject: SubjectModel,
    *,
    up_axis: Literal["y", "z"] = "y",
    rate_hz: float | None = None,
) -> Path:
    """Write the solved skeleton as BVH: the humanoid's hierarchy and one frame per sample.

    * Hierarchy: one ``JOINT`` per MJCF body (``ROOT`` = the pelvis), ``OFFSET`` = the body's
      MJCF position in its parent (cm), the root's 0 (its position channels carry the free
      joint's position, which is the pelvis origin in the world); leaves get an ``End Site`` at their farthest marker
      (or 10 cm along the parent bone if they carry none).
    * Channels: the root has ``Xposition Yposition Zposition`` (cm) and ``Zrotation
      Yrotation Xrotation``; every other joint has three rotation channels: its hinges in
      qpos order (a hinge about body axis ``a`` becomes the rotation channel about the BVH
      axis ``a`` maps to), followed by the axes it does not have, which stay 0. A joint's
      rotation is the product of its channels in the listed order, so ``R = Rx Ry Rz`` of the
      contract is written exactly (``Xrotation Yrotation Zrotation``).
    * Axes: ``up_axis="y"`` (default, the BVH custom): ``(x, y, z)_bvh = (x, z, -y)_world``, so
      the body's Y axis becomes -Z (a hinge about Y is written as a Zrotation with its sign
      flipped) and Z becomes Y. ``up_axis="z"``: the world axes unchanged.
    * ``Frame Time`` = ``1 / rate_hz`` (default: the fit's rate, from its timestamps). Frames the fit could not solve repeat the nearest
      solved frame (BVH has no way to mark a gap).

    Parameters
    ----------
    path : path-like
    fit : SkeletonFit
        From :func:`mocap.skeleton.solve_skeleton` on ``subject``.
    subject : SubjectModel
    up_axis : {"y", "z"}
    rate_hz : float, optional
        Needed only for a single-frame fit.

    Returns
    -------
    Path
    """
    path = Path(path)
    P = _bvh_axes(path, fit, subject, up_axis)
    rate = _rate(fit.times, rate_hz, str(path))
    qpos = _nearest_solved_qpos(fit.qpos, fit.valid)
    channel_names, columns = _bvh_root_channels(qpos, P)
    for b in range(1, len(fit.tree.body_names)):
        names, cols = _bvh_joint_channels(b, fit.tree, qpos, P, path)
        channel_names.append(names)
        columns.append(cols)
    lines = ["HIERARCHY", *_bvh_hierarchy(fit.tree, channel_names, _bvh_end_sites(fit.tree, subject), P)]
    lines += ["MOTION", f"Frames: {len(fit.times)}", f"Frame Time: {1.0 / rate:.8f}"]
    motion = np.concatenate(columns, axis=1)
    body = pd.DataFrame(motion).to_csv(sep=" ", header=False, index=False, float_format="%.6f", lineterminator="\n")
    with _atomic_target(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n" + body)
    return path


def _bvh_axes(path: Path, fit: SkeletonFit, subject: SubjectModel, up_axis: str) -> np.ndarray:
    """Check that ``fit`` can be written as BVH for ``subject``; the axis change for ``up_axis``.

    Returns
    -------
    P : (3, 3) float
        ``v_bvh = P @ v_world`` (Y up: :data:`_Z_UP_TO_Y_UP`; Z up: the identity).
    """
    tree = fit.tree
    if tree.body_names != subject.body_names:
        raise MocapInputError(f"{path}: the fit's bodies {tree.body_names} are not the subject's {subject.body_names}; write the BVH with the subject the fit was solved with")
    if tree.rest_rotation:
        raise MocapInputError(f"{path}: a body of the MJCF has a rest orientation; BVH export needs body frames aligned with the world in the rest pose (docs/humanoid_spec.md)")
    if up_axis == "y":
        P = _Z_UP_TO_Y_UP
    elif up_axis == "z":
        P = np.eye(3)
    else:
        raise MocapInputError(f"{path}: up_axis must be 'y' or 'z', got {up_axis!r}")
    if not fit.valid.any():
        raise MocapInputError(f"{path}: no frame of the fit was solved, nothing to write; check the marker labels and min_markers")
    return P


def _nearest_solved_qpos(qpos: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``qpos (F, nq)`` with each unsolved frame replaced by the nearest solved one (the earlier on a tie).

    ``valid (F,) bool`` marks the solved frames; at least one must be. Returns ``(F, nq)``.
    """
    F = len(valid)
    ok = np.flatnonzero(valid)
    nearest = ok[np.clip(np.searchsorted(ok, np.arange(F)), 0, len(ok) - 1)]
    left = ok[np.clip(np.searchsorted(ok, np.arange(F)) - 1, 0, len(ok) - 1)]
    use = np.where(np.abs(left - np.arange(F)) <= np.abs(nearest - np.arange(F)), left, nearest)
    return qpos[use]


def _bvh_root_channels(qpos: np.ndarray, P: np.ndarray) -> tuple[list[list[str]], list[np.ndarray]]:
    """The root's six channels from the free joint of ``qpos (F, nq)`` (position m, quaternion w-first).

    Returns ``([names], [values (F, 6)])``: position in cm in BVH axes (``P @ x``), then the
    ``Zrotation Yrotation Xrotation`` Euler angles (degrees) of ``P R P^T``; lists so that the
    joints' channels can be appended.
    """
    root_pos = qpos[:, :3] @ P.T * 100.0  # cm
    root_R = P @ Rotation.from_quat(qpos[:, 3:7], scalar_first=True).as_matrix() @ P.T
    root_euler = np.degrees(Rotation.from_matrix(root_R).as_euler("ZYX"))  # R = Rz Ry Rx
    names = ["Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"]
    return [names], [np.concatenate([root_pos, root_euler], axis=1)]


def _bvh_joint_channels(b: int, tree: KinematicTree, qpos: np.ndarray, P: np.ndarray, path: Path) -> tuple[list[str], np.ndarray]:
    """Body ``b``'s three rotation channels: its hinges (qpos order), then its missing axes at 0.

    Parameters
    ----------
    b : int
        Body index (not the root).
    qpos : (F, nq) float
        Free joint (7) then hinge angles in radians.
    P : (3, 3) float
        World -> BVH axes.

    Returns
    -------
    names : list[str], length 3
        ``"<axis>rotation"`` channel names.
    values : (F, 3) float
        Degrees, signed for the BVH axis each hinge maps to.
    """
    angles_deg = np.degrees(qpos[:, 7:])
    names, cols, used = [], [], set()
    for h in np.flatnonzero(tree.hinge_bodies == b):
        k, sign = _hinge_channel(tree.hinge_axes[h], P, f"{path}: hinge {tree.hinge_names[h]!r}")
        if k in used:
            raise MocapInputError(f"{path}: body {tree.body_names[b]!r} has two hinges about the same axis; BVH cannot write that")
        used.add(k)
        names.append(f"{_AXIS_NAMES[k]}rotation")
        cols.append(sign * angles_deg[:, h])
    for k in range(3):
        if k not in used:
            names.append(f"{_AXIS_NAMES[k]}rotation")
            cols.append(np.zeros(len(qpos)))
    return names, np.stack(cols, axis=1)


def _bvh_end_sites(tree: KinematicTree, subject: SubjectModel) -> dict[int, np.ndarray]:
    """``body index -> (3,) end-site offset (m, body frame)`` for every leaf body.

    The leaf's marker farthest from its origin, else 10 cm along its bone from the parent
    (straight up for a zero-length bone).
    """
    marker_offsets: dict[str, list[np.ndarray]] = {}
    for m in subject.markers:
        marker_offsets.setdefault(m.body, []).append(m.offset_m)
    has_child = set(int(p) for p in tree.parents[1:])
    sites: dict[int, np.ndarray] = {}
    for b in range(len(tree.body_names)):
        if b in has_child:
            continue
        offs = marker_offsets.get(tree.body_names[b])
        if offs:
            offs_arr = np.array(offs)
            sites[b] = offs_arr[int(np.argmax(np.linalg.norm(offs_arr, axis=1)))]
        else:
            bone = tree.offsets_m[b]
            n = np.linalg.norm(bone)
            sites[b] = bone / n * 0.1 if n > 0 else np.array([0.0, 0.0, 0.1])
    return sites


def _bvh_hierarchy(tree: KinematicTree, channel_names: list[list[str]], end_sites: dict[int, np.ndarray], P: np.ndarray) -> list[str]:
    """The ``HIERARCHY`` section's lines after its keyword: ROOT/JOINT blocks, depth first.

    ``channel_names[b]`` are body ``b``'s channels; ``end_sites[b] (3,)`` metres for each leaf;
    offsets are written in cm in BVH axes (``P @ v``).
    """
    children: dict[int, list[int]] = {b: [] for b in range(len(tree.body_names))}
    for b in range(1, len(tree.body_names)):
        children[int(tree.parents[b])].append(b)
    lines: list[str] = []

    def fmt(v: np.ndarray) -> str:
        return " ".join(f"{x:.6f}" for x in (P @ v) * 100.0)

    def emit(b: int, depth: int) -> None:
        pad = "  " * depth
        kind = "ROOT" if b == 0 else "JOINT"
        lines.append(f"{pad}{kind} {tree.body_names[b]}")
        lines.append(f"{pad}{{")
        offset = np.zeros(3) if b == 0 else tree.offsets_m[b]
        lines.append(f"{pad}  OFFSET {fmt(offset)}")
        lines.append(f"{pad}  CHANNELS {len(channel_names[b])} {' '.join(channel_names[b])}")
        if children[b]:
            for c in children[b]:
                emit(c, depth + 1)
        else:
            lines.append(f"{pad}  End Site")
            lines.append(f"{pad}  {{")
            lines.append(f"{pad}    OFFSET {fmt(end_sites[b])}")
            lines.append(f"{pad}  }}")
        lines.append(f"{pad}}}")

    emit(0, 0)
    return lines
