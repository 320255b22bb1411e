"""C3D (ezc3d): write the pipeline's labelled markers, read any writer's markers.

World axes (Z up), millimetres in the file; the residual word holds the reprojection
residual in pixels for simbench's own files (see :mod:`mocap.exports`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import ezc3d
import numpy as np

from mocap.errors import InputFileError, MocapInputError
from mocap.atomic_files import atomic_target
from mocap.exports._common import _UNIT_TO_M, _rate
from mocap.exports.capture_files import CaptureTrajectories, _classify_points, _decide_up_axis, _OUTPUT_GROUPS, _rotate_to_z_up
from mocap.types import Trajectories

_C3D_RESIDUAL_STEP = 0.01  # |POINT:SCALE|: residual resolution in the 4th word
_C3D_RESIDUAL_MAX = 255 * _C3D_RESIDUAL_STEP  # the residual is stored in one byte


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
    with atomic_target(path, ".c3d") as tmp:  # ezc3d appends .c3d to names without it
        c3d.write(str(tmp))
    return path


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
