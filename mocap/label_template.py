"""The label template: every marker's name and its T-pose position in the subject-local frame
(facing +X, left towards +Y, Z up, origin between the feet on the floor, metres), and its
file format, CSV ``name,x,y,z``. A user provides it once per marker set;
:func:`mocap.labelling.initial_labels` fits it to the first frame.
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap.atomic_files import atomic_target
from mocap.errors import InputFileError

__all__ = ["LabelTemplate", "load_template", "save_template"]


@dataclass(frozen=True, eq=False)
class LabelTemplate:
    """Marker names and their T-pose positions in the subject-local frame.

    Attributes
    ----------
    names : tuple[str, ...], length M
    positions : (M, 3) float
        Metres; subject-local frame (facing +X, left +Y, Z up, origin between the feet
        on the floor).
    """

    names: tuple[str, ...]
    positions: np.ndarray

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.names)
        pos = np.asarray(self.positions, dtype=np.float64)
        if pos.shape != (len(names), 3):
            raise ValueError(f"positions must be (M, 3) with M = {len(names)} names, got {pos.shape}")
        if not np.isfinite(pos).all():
            raise ValueError("template positions must be finite")
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"duplicate marker names in the template: {dup}")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "positions", pos)

    def __len__(self) -> int:
        return len(self.names)


def load_template(path: str | os.PathLike) -> LabelTemplate:
    """Read a template CSV: one ``name,x,y,z`` row per marker (metres), optional header.

    Raises
    ------
    InputFileError
        Missing file, wrong column count, non-numeric coordinate, duplicate name or no
        marker; the message names the file and line.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "file not found", "pass a marker template CSV with rows name,x,y,z (metres)")
    names: list[str] = []
    rows: list[list[float]] = []
    first_line: dict[str, int] = {}
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = exc.object[:exc.start].count(b"\n") + 1
        raise InputFileError(path, f"byte {exc.start} is not UTF-8", "save the template as UTF-8 text", field=f"line {line}") from None
    for lineno, row in enumerate(csv.reader(io.StringIO(text, newline="")), start=1):
        if not row or all(not c.strip() for c in row) or row[0].lstrip().startswith("#"):
            continue
        cells = [c.strip() for c in row]
        if not names and not rows and [c.lower() for c in cells] == ["name", "x", "y", "z"]:
            continue  # header
        if len(cells) != 4:
            raise InputFileError(path, f"{len(cells)} columns {cells}", "each row must be name,x,y,z (metres)", field=f"line {lineno}")
        try:
            xyz = [float(c) for c in cells[1:]]
        except ValueError:
            raise InputFileError(path, f"coordinates {cells[1:]} are not all numbers", "write x,y,z in metres as decimal numbers", field=f"line {lineno}") from None
        if not np.isfinite(xyz).all():
            raise InputFileError(path, f"coordinates {cells[1:]} are not finite", "write x,y,z in metres as finite numbers", field=f"line {lineno}")
        if not cells[0]:
            raise InputFileError(path, "empty marker name", "give every row a marker name", field=f"line {lineno}")
        if cells[0] in first_line:
            raise InputFileError(path, f"marker {cells[0]!r} already defined on line {first_line[cells[0]]}", "give each marker one row", field=f"line {lineno}")
        first_line[cells[0]] = lineno
        names.append(cells[0])
        rows.append(xyz)
    if not names:
        raise InputFileError(path, "no marker rows", "add one row name,x,y,z (metres) per marker")
    return LabelTemplate(tuple(names), np.array(rows))


def save_template(template: LabelTemplate, path: str | os.PathLike) -> Path:
    """Write ``name,x,y,z`` CSV (header, micrometre precision), atomically."""
    path = Path(path)
    with atomic_target(path) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["name", "x", "y", "z"])
        for n, p in zip(template.names, template.positions):
            w.writerow([n, *(f"{v:.6f}" for v in p)])
    return path
