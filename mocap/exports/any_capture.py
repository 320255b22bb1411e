"""Read a labelled capture file of any of the three types the project reads, chosen by its suffix.

Input: a ``.c3d``, ``.trc`` or ``.csv`` path. Output: its trajectories (world axes, Z up, metres;
:func:`mocap.exports.read_c3d`, :func:`mocap.exports.read_trc`, :func:`mocap.exports.read_csv`). The one
place that maps a suffix to a reader: the labelled trials of ``mocap markers`` and the results of
other capture systems that the bench scores both come through it.
"""

from __future__ import annotations

import os
from pathlib import Path

from mocap.errors import InputFileError
from mocap.exports.c3d import read_c3d
from mocap.exports.csv_table import read_csv
from mocap.exports.trc import read_trc
from mocap.types import Trajectories

__all__ = ["CAPTURE_SUFFIXES", "read_capture"]

CAPTURE_SUFFIXES = (".c3d", ".trc", ".csv")
"""The file types :func:`read_capture` reads."""


def read_capture(path: str | os.PathLike, *, trc_axes: str = "opensim", what: str = "capture file") -> Trajectories:
    """The trajectories of ``path`` by its suffix (``trc_axes``: :func:`mocap.exports.read_trc`'s ``axes``).

    Raises :class:`~mocap.errors.InputFileError` naming the file for another suffix, a folder or a missing
    file (``what`` names the file's role in the fix), and whatever the reader raises for its content.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in CAPTURE_SUFFIXES:
        raise InputFileError(path, f"file type {path.suffix or '(none)'!r}", f"give the {what} as one of {', '.join(CAPTURE_SUFFIXES)}")
    if not path.is_file():
        raise InputFileError(path, "is a folder" if path.is_dir() else "no such file", f"give the path of the {what}")
    if suffix == ".c3d":
        return read_c3d(path)
    if suffix == ".trc":
        return read_trc(path, axes=trc_axes)
    return read_csv(path)
