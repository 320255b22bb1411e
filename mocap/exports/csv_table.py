"""The bench's CSV of labelled markers: world axes (Z up), millimetres, empty fields in gaps."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from mocap.errors import InputFileError
from mocap.atomic_files import atomic_target
from mocap.types import Trajectories


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
    import pandas as pd  # here, not at the top: see mocap/exports/trc.py

    coords = pd.DataFrame(
        traj.xyz.reshape(F, 3 * M) * 1000.0,
        columns=[f"{label}_{a}_mm" for label in traj.labels for a in "xyz"],
    )
    flags = pd.DataFrame(np.asarray(traj.filled, dtype=np.int8), columns=[f"{label}_filled" for label in traj.labels])
    table = pd.concat([pd.DataFrame({"frame": np.arange(F), "time_s": np.asarray(traj.times, dtype=np.float64)}), coords, flags], axis=1)
    with atomic_target(path) as tmp:
        table.to_csv(tmp, index=False, na_rep="", float_format="%.10g", lineterminator="\n")
    return path


def read_csv(path: str | os.PathLike) -> Trajectories:
    """Read a CSV written by :func:`write_csv` back into trajectories (metres)."""
    path = Path(path)
    import pandas as pd  # here, not at the top: see mocap/exports/trc.py

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
