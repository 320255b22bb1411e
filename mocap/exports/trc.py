"""TRC (OpenSim, Pose2Sim, Motion Analysis): tab-separated text, millimetres, Y up by default."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import numpy as np

from mocap.atomic_files import atomic_target
from mocap.errors import InputFileError, MocapInputError
from mocap.exports._common import (
    _UNIT_TO_M,
    _rate,
    pose2sim_to_world,
    world_to_opensim,
    world_to_pose2sim,
)
from mocap.exports.capture_files import CaptureTrajectories, _classify_points, _decide_up_axis, _rotate_to_z_up
from mocap.types import Trajectories


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
    # pandas here, not at the top of the module: a run imports mocap.exports whether or not it writes
    # anything, and pandas is about 0.7 CPU-s of a process's start-up on a busy 2-core machine
    import pandas as pd

    table = pd.DataFrame(xyz.reshape(F, 3 * M) * 1000.0)
    table.insert(0, "time", np.asarray(traj.times, dtype=np.float64))
    table.insert(0, "frame", np.arange(1, F + 1))
    body = table.to_csv(sep="\t", header=False, index=False, na_rep="NaN", float_format="%.10g", lineterminator="\n")
    with atomic_target(path) as tmp:
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
        raw = path.read_bytes()
    except OSError as exc:
        raise InputFileError(path, f"cannot read ({exc.strerror})", "give the path of a .trc file") from None
    if b"\0" in raw:
        raise InputFileError(path, "not a text file", "give a TRC (tab-separated text) file") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        # A TRC declares no encoding, and Windows capture software writes its ANSI code page: a marker named
        # "genou_gauche_\xe9" in cp1252 was "not a text file". cp1252 leaves five bytes undefined; Latin-1 takes every byte.
        try:
            text = raw.decode("cp1252")
        except UnicodeDecodeError:
            text = raw.decode("latin-1")
    lines = text.splitlines()
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
