"""Reading the capture product's own ``.npz`` files (a colour model, IK priors, a pose database), with one error for a
wrong file.

Why one helper: each reader opened its archive and indexed the arrays itself, so a wrong file given for one of them
(``mocap shirt --priors colour_model.npz``, or a PNG) came out as numpy's ``KeyError`` or its pickle ``ValueError``,
a traceback, or as "missing array 'means is not a file in the archive'".
"""

from __future__ import annotations

import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from mocap.errors import InputFileError

__all__ = ["read_npz"]


def read_npz(path: str | os.PathLike, names: tuple[str, ...], what: str, fix: str) -> dict[str, np.ndarray]:
    """The arrays ``names`` of the ``.npz`` file ``path``, read whole.

    Raises
    ------
    InputFileError
        Naming the file: not found, not a readable ``.npz`` (no pickled objects are read), or without some of
        ``names``; ``what`` names the file's kind in the message ("colour model") and ``fix`` what to do.
    """
    path = Path(path)
    a_what = ("an " if what[:1].lower() in "aeiou" else "a ") + what
    if not path.is_file():
        raise InputFileError(path, f"{what} not found", fix)
    try:
        with path.open("rb") as f:
            if f.read(4) != b"PK\x03\x04":  # not a zip archive at all (numpy would try it as a pickle, and say so)
                raise InputFileError(path, f"not {a_what}: not a .npz archive", fix)
        with np.load(path, allow_pickle=False) as z:
            missing = [n for n in names if n not in z.files]
            if missing:
                raise InputFileError(path, f"not {a_what}: no array {', '.join(missing)}", fix)
            return {n: z[n] for n in names}  # read here: a corrupt member fails only when it is read
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise InputFileError(path, f"not a readable {what} ({type(exc).__name__}: {exc})", fix) from None
