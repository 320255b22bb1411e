"""Errors a user can cause: each names the file, the field, the value and the fix.

The CLIs turn any :class:`MocapInputError` into one line on stderr and exit code 2.
"""

from __future__ import annotations

from pathlib import Path


class MocapInputError(Exception):
    """Base class for errors caused by the user's input (files, fields, values)."""


class CalibrationFileError(MocapInputError):
    def __init__(self, path: Path | str, field: str, problem: str, fix: str) -> None:
        self.path, self.field, self.problem, self.fix = Path(path), field, problem, fix
        where = f"{self.path}" + (f": field '{field}'" if field else "")
        super().__init__(f"{where}: {problem}; {fix}")


class InputFileError(MocapInputError):
    """A video, image, template or data file that cannot be used."""

    def __init__(self, path: Path | str, problem: str, fix: str, field: str = "") -> None:
        self.path, self.problem, self.fix, self.field = Path(path), problem, fix, field
        where = f"{self.path}" + (f": field '{field}'" if field else "")
        super().__init__(f"{where}: {problem}; {fix}")
